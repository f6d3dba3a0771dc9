"""A run's log as a PX4 ULog (ground/ulog/export.py): read back by pyulog, the topics and
fields PX4's own (its message declarations, tests/data/px4_msg), every value the log's
records to float32, the parameters under PX4's names and types, the motor model a reader
inverts, bad logs refused with nothing written; and, through processes, a flown run's
``ivfm run --ulog`` read by pyulog's ``ulog_info``, ``ulog_params`` and ``ulog2csv``."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from autopilot.copter_parameters import ARDUPILOT_ONLY, px4_parameters
from autopilot.parameters import PARAMETER_SPECS
from contracts.airframe import airframe_by_name, rotor_speeds
from contracts.airframe_file import read_airframe
from contracts.frames import (
    DEFAULT_HOME,
    GRAVITY_MPS2,
    Home,
    body_rates_from_euler_rates,
    euler_rates_from_body_rates,
    quat_from_euler,
    rotation_from_quat,
)
from contracts.mavlink import mavlink, new_mavlink
from contracts.modes import FlightMode
from contracts.sim_samples import GpsSample, SensorSample, TruthSample, sample_frames
from contracts.telemetry import STATE
from ground.cli.main import main
from ground.record.events import statustext_events
from ground.record.run_files import ULOG_FILE, control_records, iter_messages
from ground.ulog import px4_topics as px4
from ground.ulog.export import _airframe, export_ulog
from ground.ulog.run_topics import max_thrust_n, readings_topics

DATA = Path(__file__).parents[1] / "data"
SHORT_RUN = DATA / "short-run"  # a 1 s lockstep hover: paper airframe, ivfc, rigid-body plant
PX4_MSG = DATA / "px4_msg"
F32 = np.float32
READINGS = {"sensor_combined", "sensor_gps"}  # written where the run logged its readings


def f32(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).astype(np.float32)


# -- PX4's declarations --------------------------------------------------------------------

def px4_message(name: str) -> tuple[dict[str, tuple[str, int]], dict[str, int], list[str]]:
    """(fields name -> (type, count), constants, topics) of a vendored PX4 .msg file."""
    fields, constants, topics = {}, {}, []
    for raw in (PX4_MSG / f"{name}.msg").read_text().splitlines():
        if raw.startswith("# TOPICS"):
            topics += raw.split()[2:]
            continue
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if "=" in line:
            left, value = line.split("=")
            constants[left.split()[1]] = int(value)
            continue
        kind, field = line.split()
        count = 0
        if kind.endswith("]"):
            kind, size = kind[:-1].split("[")
            count = int(size)
        fields[field] = (kind, count)
    if not topics:  # a message without TOPICS has one topic, its name in snake case
        topics = ["".join("_" + ch.lower() if ch.isupper() else ch for ch in name)[1:]]
    return fields, constants, topics


# -- the short run, exported once -----------------------------------------------------------

@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("ulog") / "short-run"
    shutil.copytree(SHORT_RUN, folder)
    export_ulog(folder, folder / ULOG_FILE)
    return folder


@pytest.fixture(scope="module")
def ulog(short_run) -> ULog:
    return ULog(str(short_run / ULOG_FILE))


@pytest.fixture(scope="module")
def data(ulog) -> dict[str, dict[str, np.ndarray]]:
    assert len({d.name for d in ulog.data_list}) == len(ulog.data_list)  # one instance each
    return {d.name: d.data for d in ulog.data_list}


@pytest.fixture(scope="module")
def records(short_run) -> dict[str, np.ndarray]:
    return control_records(short_run, 1)


def test_pyulog_reads_every_topic_back_whole(short_run, ulog, records):
    assert not ulog.file_corruption and not ulog.dropouts
    # The short run was flown without --log-sensors: no readings in its log.
    assert sorted(d.name for d in ulog.data_list) == sorted(set(px4.TOPICS) - READINGS)
    n = len(records["seq"])
    assert n == 100
    for name, topic in px4.TOPICS.items():
        if name in READINGS:
            continue  # a flown run's (test_a_flown_runs_readings_are_its_sensor_topics)
        data = ulog.get_dataset(name)
        assert [f.field_name for f in data.field_data] == topic.columns()
        assert ulog.message_formats[name].fields == [
            (f.ulog_type, f.count, f.name) for f in topic.ulog_fields]
        if name not in ("vehicle_status", "vehicle_land_detected") and \
                not name.endswith("groundtruth"):
            assert np.array_equal(data.data["timestamp"], records["sim_time_us"]), name
    assert ulog.start_timestamp == 0
    assert ulog.last_timestamp == 1_000_000  # the simulator's last sample, 1 s


def test_topics_and_fields_are_px4s_own(ulog):
    """Every field written is a field of the PX4 message the topic belongs to, with its
    type and size; every topic is one PX4 names for its message."""
    for data in ulog.data_list:
        topic = px4.TOPICS[data.name]
        fields, _constants, topics = px4_message(topic.message)
        assert data.name in topics, (data.name, topics)
        written = {name: (kind, count) for kind, count, name in
                   ulog.message_formats[data.name].fields}
        for name, (ulog_type, count) in written.items():
            assert name in fields, f"{data.name}.{name} is not a field of {topic.message}"
            msg_type, msg_count = fields[name]
            assert (px4.ULOG_TYPES[msg_type][0], msg_count) == (ulog_type, count), \
                f"{data.name}.{name}"
        assert "timestamp" in written


def test_every_topic_declared_is_px4s_own():
    """Each topic the export may write, whether a given log has it or not (the sensor
    topics need a run that logged its readings): PX4's topic name, field names and
    types."""
    for topic in px4.TOPICS.values():
        fields, _constants, topics = px4_message(topic.message)
        assert topic.name in topics, (topic.name, topics)
        for field in topic.fields:
            assert fields.get(field.name) == (field.msg_type, field.count), \
                f"{topic.name}.{field.name}"


def test_the_readings_sent_become_sensor_combined_and_sensor_gps():
    """The HIL_SENSOR and HIL_GPS frames the simulator packs (as its --log-sensors hands
    them to the log) read back in PX4's units, to float32: degrees from degE7, metres
    from millimetres, m/s from cm/s, course from centidegrees, eph from centimetres as
    PX4's simulator reads it; the sample period from consecutive readings."""
    mav, frames = new_mavlink(1, 51), []
    truth = TruthSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                        (0.0, 0.0, 0.0), (0.0, 0.0, -9.81))
    for k, t_us in enumerate((4_000, 8_000, 12_000)):
        sensor = SensorSample(t_us, (0.1 * k, -0.2, -9.79), (0.01, 0.02 * k, -0.03),
                              (0.2, 0.0, 0.4), 1013.25, 12.5, 20.0, 0x1FFF)
        fix = (GpsSample(t_us, 47.3977421, 8.5455941, 488.123, (1.0, -1.0, 0.25), 0.8,
                         1.2, 3, 10) if k == 1 else None)
        sample_frames(truth._replace(time_us=t_us), sensor, fix, DEFAULT_HOME, mav,
                      lambda s, g: frames.extend(f for f in (s, g) if f is not None))
    parser = mavlink.MAVLink(None)
    msgs = [m for f in frames for m in parser.parse_buffer(f)]
    topics = readings_topics([m for m in msgs if m.get_type() == "HIL_SENSOR"],
                             [m for m in msgs if m.get_type() == "HIL_GPS"])
    imu = topics["sensor_combined"]
    assert list(imu["timestamp"]) == [4_000, 8_000, 12_000]
    assert list(imu["gyro_integral_dt"]) == [4_000] * 3
    assert list(imu["accelerometer_integral_dt"]) == [4_000] * 3
    assert np.array_equal(_columns(imu, "accelerometer_m_s2", 3),
                          f32([(0.0, -0.2, -9.79), (0.1, -0.2, -9.79), (0.2, -0.2, -9.79)]))
    assert np.array_equal(_columns(imu, "gyro_rad", 3),
                          f32([(0.01, 0.0, -0.03), (0.01, 0.02, -0.03), (0.01, 0.04, -0.03)]))
    (gps,) = topics["sensor_gps"]
    assert gps["timestamp"] == gps["timestamp_sample"] == 8_000
    assert gps["latitude_deg"] == pytest.approx(47.3977421, abs=1e-9)  # degE7
    assert gps["longitude_deg"] == pytest.approx(8.5455941, abs=1e-9)
    assert gps["altitude_msl_m"] == pytest.approx(488.123, abs=1e-9)  # mm
    assert (gps["fix_type"], gps["satellites_used"], gps["vel_ned_valid"]) == (3, 10, 1)
    assert (gps["eph"], gps["epv"]) == (F32(0.8), F32(1.2))
    assert (gps["hdop"], gps["vdop"]) == (F32(0.8), F32(1.2))
    assert (gps["vel_n_m_s"], gps["vel_e_m_s"], gps["vel_d_m_s"]) == (
        F32(1.0), F32(-1.0), F32(0.25))
    assert gps["vel_m_s"] == F32(1.41)  # HIL_GPS's ground speed: whole cm/s
    assert gps["cog_rad"] == F32(np.radians(-45.0))  # 315 deg, as PX4 gives it: -pi..pi


