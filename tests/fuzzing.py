"""Fuzzing the boundaries: hypothesis strategies for hostile input and one target per
boundary, each a function that feeds one generated input to the real code and checks
what must hold afterwards. ``tests/test_fuzz.py`` runs every target briefly (seeded,
bounded: the CI run); ``tests/stress/fuzz_long.py`` runs them for as many examples as
asked.

Targets and what each must survive, with the answer it must give:
* ``mavlink_ground``: every message of the dialect with hostile field values, and
  damaged frames, on a real UDP link into the vehicle's MAVLink server (loopback): no
  exception; the vehicle still answers a PING; its parameters stay in range; a control
  step gives finite motor commands in [0, 1].
* ``sim_link``: hostile simulator messages (HIL_SENSOR, HIL_GPS, HIL_STATE_QUATERNION,
  ODOMETRY) and damaged frames over a real TCP socket into the autopilot's simulator
  link: each sample finite or refused and counted.
* ``actuators``: hostile HIL_ACTUATOR_CONTROLS into the simulator: motor commands finite
  in [0, 1], or refused.
* ``perturbation``: hostile JSON into the perturbation book: an answer or ValueError;
  what the book holds stays valid and bounded.
* ``logger``: records on any key with any bytes into the logger's writer: written or
  refused; the file stays readable; the per-key structures stay bounded.
* ``files``: hostile scenario, airframe, sensor-profile, plan and model files: read or
  ValueError naming the file.
* ``ulog``: PX4 logs truncated, bit-flipped, spliced or empty, and logs whose fields hold
  hostile values (NaN, infinities, 1e38, wrong-sign stamps), into ``ivfm ulog info``,
  ``ivfm identify --ulog`` and ``ivfm airframe from-ulog``: each answers or exits 2 saying
  why, never a traceback.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import select
import socket
import struct
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from contracts.mavlink import ardupilotmega, mavlink
from contracts.telemetry import unbatched

M = mavlink
HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 1e38, -1e38, 3.4e38, 1e-45,
                  -1.0, 1.0, 65535.0, 2.0**31, -(2.0**31))
INT_RANGES = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-2**15, 2**15 - 1),
              "uint16_t": (0, 2**16 - 1), "int32_t": (-2**31, 2**31 - 1),
              "uint32_t": (0, 2**32 - 1), "int64_t": (-2**63, 2**63 - 1),
              "uint64_t": (0, 2**64 - 1)}
MESSAGE_CLASSES = sorted({cls for cls in M.mavlink_map.values()}, key=lambda c: c.msgname)
# The ArduPilot flavour's dialect: every message its links decode.
APM_MESSAGE_CLASSES = sorted({cls for cls in ardupilotmega.mavlink_map.values()},
                             key=lambda c: c.msgname)


# Strategies are built once (functools.cache): building them per draw costs hypothesis
# more than most targets take to run.
@functools.cache
def hostile_float() -> st.SearchStrategy[float]:
    return st.one_of(st.sampled_from(HOSTILE_FLOATS), st.floats(width=32))


@functools.cache
def _field(name: str, kind: str, length: int) -> st.SearchStrategy:
    if kind == "char":
        return st.binary(max_size=max(1, length))
    if name == "target_system":
        element: st.SearchStrategy = st.sampled_from((0, 1, 1, 1, 2, 255))
    elif name == "target_component":
        element = st.sampled_from((0, 1, 190, 255))
    elif kind in ("float", "double"):
        element = hostile_float()
    else:
        low, high = INT_RANGES[kind]
        element = st.one_of(st.sampled_from((low, high, 0, 1)), st.integers(low, high))
    if length:
        return st.lists(element, min_size=length, max_size=length)
    return element


@st.composite
def hostile_message(draw, classes=MESSAGE_CLASSES) -> Any:
    """A message of one of ``classes``, every field drawn from hostile values."""
    cls = draw(st.sampled_from(classes))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    values = [draw(_field(n, t, lengths[n])) for n, t in
              zip(cls.fieldnames, cls.fieldtypes, strict=True)]
    return cls(*values)


def damaged(frame: bytes) -> st.SearchStrategy[bytes]:
    """``frame`` truncated, bit-flipped, doubled or with garbage around it."""
    n = len(frame)
    return st.one_of(
        st.integers(0, max(0, n - 1)).map(lambda k: frame[:k]),
        st.lists(st.tuples(st.integers(0, n - 1), st.integers(1, 255)), min_size=1,
                 max_size=4).map(lambda flips: _flip(frame, flips)),
        st.just(frame + frame[: n // 2]),
        st.binary(max_size=32).map(lambda junk: junk + frame + junk),
        st.binary(min_size=1, max_size=300),
    )


def _flip(frame: bytes, flips: list[tuple[int, int]]) -> bytes:
    out = bytearray(frame)
    for i, mask in flips:
        out[i] ^= mask
    return bytes(out)


@st.composite
def ground_input(draw, handled: tuple[str, ...], key: bytes | None = None,
                 newest_timestamp: int = 0, dialect=M,
                 commands: tuple[int, ...] = ()) -> list[bytes]:
    """1-8 datagrams: hostile messages (half of them of a type the server handles),
    some of them damaged. With ``key`` (a vehicle that signs): each frame signed with
    that key, another key or not at all, at a timestamp up to 100 s older than
    ``newest_timestamp`` (10 us units), on any link id, and some sent twice (replays).
    Component 191: a stream of its own, beside the test client's. ``dialect``: the
    vehicle's (its messages drawn); ``commands``: ids a hostile COMMAND_LONG / COMMAND_INT
    carries half the time (the ones the vehicle serves: a random id rarely is one)."""
    classes_all = APM_MESSAGE_CLASSES if dialect is ardupilotmega else MESSAGE_CLASSES
    encoder = dialect.MAVLink(None, srcSystem=draw(st.sampled_from((255, 1, 0, 254))),
                        srcComponent=190 if key is None else 191)
    if key is not None:
        signer = draw(st.sampled_from(("key", "wrong key", "unsigned")))
        if signer != "unsigned":
            encoder.signing.secret_key = key if signer == "key" else bytes(31) + b"\x01"
            encoder.signing.sign_outgoing = True
            encoder.signing.link_id = draw(st.integers(0, 255))
            age = draw(st.integers(0, 10**7))  # the draw's bounds fixed: reproducible
            encoder.signing.timestamp = max(0, newest_timestamp - age)
    wanted = [c for c in classes_all if c.msgname in handled]
    out = []
    for _ in range(draw(st.integers(1, 8))):
        classes = wanted if draw(st.booleans()) else classes_all
        try:
            msg = draw(hostile_message(classes))
            if commands and hasattr(msg, "command") and draw(st.booleans()):
                msg.command = draw(st.sampled_from(commands))
            frame = msg.pack(encoder)
        except (struct.error, OverflowError, TypeError, ValueError):
            continue  # not packable: what no encoder can send either
        out.append(draw(damaged(frame)) if draw(st.integers(0, 3)) == 0 else frame)
        if key is not None and draw(st.integers(0, 4)) == 0:
            out.append(frame)  # a replay
    return out


@st.composite
def shaped_messages(draw, classes, shape: Callable[[Any, Any], None]) -> list[bytes]:
    """1-4 hostile messages of ``classes``, each made what a target wants by
    ``shape(draw, msg)`` (a command id, a frame ...), packed as a tool (system 255)
    sends them; one no encoder can pack is left out."""
    encoder = M.MAVLink(None, srcSystem=255, srcComponent=190)
    out = []
    for _ in range(draw(st.integers(1, 4))):
        msg = draw(hostile_message(classes))
        shape(draw, msg)
        try:
            out.append(msg.pack(encoder))
        except (struct.error, OverflowError, TypeError, ValueError):
            continue
    return out


# -- targets -------------------------------------------------------------------------------

def check_vehicle(vehicle, t_s: float = 1.0) -> None:
    """What must hold of a vehicle after hostile input: parameters in range, and a
    control step with finite motor commands in [0, 1]."""
    from autopilot.parameters import PARAMETER_SPECS

    for name, value in vehicle.parameters.items():
        spec = PARAMETER_SPECS[name]
        assert math.isfinite(value) and spec.minimum <= value <= spec.maximum, (name, value)
    measurement = np.zeros(12)
    measurement[2] = -2.5
    commands = vehicle.step(t_s, measurement)
    assert np.all(np.isfinite(commands)) and np.all((commands >= 0) & (commands <= 1)), \
        commands


def mavlink_ground(station, datagrams: list[bytes]) -> None:
    """Send ``datagrams`` to the vehicle's ground link (real UDP); the server reads them,
    services its links; it must answer a PING after, and the vehicle fly on."""
    client = station.client
    for data in datagrams:
        client.sock.sendto(data, client.vehicle_address)
    station.server.receive(station.links[0])
    station.server.service()
    # A fuzzed SETUP_SIGNING from this machine may set a key (or clear it), as it may:
    # the tool that sent it knows the key, so the barrier PING is signed with it.
    signing, ours = station.links[0].mav.signing, client.mav.signing
    if signing.secret_key != ours.secret_key:
        from autopilot.mavlink.signing import signing_clock_now

        ours.secret_key, ours.sign_outgoing = signing.secret_key, bool(signing.secret_key)
        ours.timestamp = max(ours.timestamp, signing_clock_now(), signing.timestamp + 1)
    client.sync()  # the barrier PING: answered, so the server is alive
    check_vehicle(station.vehicle)


SIM_TYPES = ("HIL_SENSOR", "HIL_GPS", "HIL_STATE_QUATERNION", "ODOMETRY")


class SimLinkPair:
    """The autopilot's simulator link on a real loopback TCP connection; the test writes
    the simulator's side."""

    def __init__(self, source: str = "auto") -> None:
        from autopilot.process.sim_link import SimLink
        from contracts.frames import DEFAULT_HOME

        self.server = socket.create_server(("127.0.0.1", 0))
        port = self.server.getsockname()[1]
        self.link = SimLink("127.0.0.1", port, source, home=DEFAULT_HOME)
        assert self.link.connect(0.0)
        self.peer, _ = self.server.accept()

    def feed(self, data: bytes) -> list:
        """What the link makes of ``data``: on loopback a sendall has reached the other
        side's buffer when it returns, so the link reads until that is empty."""
        if not data:
            return []
        self.peer.sendall(data)
        readings: list = []
        timeout_s = 1.0  # the first read: the data is there long before
        while select.select([self.link.sock], [], [], timeout_s)[0]:
            timeout_s = 0.0
            got = self.link.read()
            if got is None:
                break
            readings += got
        return readings

    def close(self) -> None:
        self.link.close()
        self.peer.close()
        self.server.close()


