"""The CI-sized fuzz run: every boundary's target (tests/fuzzing.py) for a bounded
number of seeded hypothesis examples (derandomized: the same inputs each run, so a
failure reproduces). The long run is ``python tests/stress/fuzz_long.py``."""

from __future__ import annotations

import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from autopilot.copter_parameters import ardupilot_parameters
from contracts.telemetry import pack_batch
from tests import fuzzing as fz

# FUZZ_EXAMPLES raises every target's count (the long script sets it).
EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "150"))
FUZZ = settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
                suppress_health_check=list(HealthCheck))


@pytest.fixture(scope="module")
def station():
    from tests.mavlink_station import Station

    s = Station()
    s.flying()
    yield s
    s.close()


@pytest.fixture(scope="module")
def handled(station):
    return tuple(station.server.handlers)


@FUZZ
@given(data=st.data())
def test_fuzz_mavlink_into_the_ground_link(station, handled, data):
    fz.mavlink_ground(station, data.draw(fz.ground_input(handled)))


@pytest.fixture(scope="module")
def copter_station():
    """The ArduPilot-Copter flavour in GUIDED in the air: where go-tos and targets act."""
    from contracts.modes import FlightMode
    from tests.mavlink_station import T0, Station

    s = Station(flavour="ardupilot")
    s.state_up()
    s.vehicle.set_mode(FlightMode.GUIDED, T0)
    s.flying()
    yield s
    s.close()


RC_MESSAGES = ("RC_CHANNELS_OVERRIDE", "MANUAL_CONTROL")


def _guided_item(draw, msg) -> None:
    """MISSION_ITEM / MISSION_ITEM_INT with current 2 or 3 (Copter's GUIDED go-to and
    altitude change), some in a global frame as DroneKit sends them; or one of Copter's
    own commands (arming with 2989, flight termination, modes, take-off)."""
    if msg.get_type() == "COMMAND_LONG":
        msg.command = draw(st.sampled_from((fz.M.MAV_CMD_DO_FLIGHTTERMINATION,
                                            fz.M.MAV_CMD_COMPONENT_ARM_DISARM,
                                            fz.M.MAV_CMD_DO_SET_MODE, fz.M.MAV_CMD_NAV_TAKEOFF)))
        return
    msg.current = draw(st.sampled_from((2, 3)))
    msg.mission_type = 0
    if draw(st.booleans()):
        msg.frame = draw(st.sampled_from((0, 3, 5, 6)))
        msg.command = fz.M.MAV_CMD_NAV_WAYPOINT


@FUZZ
@given(datagrams=fz.shaped_messages([fz.M.MAVLink_mission_item_message,
                                      fz.M.MAVLink_mission_item_int_message,
                                      fz.M.MAVLink_command_long_message], _guided_item))
def test_fuzz_guided_items_and_copter_commands(copter_station, datagrams):
    """Refused with a MISSION_ACK / COMMAND_ACK and a reason, or carried out: the vehicle
    answers and its setpoint stays finite."""
    fz.mavlink_ground(copter_station, datagrams)
    assert all(math.isfinite(v) for v in copter_station.vehicle.setpoint.position_ned_m)


@FUZZ
@given(data=st.data())
def test_fuzz_rc_overrides_into_the_ardupilot_flavour(copter_station, data):
    """RC_CHANNELS_OVERRIDE and MANUAL_CONTROL (half of the messages), hostile: every
    channel the vehicle sees stays 0 or a PWM in the RC range; it flies on."""
    from autopilot.commander.rc import PWM_MAX_US, PWM_MIN_US

    fz.mavlink_ground(copter_station, data.draw(fz.ground_input(RC_MESSAGES)))
    assert all(p == 0 or PWM_MIN_US <= p <= PWM_MAX_US
               for p in copter_station.vehicle.rc_channels_pwm)