def test_the_numbers_are_px4s_own():
    _fields, status, _ = px4_message("VehicleStatus")
    for name, number in px4.NAVIGATION_STATES.items():
        assert status[f"NAVIGATION_STATE_{name}"] == number
    assert (status["ARMING_STATE_DISARMED"], status["ARMING_STATE_ARMED"]) == (
        px4.ARMING_STATE_DISARMED, px4.ARMING_STATE_ARMED)
    assert status["VEHICLE_TYPE_ROTARY_WING"] == px4.VEHICLE_TYPE_ROTARY_WING
    assert px4_message("ActuatorMotors")[1]["NUM_CONTROLS"] == px4.ACTUATOR_MOTORS_COUNT
    # every mode maps to a state PX4 has
    assert set(px4.NAV_STATE_OF_MODE.values()) <= set(status.values())
    assert px4.NAV_STATE_OF_MODE[FlightMode.REFERENCE] == status["NAVIGATION_STATE_OFFBOARD"]


def test_px4_orders_fields_by_size_timestamp_first():
    topic = px4.VEHICLE_LOCAL_POSITION
    sizes = [f.size for f in topic.ulog_fields]
    assert topic.ulog_fields[0].name == "timestamp" and sizes == sorted(sizes, reverse=True)
    assert [f.name for f in topic.ulog_fields if f.size == 1] == [
        "xy_valid", "z_valid", "v_xy_valid", "v_z_valid", "heading_good_for_control",
        "xy_global", "z_global"]  # declaration order among equals
    with pytest.raises(ValueError, match="starts with uint64 timestamp"):
        _ = px4.Topic("bad", "Bad", "float32 x").fields
    with pytest.raises(ValueError, match="unknown PX4 field type"):
        px4.parse_fields("string name")