def sim_link(pair: SimLinkPair, data: bytes) -> None:
    """Every sample the link gives is finite; what it refused was counted."""
    before = pair.link.bad_messages
    for reading in pair.feed(data):
        for name, value in zip(reading._fields[1:], reading[1:], strict=True):
            if name == "baro_alt_amsl_m" and math.isnan(value):
                continue  # documented: no fresh baro in this HIL_SENSOR
            if value is None:
                continue  # documented: no fresh magnetometer
            array = np.asarray(value if not hasattr(value, "_asdict") else
                               [v for v in value if v is not None], dtype=float)
            assert np.all(np.isfinite(array)), reading
    assert pair.link.bad_messages >= before


def actuators(simulator, msg) -> None:
    """HIL_ACTUATOR_CONTROLS into the simulator, as it arrives (packed and parsed):
    applied finite in [0, 1] or refused."""
    encoder = M.MAVLink(None, srcSystem=1, srcComponent=1)
    try:
        frame = msg.pack(encoder)
    except (struct.error, OverflowError, TypeError, ValueError):
        return  # not packable: no autopilot can send it
    (msg,) = M.MAVLink(None).parse_buffer(frame)
    answered = simulator.apply_actuators(msg)
    commands = simulator._commands
    assert np.all(np.isfinite(commands)) and np.all((commands >= 0) & (commands <= 1))
    if answered is None:
        assert simulator.stats.bad_messages > 0