@FUZZ
@given(data=st.data())
def test_fuzz_ardupilotmega_into_the_ardupilot_flavour(copter_station, data):
    """The ArduPilot flavour's link: every ardupilotmega message, and COMMAND_LONG /
    COMMAND_INT of the commands it serves (banner, reboot, calibrations, mag cal, pre-arm
    checks ...) with hostile parameters; it keeps answering and flies on."""
    server = copter_station.server
    fz.mavlink_ground(copter_station, data.draw(fz.ground_input(
        tuple(server.handlers), dialect=fz.ardupilotmega,
        commands=tuple(server.commands.table))))


@pytest.fixture(scope="module", params=["ardupilot", "px4"])
def home_station(request):
    """A vehicle of each flavour in the air with its origin known: DO_SET_HOME acts."""
    from contracts.frames import DEFAULT_HOME
    from tests.mavlink_station import Station

    s = Station(flavour=request.param)
    s.vehicle.set_origin(DEFAULT_HOME)
    s.flying()
    yield s
    s.close()


def _set_home_command(draw, msg) -> None:
    """MAV_CMD_DO_SET_HOME, every other field hostile; a COMMAND_INT half the time in a
    global frame."""
    msg.command = fz.M.MAV_CMD_DO_SET_HOME
    if msg.get_type() == "COMMAND_INT" and draw(st.booleans()):
        msg.frame = draw(st.sampled_from((0, 3, 5, 6)))


@FUZZ
@given(datagrams=fz.shaped_messages([fz.M.MAVLink_command_long_message,
                                      fz.M.MAVLink_command_int_message], _set_home_command))
def test_fuzz_set_home_commands(home_station, datagrams):
    """Refused with a reason or carried out: the origin never moves and home stays a
    place on Earth (every field finite and in range)."""
    from contracts.frames import DEFAULT_HOME, Home

    fz.mavlink_ground(home_station, datagrams)
    places = home_station.vehicle.places
    assert places.origin == DEFAULT_HOME
    assert Home.checked(*places.home) == places.home


SIGNING_KEY = bytes(range(32))


@pytest.fixture(scope="module")
def signed_station():
    from autopilot.mavlink.signing import signing_clock_now
    from tests.mavlink_station import Station

    s = Station()
    for mav in (s.links[0].mav, s.client.mav):  # the vehicle signs; so does its tool
        mav.signing.secret_key = SIGNING_KEY
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_clock_now()
    s.links[0].mav.signing.allow_unsigned_callback = None
    s.flying()
    yield s
    s.close()


@FUZZ
@given(data=st.data())
def test_fuzz_signed_and_forged_mavlink_into_a_signing_vehicle(signed_station, handled,
                                                                 data):
    """Signed with the key, another key or not at all, replayed, damaged: the signing
    vehicle keeps answering its signed tool and flies on."""
    newest = signed_station.client.mav.signing.timestamp
    fz.mavlink_ground(signed_station, data.draw(fz.ground_input(handled, SIGNING_KEY,
                                                                newest)))


MISSION_MESSAGES = ("MISSION_COUNT", "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_REQUEST",
                    "MISSION_REQUEST_INT", "MISSION_REQUEST_LIST", "MISSION_ACK",
                    "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT")


@FUZZ
@given(data=st.data())
def test_fuzz_missions_into_an_ardupilot_vehicle(copter_station, data):
    """The ArduPilot flavour's mission protocol (home as item 0, items renumbered on the
    way in and out): hostile mission messages, an upload started first half the time so
    that items land mid-transfer; every stored item still passes the store's check."""
    from autopilot.navigator.mission_store import MISSION_TYPES, check_item

    if data.draw(st.booleans()):
        copter_station.client.send(fz.M.MAVLink_mission_count_message(
            1, 1, data.draw(st.integers(0, 6)), data.draw(st.sampled_from(MISSION_TYPES))))
    fz.mavlink_ground(copter_station, data.draw(fz.ground_input(MISSION_MESSAGES)))
    for items in copter_station.vehicle.mission.lists.values():
        for item in items:
            check_item(item, len(items), ardupilot=True)


@pytest.fixture(scope="module")
def sim_pair():
    pair = fz.SimLinkPair()
    yield pair
    pair.close()