def _columns(data: dict[str, np.ndarray], name: str, count: int) -> np.ndarray:
    return np.stack([data[f"{name}[{i}]"] for i in range(count)], axis=1)


def test_what_the_autopilot_flew_on_is_the_records_to_float32(data, records):
    m = records["measurement"]
    q = np.array([quat_from_euler(*e) for e in m[:, 6:9]])
    att = data["vehicle_attitude"]
    assert np.array_equal(_columns(att, "q", 4), f32(q))
    assert np.array_equal(att["timestamp_sample"], records["sim_time_us"])
    pos = data["vehicle_local_position"]
    for i, axis in enumerate("xyz"):
        assert np.array_equal(pos[axis], f32(m[:, i]))
        assert np.array_equal(pos["v" + axis], f32(m[:, 3 + i]))
    assert np.array_equal(pos["heading"], f32(m[:, 8]))
    assert np.all(pos["xy_valid"] == 1) and np.all(pos["xy_global"] == 1)
    home = Home(*json.loads((SHORT_RUN / "run.json").read_text())["home"])
    assert np.all(pos["ref_lat"] == home.lat_deg) and np.all(pos["ref_lon"] == home.lon_deg)
    geodetic = np.array([home.geodetic_from_ned(*p) for p in m[:, :3]])
    glob = data["vehicle_global_position"]
    assert np.array_equal(glob["lat"], geodetic[:, 0])  # float64, exact
    assert np.array_equal(glob["lon"], geodetic[:, 1])
    assert np.array_equal(glob["alt"], f32(geodetic[:, 2]))
    # body rates whose Euler rates are the logged ones, to float32
    rates = data["vehicle_angular_velocity"]
    body = _columns(rates, "xyz", 3)
    assert np.array_equal(body, f32([body_rates_from_euler_rates(*r[6:8], *r[9:12])
                                     for r in m]))
    back = np.array([euler_rates_from_body_rates(*r[6:8], *b) for r, b in zip(m, body,
                                                                              strict=True)])
    assert np.max(np.abs(back - m[:, 9:12])) < 1e-6