@functools.cache
def json_values() -> st.SearchStrategy:
    scalars = st.one_of(st.none(), st.booleans(), st.integers(), hostile_float(),
                        st.text(max_size=20), st.sampled_from(("now", "wind", "kick", "gust",
                                                               "sim_stall", "inf", "nan")))
    return st.recursive(scalars, lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=12), inner,
                                                      max_size=6)), max_leaves=20)


@st.composite
def perturbation_request(draw) -> Any:
    """A request near the real ones (a known kind, its fields, hostile values) or any
    JSON value at all."""
    from contracts.perturbations import KINDS

    if draw(st.booleans()):
        return draw(json_values())
    kind = draw(st.sampled_from(sorted(KINDS)))
    fields = {name: draw(_request_field()) for name in KINDS[kind].params
              if draw(st.booleans())}
    extra = {k: draw(_request_extra()) for k in ("start_s", "end_s", "duration_s", "id", "op")
             if draw(st.booleans())}
    return {"kind": kind, **fields, **extra}


@functools.cache
def _request_field() -> st.SearchStrategy:
    return st.one_of(hostile_float(), st.lists(hostile_float(), max_size=4), json_values())


@functools.cache
def _request_extra() -> st.SearchStrategy:
    return st.one_of(hostile_float(), json_values(), st.just("now"))