@st.composite
def _sim_frames(draw) -> bytes:
    encoder = fz.M.MAVLink(None, srcSystem=1, srcComponent=51)
    classes = [c for c in fz.MESSAGE_CLASSES if c.msgname in fz.SIM_TYPES]
    out = b""
    for _ in range(draw(st.integers(1, 6))):
        try:
            frame = draw(fz.hostile_message(classes)).pack(encoder)
        except (ValueError, TypeError, OverflowError, fz.struct.error):
            continue
        out += draw(fz.damaged(frame)) if draw(st.integers(0, 3)) == 0 else frame
    return out


@FUZZ
@given(data=_sim_frames())
def test_fuzz_the_simulator_link_into_the_autopilot(sim_pair, data):
    fz.sim_link(sim_pair, data)


@pytest.fixture(scope="module")
def simulator():
    from contracts.airframe import PAPER
    from sitl.server import Simulator, SimulatorConfig

    return Simulator(SimulatorConfig(PAPER), log=lambda text: None)


@FUZZ
@given(msg=fz.hostile_message([c for c in fz.MESSAGE_CLASSES
                               if c.msgname == "HIL_ACTUATOR_CONTROLS"]))
def test_fuzz_actuator_commands_into_the_simulator(simulator, msg):
    fz.actuators(simulator, msg)


@FUZZ
@given(requests=st.lists(fz.perturbation_request(), min_size=1, max_size=5),
       now_s=fz.hostile_float())
def test_fuzz_perturbation_requests(requests, now_s):
    from contracts.perturbation_book import PerturbationBook

    for target in ("sitl", "autopilot"):
        book = PerturbationBook(target)
        for request in requests:
            fz.perturbation(book, request, now_s)  # NaN and inf: refused


@pytest.fixture(scope="module")
def logger(tmp_path_factory):
    from contracts.zenoh_link import ZenohOptions
    from ground.telemetry.logger import Logger, LoggerConfig

    out = tmp_path_factory.mktemp("fuzz-logger")
    lg = Logger(LoggerConfig(out, ZenohOptions(enabled=False)), log=lambda text: None)
    lg.files.start()
    yield lg
    lg.files.file.finish()


KEYS = st.one_of(st.sampled_from((
    "ivfm/vehicle/1/autopilot/control", "ivfm/vehicle/1/sitl/state",
    "ivfm/vehicle/1/autopilot/batch", "ivfm/vehicle/1/sitl/batch",
    "ivfm/vehicle/1/autopilot/status", "ivfm/vehicle/1/sitl/perturbation",
    "mavlink/1/1/HEARTBEAT", "ivfm/vehicle/999/x/y", "ivfm/logger/run/status")),
    st.text(max_size=80))


@FUZZ
@given(key=KEYS, payload=st.one_of(st.binary(max_size=600), fz.json_values().map(
    lambda v: fz.json.dumps(v).encode())), attachment=st.one_of(st.none(),
                                                                 st.binary(max_size=24)))
def test_fuzz_records_into_the_logger(logger, key, payload, attachment):
    fz.logger_record(logger, key, payload, attachment)


@st.composite
def _hostile_batch(draw) -> bytes:
    """A batch that packs (keys its sender may and may not publish, any payloads), then
    maybe cut, grown or with bytes overwritten."""
    keys = draw(st.lists(st.one_of(KEYS, st.sampled_from((
        "ivfm/vehicle/1/autopilot/timing", "mavlink/1/1/HIL_ACTUATOR_CONTROLS",
        "mavlink/2/1/HEARTBEAT", "ivfm/vehicle/1/autopilot/batch"))), min_size=1,
        max_size=4, unique=True))
    n = draw(st.integers(1, 6))
    batch = pack_batch(keys, [draw(st.integers(0, len(keys) - 1)) for _ in range(n)],
                          [draw(st.binary(max_size=200)) for _ in range(n)],
                          [draw(st.binary(max_size=20)) for _ in range(n)])
    cut = draw(st.integers(0, len(batch)))
    return draw(st.sampled_from((batch, batch[:cut], batch + draw(st.binary(max_size=8)),
                                 batch[:cut] + draw(st.binary(min_size=1, max_size=4))
                                 + batch[cut + 4:])))