def test_the_truth_is_the_simulators_records(short_run, data):
    states = sorted((STATE.decode(d) for _t, _m, d in
                     iter_messages(short_run, "ivfm/vehicle/1/sitl/state")),
                    key=lambda r: r["sim_time_us"])
    truth = data["vehicle_attitude_groundtruth"]
    assert np.array_equal(truth["timestamp"], [r["sim_time_us"] for r in states])
    assert np.array_equal(_columns(truth, "q", 4), f32([r["quaternion"] for r in states]))
    rates = data["vehicle_angular_velocity_groundtruth"]
    assert np.array_equal(_columns(rates, "xyz", 3),
                          f32([r["body_rate_rad_s"] for r in states]))
    pos = data["vehicle_local_position_groundtruth"]
    assert np.array_equal(pos["z"], f32([r["position_ned_m"][2] for r in states]))


def test_motor_commands_are_normalized_thrust_that_inverts_to_rotor_speeds(short_run, data,
                                                                           records, ulog):
    """actuator_motors carries T_i / T_max,i (PX4's meaning): with the paper's speed map
    c^2, stored as float32; W_i = W_max sqrt(control_i) gives the plant's rotor speeds
    (docs/data-format.md), and the simulator's rotors turn at them one sample later."""
    c = records["motor_commands"]
    control = _columns(data["actuator_motors"], "control", 12)
    assert np.array_equal(control[:, :4], f32(np.clip(c, 0, 1) ** 2))
    assert np.all(np.isnan(control[:, 4:]))
    assert np.all(data["actuator_motors"]["reversible_flags"] == 0)
    spec = read_airframe("paper")
    w_max = np.array([r.max_rad_s for r in spec.rotors])
    speeds = w_max * np.sqrt(control[:, :4].astype(np.float64))
    af = airframe_by_name("paper")
    assert np.max(np.abs(speeds - np.array([rotor_speeds(row, af) for row in c]))) < 1e-4
    truth = {int(r["sim_time_us"]): r["rotor_rad_s"] for r in
             (STATE.decode(d) for _t, _m, d in
              iter_messages(short_run, "ivfm/vehicle/1/sitl/state"))}
    later = np.array([truth[int(t) + 10_000] for t in records["sim_time_us"]])
    assert np.max(np.abs(speeds - later)) < 1e-4
    # the same with the parameters alone: CT = k W_max^2, so W = sqrt(CT control / k)
    p = ulog.initial_parameters
    assert p["THR_MDL_FAC"] == 1.0
    ct = np.array([p[f"CA_ROTOR{i}_CT"] for i in range(4)])
    k = np.array([r.thrust_coeff_ns2 for r in spec.rotors])
    assert np.max(np.abs(np.sqrt(ct * control[:, :4] / k) - later)) < 1e-3
    thrust = data["vehicle_attitude_setpoint"]["thrust_body[2]"]
    assert np.allclose(thrust, -np.mean(np.clip(c, 0, 1) ** 2, axis=1), rtol=0, atol=1e-7)