def perturbation(book, request: Any, now_s: float) -> None:
    """The book answers or refuses with ValueError; what it holds stays valid (whatever
    its clock reads: the long run found an infinite one turning "now" into t = inf)."""
    from contracts.perturbations import KINDS

    with contextlib.suppress(ValueError):
        book.handle(request, now_s)
    for entry in book.entries:
        assert entry.kind in KINDS and math.isfinite(entry.start_s) and \
            not math.isnan(entry.end_s)


def logger_record(logger, key: str, payload: bytes, attachment: bytes | None) -> None:
    """A record (or a batch of them) on any key: each written or refused (counted), a
    batch that does not parse refused whole; never an exception."""
    try:
        expected = len(unbatched(key, payload, attachment))
    except ValueError:
        expected = 1
    before = logger.counters.records + logger.counters.rejected
    logger._write(key, payload, attachment, 0)
    assert logger.counters.records + logger.counters.rejected == before + expected


def scratch_dir() -> Path:
    return Path(tempfile.mkdtemp(prefix="ivfm-fuzz-"))


def write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, allow_nan=True))


# -- files ---------------------------------------------------------------------------------

LEAVES = st.one_of(hostile_float(), st.integers(-10**12, 10**12), st.booleans(),
                   st.text(max_size=16), st.none(), st.lists(hostile_float(), max_size=4))


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path to a value in a nested dict/list document."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw, doc: Any) -> Any:
    """``doc`` (a real file's content) with 1-4 values replaced, keys deleted or unknown
    keys added: input close enough to the real thing to get past the first checks."""
    doc = json.loads(json.dumps(doc))
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for step in path[:-1]:
            parent = parent[step]
        action = draw(st.integers(0, 3))
        if action <= 1:
            parent[path[-1]] = draw(LEAVES)
        elif action == 2 and isinstance(parent, dict):
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(LEAVES)
    return doc


def _toml(doc: Any) -> str | None:
    import tomli_w

    try:
        return tomli_w.dumps(_tomlable(doc))
    except (TypeError, ValueError):
        return None


def _tomlable(doc: Any) -> Any:
    """TOML has no null: drop them (a missing value is a case of its own)."""
    if isinstance(doc, dict):
        return {k: _tomlable(v) for k, v in doc.items() if v is not None}
    if isinstance(doc, list):
        return [_tomlable(v) for v in doc if v is not None]
    return doc


def read_file(kind: str, path: Path) -> None:
    """Read a file of ``kind`` as the product does; ValueError is the refusal."""
    if kind == "scenario":
        from ground.scenario.scenario_file import load_scenario
        load_scenario(path)
    elif kind == "airframe":
        from contracts.airframe_file import read_airframe
        read_airframe(path)
    elif kind == "sensors":
        from sitl.sensors import read_profile
        read_profile(path)
    elif kind == "plan":
        from autopilot.navigator.plan_file import read_plan
        read_plan(path)
    elif kind == "model":
        from autopilot.models.model_file import load_model
        load_model(path)
    elif kind == "profile":
        from ground.rehearsal.readiness import load_profile
        load_profile(path)


def hostile_file(kind: str, folder: Path, text: str) -> None:
    """A file of ``kind`` holding ``text``: read, or refused with ValueError."""
    suffix = ".json" if kind in ("plan", "model") else ".toml"
    path = folder / f"fuzzed{suffix}"
    path.write_text(text)
    with contextlib.suppress(ValueError):
        read_file(kind, path)


# -- logs ----------------------------------------------------------------------------------

SHORT_RUN = Path(__file__).parent / "data" / "short-run"  # a 1 s lockstep run's folder


def corrupt(data: bytes) -> st.SearchStrategy[bytes]:
    """A log truncated anywhere, with bytes flipped, zeroed or spliced, or empty."""
    n = len(data)
    return st.one_of(
        st.just(b""),
        st.integers(0, n - 1).map(lambda k: data[:k]),
        st.lists(st.tuples(st.integers(0, n - 1), st.integers(1, 255)), min_size=1,
                 max_size=16).map(lambda flips: _flip(data, flips)),
        st.tuples(st.integers(0, n - 1), st.integers(1, 4096)).map(
            lambda cut: data[:cut[0]] + bytes(cut[1]) + data[cut[0] + cut[1]:]),
        st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)).map(
            lambda ab: data[:ab[0]] + data[ab[1]:]),
    )