@FUZZ
@given(key=st.sampled_from(("ivfm/vehicle/1/autopilot/batch", "ivfm/vehicle/1/sitl/batch")),
       batch=_hostile_batch())
def test_fuzz_batches_into_the_logger(logger, key, batch):
    fz.logger_record(logger, key, batch, None)


# -- files -----------------------------------------------------------------------------------

ROOT = fz.Path(__file__).parents[1]
SOURCES = {
    "scenario": [ROOT / "ground/scenario/shipped" / f for f in (
        "position-kick.toml", "mission-six-waypoints.toml", "gps-outage.toml")]
    + [ROOT / "ground/rehearsal/profiles/flights/setpoint-loss.toml",
       ROOT / "ground/rehearsal/profiles/flights/sim-stall.toml"],
    "airframe": [ROOT / "contracts/airframes/quad-x-500.toml"],
    "sensors": [ROOT / "sitl/sensor_profiles/typical.toml"],
    "plan": [ROOT / "ground/scenario/shipped/six-waypoints.plan"],
    "model": [ROOT / "autopilot/models/quad-x-500.json"],
    "profile": [ROOT / "ground/rehearsal/profiles/default.toml"],
}


def _load(path):
    import tomllib

    return fz.json.loads(path.read_text()) if path.suffix in (".json", ".plan") else \
        tomllib.loads(path.read_text())


@pytest.fixture(scope="module")
def file_folder(tmp_path_factory):
    """A scratch folder holding what the shipped files name beside them."""
    import shutil

    folder = tmp_path_factory.mktemp("fuzz-files")
    shutil.copy(ROOT / "ground/scenario/shipped/six-waypoints.plan", folder)
    shutil.copytree(ROOT / "ground/rehearsal/profiles/flights", folder / "flights")
    return folder


@st.composite
def _hostile_file(draw):
    kind = draw(st.sampled_from(sorted(SOURCES)))
    if draw(st.integers(0, 4)) == 0:  # not even the file's syntax
        return kind, draw(st.text(max_size=200))
    doc = draw(fz.mutated(_load(draw(st.sampled_from(SOURCES[kind])))))
    text = fz.json.dumps(doc) if kind in ("plan", "model") else fz._toml(doc)
    return kind, text if text is not None else ""


@FUZZ
@given(case=_hostile_file())
def test_fuzz_files(file_folder, case):
    kind, text = case
    fz.hostile_file(kind, file_folder, text)


# -- logs ------------------------------------------------------------------------------------

LOG = (fz.SHORT_RUN / "telemetry-000.mcap").read_bytes()