def test_setpoints_are_the_controllers_desired_values(data, records):
    ref, ch_ref = records["reference"], records["ch_ref"]
    sp = data["vehicle_attitude_setpoint"]
    assert np.array_equal(_columns(sp, "q_d", 4),
                          f32([quat_from_euler(*r[:3]) for r in ch_ref]))
    local = data["vehicle_local_position_setpoint"]
    assert np.array_equal(local["x"], f32(ref[:, 0]))  # a hover: the position loop is on
    assert np.array_equal(local["z"], f32(ref[:, 2]))
    assert np.array_equal(local["yawspeed"], f32(ref[:, 14]))
    # the desired Euler rates recovered from the sliding surfaces: yaw's is the reference's
    m = records["measurement"]
    rates = data["vehicle_rates_setpoint"]
    body = np.stack([rates["roll"], rates["pitch"], rates["yaw"]], axis=1)
    euler = np.array([euler_rates_from_body_rates(*r[6:8], *b) for r, b in zip(m, body,
                                                                               strict=True)])
    assert np.max(np.abs(euler[:, 2] - ref[:, 14])) < 1e-6


def test_status_and_landed_state(data):
    status = data["vehicle_status"]
    assert list(status["timestamp"]) == [0]  # on a change, else once a second: 0.99 s
    assert set(status["nav_state"]) == {px4.NAVIGATION_STATES["OFFBOARD"]}  # REFERENCE mode
    assert set(status["arming_state"]) == {px4.ARMING_STATE_ARMED}
    assert set(status["system_id"]) == {1} and set(status["vehicle_type"]) == {1}
    assert set(data["vehicle_land_detected"]["landed"]) == {0}  # a hover at 1 m


def test_parameters_have_px4s_names_and_types(short_run, ulog):
    run = json.loads((short_run / "run.json").read_text())
    p = ulog.initial_parameters
    for name in px4_parameters():
        value = run["parameters"][name]
        if PARAMETER_SPECS[name].integer:
            assert isinstance(p[name], int) and p[name] == value, name
        else:
            assert isinstance(p[name], float) and p[name] == F32(value), name
    assert not set(ARDUPILOT_ONLY) & set(p)
    spec = read_airframe("paper")
    assert p["CA_ROTOR_COUNT"] == 4 and isinstance(p["CA_ROTOR_COUNT"], int)
    assert (p["CA_AIRFRAME"], p["MAV_TYPE"], p["MAV_SYS_ID"]) == (0, 2, 1)
    for i, rotor in enumerate(spec.rotors):
        assert [p[f"CA_ROTOR{i}_{a}"] for a in ("PX", "PY", "PZ")] == list(
            f32(rotor.position_m))
        assert p[f"CA_ROTOR{i}_AZ"] == -1.0
        # PX4: KM positive for a counter-clockwise rotor; ours spin +1 = clockwise
        assert p[f"CA_ROTOR{i}_KM"] == F32(-rotor.spin * rotor.moment_coeff_nms2
                                           / rotor.thrust_coeff_ns2)
        assert p[f"CA_ROTOR{i}_CT"] == F32(rotor.thrust_coeff_ns2 * rotor.max_rad_s ** 2)
    assert p["MPC_THR_HOVER"] == F32(spec.mass_kg * 9.81 / max_thrust_n(spec).sum())


def test_info_says_what_wrote_it_and_which_run(ulog):
    info = ulog.msg_info_dict
    assert info["sys_name"] == "IVFM-SITL" and info["ver_hw"] == "IVFM_SITL"
    assert info["ver_sw"] == __import__("importlib.metadata").metadata.version("ivfm-sitl")
    assert (info["ivfm_scenario"], info["ivfm_controller"], info["ivfm_plant"],
            info["ivfm_airframe"]) == ("short-hover", "ivfc", "rigid-body", "paper")
    assert info["ivfm_seed"] == 0 and info["ivfm_vehicle"] == 1
    assert info["sys_uuid"] == f"ivfm-{read_airframe('paper').fingerprint()}-1"