def hostile_log(folder: Path, data: bytes, capsys) -> None:
    """``ivfm report``, ``ivfm ground tlog``, ``ivfm ground ulog`` and ``ivfm identify
    --log`` on a run folder whose log is ``data``: each succeeds or exits 2 saying why
    (report: 1 for a run that reads as diverged); never a traceback, and a refused ULog
    export leaves no file."""
    import shutil

    from ground.cli.main import main

    run = folder / "run"
    shutil.rmtree(run, ignore_errors=True)
    shutil.copytree(SHORT_RUN, run)
    (run / "telemetry-000.mcap").write_bytes(data)
    for argv in (["report", str(run), "--no-figures"],
                 ["ground", "tlog", str(run / "telemetry-000.mcap"), "--out",
                  str(run / "out.tlog")],
                 ["ground", "ulog", str(run), "--out", str(run / "out.ulg")],
                 ["identify", "--log", str(run), "--out", str(run / "model.json")]):
        code = main(argv)
        err = capsys.readouterr().err
        # report: 1 is its answer for a run that diverged (a log cut short reads as one)
        assert code in ((0, 1, 2) if argv[0] == "report" else (0, 2)), (argv, code, err)
        assert "Traceback" not in err
        if code == 2:
            assert err.startswith("ivfm: error: "), err
            if argv[:2] == ["ground", "ulog"]:
                assert not (run / "out.ulg").exists()


# -- PX4 logs (ULog) -------------------------------------------------------------------------

def hostile_ulog(folder: Path, data: bytes, capsys) -> None:
    """``ivfm ulog info``, ``ivfm identify --ulog`` and ``ivfm airframe from-ulog`` on a
    PX4 log whose bytes are ``data``: each succeeds or exits 2 saying why, never a
    traceback, and writes nothing when it refuses."""
    from ground.cli.main import main

    log = folder / "flight.ulg"
    log.write_bytes(data)
    for argv, out in ((["ulog", "info", str(log), "--airframe", "quad-x-500"], None),
                      (["identify", "--ulog", str(log), "--airframe", "quad-x-500",
                        "--allow-narrow", "--out", str(folder / "model.json")],
                       folder / "model.json"),
                      (["airframe", "from-ulog", str(log), "--mass-kg", "2", "--force",
                        "--out", str(folder / "draft.toml")], folder / "draft.toml")):
        if out is not None and out.exists():
            out.unlink()
        code = main(argv)
        err = capsys.readouterr().err
        assert code in (0, 2), (argv, code, err)
        assert "Traceback" not in err
        if code == 2:
            assert "ivfm: error: " in err, err
            assert out is None or not out.exists()


def ulog_fields(path: Path) -> list[tuple[str, str, str, int]]:
    """(topic, field, type, rows) of every field of a log but the timestamps."""
    from pyulog import ULog

    ulog = ULog(str(path))
    return [(d.name, f.field_name, f.type_str, len(d.data["timestamp"]))
            for d in ulog.data_list for f in d.field_data if f.field_name != "timestamp"]


@st.composite
def ulog_edits(draw, fields: list[tuple[str, str, str, int]]) -> list[tuple[str, str, int, Any]]:
    """1-8 (topic, field, row, value) edits, each value hostile for the field's type."""
    out = []
    for _ in range(draw(st.integers(1, 8))):
        topic, name, kind, rows = draw(st.sampled_from(fields))
        row = draw(st.integers(0, rows - 1))
        if kind in ("float", "double"):
            value: Any = draw(hostile_float())
        elif kind in INT_RANGES:
            low, high = INT_RANGES[kind]
            value = draw(st.one_of(st.sampled_from((low, high, 0, 1, 2)),
                                   st.integers(low, high)))
        else:  # bool, char
            value = draw(st.integers(0, 1))
        out.append((topic, name, row, value))
    return out


def edited_ulog(seed: Path, edits: list[tuple[str, str, int, Any]], out: Path) -> bytes:
    """The seed log with each edit made, written by pyulog's writer; its bytes."""
    from pyulog import ULog

    ulog = ULog(str(seed))
    for topic, name, row, value in edits:
        data = next(d for d in ulog.data_list if d.name == topic)
        column = data.data[name].copy()
        with np.errstate(all="ignore"):
            column[row] = value
        data.data[name] = column
    ulog.write_ulog(str(out))
    return out.read_bytes()