@settings(FUZZ, max_examples=max(10, EXAMPLES // 10))  # each runs four commands
@given(data=fz.corrupt(LOG))
def test_fuzz_logs_into_report_tlog_ulog_and_identify(tmp_path_factory, capsys, data):
    fz.hostile_log(tmp_path_factory.mktemp("fuzz-log"), data, capsys)


# -- PX4 logs (ULog) ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def px4_log(tmp_path_factory):
    """A short PX4 1.15 log of the project's own writing (tests/ulog_logs.py)."""
    from tests.ulog_logs import small_log

    return small_log(tmp_path_factory.mktemp("seed-ulog") / "seed.ulg")


@pytest.fixture(scope="module")
def px4_log_fields(px4_log):
    return fz.ulog_fields(px4_log)


@settings(FUZZ, max_examples=max(10, EXAMPLES // 10))  # each runs three commands
@given(data=st.data())
def test_fuzz_damaged_ulogs_into_info_identify_and_draft(tmp_path_factory, capsys, px4_log,
                                                         data):
    bytes_ = data.draw(fz.corrupt(px4_log.read_bytes()))
    fz.hostile_ulog(tmp_path_factory.mktemp("fuzz-ulog"), bytes_, capsys)


@settings(FUZZ, max_examples=max(10, EXAMPLES // 10))
@given(data=st.data())
def test_fuzz_hostile_values_in_ulogs(tmp_path_factory, capsys, px4_log, px4_log_fields,
                                      data):
    folder = tmp_path_factory.mktemp("fuzz-ulog-values")
    edits = data.draw(fz.ulog_edits(px4_log_fields))
    fz.hostile_ulog(folder, fz.edited_ulog(px4_log, edits, folder / "edited.ulg"), capsys)


def test_the_logger_bounds_its_keys(tmp_path):
    """Hostile keys cannot grow the logger's per-key structures past MAX_KEYS: the
    records are refused and counted, and the known keys still log."""
    from contracts.zenoh_link import ZenohOptions
    from ground.telemetry.logger import MAX_KEY_CHARS, MAX_KEYS, Logger, LoggerConfig

    lg = Logger(LoggerConfig(tmp_path, ZenohOptions(enabled=False)), log=lambda text: None)
    lg.files.start()
    for i in range(MAX_KEYS + 500):
        lg._write(f"ivfm/vehicle/1/junk/k{i}", b"x", None, 0)
    lg._write("ivfm/vehicle/1/" + "k" * MAX_KEY_CHARS, b"x", None, 0)
    c = lg.counters
    assert len(c.per_key) + len(c.rejected_per_key) == MAX_KEYS
    assert len(lg.files.file.channels) <= MAX_KEYS and c.keys_over_limit == 501
    lg._write("ivfm/vehicle/1/junk/k0", b"y", None, 0)  # a key it knows: still logged
    assert c.per_key["ivfm/vehicle/1/junk/k0"] == 2
    assert lg.status()["keys_over_limit"] == 501
    lg.files.file.finish()


# -- what the long run (tests/stress/fuzz_long.py) found, pinned ---------------------------

def test_missing_records_are_counted_without_listing_a_damaged_range():
    """The long fuzz run's find: a damaged record's sequence number 2**62 made the report
    list the range between (48 TiB)."""
    import numpy as np

    from ground.record.run_files import missing_count

    assert missing_count(np.array([0, 1, 2, 4, 7])) == 3
    assert missing_count(np.array([5])) == 0
    assert missing_count(np.array([0, 1, 2**62], dtype=np.uint64)) == 2**62 - 2


def test_a_book_whose_clock_is_not_finite_takes_no_request():
    """The long fuzz run's find: at now_s = inf, a baro drift starting "now" was taken
    with start_s = inf."""
    from contracts.perturbation_book import PerturbationBook

    for now_s in (math.inf, -math.inf, math.nan):
        book = PerturbationBook("autopilot")
        with pytest.raises(ValueError, match="clock reads"):
            book.handle({"kind": "baro_drift", "rate_mps": 0.0, "start_s": "now"}, now_s)
        assert book.entries == []


def test_a_request_whose_kind_is_not_text_is_refused():
    """The long fuzz run's find: {"kind": []} raised TypeError (unhashable) out of the
    book, past the processes' handlers, which catch ValueError."""
    from contracts.perturbation_book import PerturbationBook

    for kind in ([], {}, 1, None):
        with pytest.raises(ValueError, match="unknown perturbation kind"):
            PerturbationBook("sitl").handle({"kind": kind}, 0.0)


COPTER_NAMES = [p.name for p in ardupilot_parameters()]


@FUZZ
@given(name=st.sampled_from(COPTER_NAMES) | st.text(max_size=16),
       value=st.floats(width=32) | st.sampled_from([math.nan, math.inf, -math.inf]),
       kind=st.integers(0, 255), flavour=st.sampled_from(["copter", "px4"]))
def test_fuzz_param_set_by_copter_name_value_and_type(station, copter_station, name, value,
                                                     kind, flavour):
    """Any name, float and declared type: the vehicle keeps parameters it flies, and the
    Copter values kept for the tools stay finite."""
    s = copter_station if flavour == "copter" else station
    from tests.mavlink_station import M

    encoded = name.encode()[:16]
    s.client.send(M.MAVLink_param_set_message(1, 1, encoded, value, kind))
    s.client.sync()
    fz.check_vehicle(s.vehicle)
    stored = copter_station.server.parameters.stored.values()
    assert all(math.isfinite(v) for v in stored)