def test_statustext_becomes_logged_messages_with_their_severity(short_run, ulog):
    said = statustext_events(short_run, 1)
    assert [m.message for m in ulog.logged_messages] == [e.text for e in said] == [
        "simulator link up"]
    assert [m.timestamp for m in ulog.logged_messages] == [round(e.t_s * 1e6) for e in said]
    assert [m.log_level_str() for m in ulog.logged_messages] == ["INFO"]  # MAV_SEVERITY 6


def test_the_same_log_gives_the_same_file(short_run, tmp_path):
    again = tmp_path / "again.ulg"
    export_ulog(short_run, again)
    assert again.read_bytes() == (short_run / ULOG_FILE).read_bytes()


# -- the command and bad input --------------------------------------------------------------

def test_the_command_writes_beside_the_log_and_says_what(short_run, tmp_path, capsys):
    mcap = tmp_path / "copy.mcap"
    shutil.copyfile(short_run / "telemetry-000.mcap", mcap)
    assert main(["ground", "ulog", str(mcap), "--airframe", "paper"]) == 0
    assert f"wrote {tmp_path / 'copy.ulg'}: 11 topics" in capsys.readouterr().out
    copy = ULog(str(tmp_path / "copy.ulg"))
    # no run.json beside it: no run parameters, no home, the airframe given
    assert "ivfm_scenario" not in copy.msg_info_dict and "ATT_LAM" not in \
        copy.initial_parameters and copy.initial_parameters["CA_ROTOR_COUNT"] == 4
    assert "vehicle_global_position" not in {d.name for d in copy.data_list}
    assert "vehicle_rates_setpoint" not in {d.name for d in copy.data_list}


@pytest.mark.parametrize("cut", [0.02, 0.5, 0.97])
def test_a_truncated_log_is_refused_and_nothing_written(short_run, tmp_path, cut, capsys):
    folder = tmp_path / "run"
    folder.mkdir()
    shutil.copyfile(short_run / "run.json", folder / "run.json")
    whole = (short_run / "telemetry-000.mcap").read_bytes()
    (folder / "telemetry-000.mcap").write_bytes(whole[:int(len(whole) * cut)])
    assert main(["ground", "ulog", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ivfm: error: ") and "telemetry-000.mcap" in err
    assert sorted(p.name for p in folder.iterdir()) == ["run.json", "telemetry-000.mcap"]


def test_a_folder_without_a_log_is_refused(tmp_path, capsys):
    assert main(["ground", "ulog", str(tmp_path)]) == 2
    assert f"ivfm: error: no .mcap file in {tmp_path}" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_vehicle_or_airframe_the_log_lacks_is_refused(short_run, tmp_path):
    out = tmp_path / "x.ulg"
    with pytest.raises(ValueError, match="no records of vehicle 2"):
        export_ulog(short_run, out, vehicle=2)
    folder = tmp_path / "run"
    shutil.copytree(short_run, folder)
    run = json.loads((folder / "run.json").read_text())
    (folder / "run.json").write_text(json.dumps({**run, "airframe": "no-such-airframe"}))
    with pytest.raises(ValueError, match=r"does not read .*--airframe"):
        export_ulog(folder, out)
    (folder / "run.json").write_text(json.dumps({**run, "parameters": {"ATT_LAM": "x"}}))
    with pytest.raises(ValueError, match="parameters must be an object of finite numbers"):
        export_ulog(folder, out)
    assert not out.exists()


def test_an_airframe_other_than_the_one_flown_is_refused():
    scene = {"airframe": {"name": "paper", "rotors": [[0.23, 0.0, 0.0, 1.0],
                                                      [0.0, 0.23, 0.0, -1.0],
                                                      [-0.23, 0.0, 0.0, 1.0],
                                                      [0.0, -0.23, 0.0, -1.0]]}}
    assert _airframe({}, scene, None).name == "paper"  # a shipped name in the scene
    with pytest.raises(ValueError, match="is not the one the log flew"):
        _airframe({}, scene, read_airframe("quad-x-500"))
    with pytest.raises(ValueError, match="does not say which airframe"):
        _airframe({}, {"airframe": {"name": "mine"}}, None)


# -- through the processes --------------------------------------------------------------------

def _script(name: str) -> str:
    beside = Path(sys.executable).parent / name
    return str(beside) if beside.exists() else (shutil.which(name) or name)


@pytest.fixture(scope="module")
def flown(tmp_path_factory) -> Path:
    """position-kick, shortened to 3 s (kicks at 1 and 2 s), flown by ``ivfm run --ulog``."""
    root = tmp_path_factory.mktemp("flown")
    shipped = (Path(__file__).parents[2] / "ground" / "scenario" / "shipped" /
               "position-kick.toml").read_text()
    text = shipped.split("\n[expect]")[0]
    for old, new in (('name = "position-kick"', 'name = "kick-short"'),
                     ("duration_s = 20.0", "duration_s = 3.0"),
                     ("transient_s = 3.0", "transient_s = 1.0"),
                     ("start_s = 8.0", "start_s = 1.0"), ("end_s = 8.5", "end_s = 1.5"),
                     ("start_s = 9.0", "start_s = 2.0"), ("end_s = 9.5", "end_s = 2.5")):
        assert old in text
        text = text.replace(old, new)
    scenario = root / "kick-short.toml"
    scenario.write_text(text)
    out = root / "run"
    done = subprocess.run([sys.executable, "-m", "ground.cli", "run", str(scenario), "--out",
                           str(out), "--no-figures", "--ulog"], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"wrote {out / ULOG_FILE}: 16 topics" in done.stdout  # readings logged (--ulog)
    return out


@pytest.mark.process
def test_pyulogs_tools_read_a_flown_runs_ulog(flown, tmp_path):
    path = str(flown / ULOG_FILE)
    info = subprocess.run([_script("ulog_info"), path], capture_output=True, text=True,
                          timeout=120)
    assert info.returncode == 0, info.stderr
    assert "sys_name: IVFM-SITL" in info.stdout and "ivfm_scenario: kick-short" in info.stdout
    for name in px4.TOPICS:
        assert f" {name} (0," in info.stdout, name
    params = subprocess.run([_script("ulog_params"), path], capture_output=True, text=True,
                            timeout=120)
    assert params.returncode == 0, params.stderr
    lines = dict(line.split(",", 1) for line in params.stdout.splitlines())
    assert lines["CA_ROTOR_COUNT"] == "4" and lines["THR_MDL_FAC"] == "1.0"
    assert lines["COM_OBL_ACT"] == "1"  # an INT32 parameter, printed as an integer
    csvs = subprocess.run([_script("ulog2csv"), "-o", str(tmp_path), "-m",
                           "vehicle_attitude,vehicle_status", path], capture_output=True,
                          text=True, timeout=120)
    assert csvs.returncode == 0, csvs.stderr
    with open(tmp_path / "flight_vehicle_attitude_0.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 300 and list(rows[0])[:6] == ["timestamp", "timestamp_sample", "q[0]",
                                                      "q[1]", "q[2]", "q[3]"]
    records = control_records(flown, 1)
    assert [int(r["timestamp"]) for r in rows] == list(records["sim_time_us"])
    assert float(rows[-1]["q[0]"]) == pytest.approx(
        quat_from_euler(*records["measurement"][-1, 6:9])[0], abs=1e-6)


@pytest.mark.process
def test_a_flown_run_round_trips_with_its_home_kicks_and_rates(flown):
    """The current log's records: home from the scene and run.json, the desired roll and
    pitch the kicks moved, the yaw rate setpoint the reference's."""
    u = ULog(str(flown / ULOG_FILE))
    data = {d.name: d.data for d in u.data_list}
    records = control_records(flown, 1)
    home = Home(*json.loads((flown / "run.json").read_text())["home"])
    glob = data["vehicle_global_position"]
    geodetic = np.array([home.geodetic_from_ned(*p) for p in records["measurement"][:, :3]])
    assert np.array_equal(glob["lat"], geodetic[:, 0])
    sp = data["vehicle_attitude_setpoint"]
    q_d = _columns(sp, "q_d", 4)
    assert np.array_equal(q_d, f32([quat_from_euler(*r[:3]) for r in records["ch_ref"]]))
    m = records["measurement"]
    rates = data["vehicle_rates_setpoint"]
    body = np.stack([rates["roll"], rates["pitch"], rates["yaw"]], axis=1)
    euler = np.array([euler_rates_from_body_rates(*r[6:8], *b) for r, b in zip(m, body,
                                                                               strict=True)])
    assert np.max(np.abs(euler[:, 2] - records["reference"][:, 14])) < 1e-6
    # roll's and pitch's: the command filter's output, which its rate limit bounds
    # (CMDF_RATE_MAX, 2 rad/s) and the sine and the kicks reach
    assert float(np.max(np.abs(euler[:, :2]))) == pytest.approx(2.0, abs=1e-6)


@pytest.mark.process
def test_a_flown_runs_readings_are_its_sensor_topics(flown):
    """``ivfm run --ulog`` logs what the simulator sent (ideal sensors here): an IMU
    reading at every sample, PX4's layout, whose specific force turned into NED by the
    truth's attitude, plus gravity, is the truth's acceleration over the period before it
    (to float32); a fix every 100 ms where the truth was, to HIL_GPS's 1e-7 degrees and
    millimetres."""
    u = ULog(str(flown / ULOG_FILE))
    for name in READINGS:
        data = u.get_dataset(name)
        assert [f.field_name for f in data.field_data] == px4.TOPICS[name].columns()
    key = "ivfm/vehicle/1/sitl/state"
    truth = {int(r["sim_time_us"]): r for r in
             (STATE.decode(d) for topic, _m, d in iter_messages(flown, key) if topic == key)}
    imu = u.get_dataset("sensor_combined").data
    assert list(imu["timestamp"]) == sorted(truth)  # every sample sent
    assert set(imu["gyro_integral_dt"]) == {10_000}  # 100 Hz
    times = sorted(truth)
    velocity = np.array([truth[t]["velocity_ned_mps"] for t in times])
    acceleration = np.diff(velocity, axis=0) / 0.01
    force = _columns(imu, "accelerometer_m_s2", 3).astype(float)
    in_ned = np.array([rotation_from_quat(truth[t]["quaternion"]) @ f
                       for t, f in zip(times, force, strict=True)])
    assert np.max(np.abs(in_ned[1:] + [0.0, 0.0, GRAVITY_MPS2] - acceleration)) < 1e-6
    assert np.max(np.abs(acceleration[:, :2])) > 5.0  # the kicks moved it (6.3 m/s^2)
    gps = u.get_dataset("sensor_gps").data
    assert list(gps["timestamp"]) == list(range(0, 3_000_001, 100_000))
    home = Home(*json.loads((flown / "run.json").read_text())["home"])
    where = np.array([home.geodetic_from_ned(*truth[int(t)]["position_ned_m"])
                      for t in gps["timestamp"]])
    assert np.max(np.abs(gps["latitude_deg"] - where[:, 0])) <= 0.5e-7
    assert np.max(np.abs(gps["longitude_deg"] - where[:, 1])) <= 0.5e-7
    assert np.max(np.abs(gps["altitude_msl_m"] - where[:, 2])) <= 0.5e-3
    assert set(gps["fix_type"]) == {3}


def test_a_run_record_without_the_gains_leaves_the_rates_setpoint_out(short_run, tmp_path):
    """The desired rates need the run's ATT_LAM and YAW_LAM: without them (a run.json from
    elsewhere, edited), no vehicle_rates_setpoint rather than a guess."""
    folder = tmp_path / "run"
    shutil.copytree(short_run, folder)
    run = json.loads((folder / "run.json").read_text())
    (folder / "run.json").write_text(json.dumps({**run, "parameters": {"COM_OBL_ACT": 0}}))
    summary = export_ulog(folder, tmp_path / "x.ulg")
    assert "vehicle_rates_setpoint" not in summary.samples and summary.samples[
        "vehicle_attitude"] == 100
    p = ULog(str(tmp_path / "x.ulg")).initial_parameters
    assert p["COM_OBL_ACT"] == 0 and "ATT_LAM" not in p
