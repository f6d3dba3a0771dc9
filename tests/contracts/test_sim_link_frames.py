"""The simulator link's frames in compiled code (contracts/mavlink_codec.py,
contracts/sim_samples.py, contracts/sim_readings.py) against pymavlink: the same bytes
packed, and everything the compiled reader leaves alone judged by pymavlink as before,
down to the links' readings and counters on mixed streams cut anywhere. The codec's own
cross-checks over randomized fields are tests/contracts/test_mavlink_codec.py."""

from __future__ import annotations

import dataclasses
import math
import random
import struct

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME
from contracts.mavlink import (
    SIMULATOR_COMPID,
    SIMULATOR_SYSID,
    LinkDataError,
    actuator_message,
    commands_from_actuator,
    mavlink,
    new_mavlink,
    split_frames,
)
from contracts.mavlink_codec import MIRRORED, FrameLayout, pack_message
from contracts.sim_readings import MAX_FRAMES, SKIP, SLOW, VALUES, read_frames
from contracts.sim_samples import sample_frames, sample_messages

# The simulator link's messages.
CLASSES = [mavlink.MAVLink_hil_gps_message, mavlink.MAVLink_hil_sensor_message,
           mavlink.MAVLink_hil_state_quaternion_message, mavlink.MAVLink_odometry_message,
           mavlink.MAVLink_hil_actuator_controls_message]
EVERY_MESSAGE = np.zeros(0, dtype=np.int64)
INT_RANGES = {"uint8_t": (0, 2**8 - 1), "int8_t": (-2**7, 2**7 - 1),
              "uint16_t": (0, 2**16 - 1), "int16_t": (-2**15, 2**15 - 1),
              "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1),
              "uint64_t": (0, 2**64 - 1), "int64_t": (-2**63, 2**63 - 1)}
FLOAT32_MAX = 3.4028234663852886e38
SPECIAL_FLOATS = (0.0, -0.0, math.nan, math.inf, -math.inf, FLOAT32_MAX, -FLOAT32_MAX,
                  1e-45, -1e-40, 1.0, -1.0)
KEY = bytes(range(32))


def _value(kind: str, style: str, rng: random.Random) -> float | int:
    if style == "zeros":
        return 0.0 if kind == "float" else 0
    if kind == "float":
        if style == "extremes" or rng.random() < 0.3:
            return rng.choice(SPECIAL_FLOATS)
        return rng.gauss(0.0, 10.0 ** rng.randint(-6, 9))
    low, high = INT_RANGES[kind]
    if style == "extremes" or rng.random() < 0.3:
        return rng.choice((low, high, 0, 1, -1 if low < 0 else 2))
    return rng.randint(low, high)


def _zero(value: float | int) -> float | int:
    return 0.0 if isinstance(value, float) else 0


def _message(cls, style: str, rng: random.Random) -> mavlink.MAVLink_message:
    """A message of ``cls`` with values of ``style``: random, extremes, zeros, or random
    with a run of its last fields on the wire zero (trimmed by MAVLink 2)."""
    values = []
    for name, kind in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = cls.array_lengths[cls.ordered_fieldnames.index(name)]
        values.append([_value(kind, style, rng) for _ in range(n)] if n
                      else _value(kind, style, rng))
    msg = cls(*values)
    if style == "trailing zeros":
        for name in cls.ordered_fieldnames[-rng.randint(1, len(cls.fieldnames)):]:
            value = getattr(msg, name)
            setattr(msg, name, [_zero(v) for v in value] if isinstance(value, list)
                    else _zero(value))
    return msg


def _messages(count: int, seed: int):
    rng = random.Random(seed)
    styles = ("random", "extremes", "zeros", "trailing zeros")
    for k in range(count):
        yield _message(CLASSES[k % len(CLASSES)], styles[k // len(CLASSES) % 4], rng)


def _exact(value):
    """A field value comparable exactly: floats by their bits (NaN, -0.0), arrays as
    tuples (pymavlink gives lists, the layouts tuples)."""
    if isinstance(value, (list, tuple)):
        return tuple(_exact(v) for v in value)
    if isinstance(value, float):
        return struct.pack("<d", value)
    return value


def _record(msg) -> tuple:
    """What a receiver reads of a message: its type and fields (BAD_DATA: reason, bytes)."""
    if msg.get_type() == "BAD_DATA":
        return "BAD_DATA", msg.reason, bytes(msg.data)
    fields = tuple((k, _exact(getattr(msg, k))) for k in msg.get_fieldnames())
    return msg.get_type(), fields or bytes(msg.get_msgbuf())


def _pymavlink(data: bytes, sysid: int = 1, compid: int = 1) -> list[tuple]:
    return [_record(m) for m in new_mavlink(sysid, compid).parse_buffer(data) or []]


def _fields(msg: mavlink.MAVLink_message) -> tuple:
    """The message's constructor arguments."""
    return tuple(getattr(msg, name) for name in msg.fieldnames)


# -- packing ---------------------------------------------------------------------------
@pytest.mark.parametrize("cls", MIRRORED)
def test_the_mirror_streams_pack_as_pymavlink_packs_them(cls):
    """The autopilot's mirror streams, packed in compiled code from their fields."""
    rng = random.Random(cls.id)
    mav = mavlink.MAVLink(None, 1, 1)
    for k in range(200):
        msg = _message(cls, ("random", "extremes", "zeros", "trailing zeros")[k % 4], rng)
        mav.seq = k % 256
        try:
            expected = msg.pack(mav)
        except (struct.error, OverflowError):
            continue
        assert pack_message(msg, mav) == expected


def test_all_zero_payloads_keep_one_byte_and_trailing_zeros_are_trimmed():
    mav = mavlink.MAVLink(None, 1, 51)
    for cls in CLASSES:
        msg = _message(cls, "zeros", random.Random(0))
        frame = FrameLayout(cls).pack_fields(_fields(msg), mav)
        assert frame == msg.pack(mav) and frame[1] == 1 and len(frame) == 13


def test_the_simulators_samples_pack_as_pymavlink_packs_them():
    from contracts.airframe import PAPER, hover_rotor_speeds
    from sitl.plant import Plant
    from sitl.sensors import SensorSuite, read_profile
    from sitl.truth import ideal_readings, truth_sample

    plant = Plant(PAPER, "rigid-body", position_ned_m=(1.0, -2.0, -3.0),
                  euler_rad=(0.3, -0.2, 1.0), rotor_rad_s=hover_rotor_speeds(PAPER))
    plant.set_motor_commands(np.array([0.5, 0.45, 0.48, 0.47]))
    suite = SensorSuite(read_profile("typical"), 100.0, 3, DEFAULT_HOME)
    sim, twin = mavlink.MAVLink(None, 1, 51), mavlink.MAVLink(None, 1, 51)
    for k in range(300):
        plant.advance(0.01)
        s = plant.state()
        t = k * 10_000
        if k % 2:
            sample = truth_sample(t, s, np.zeros(3)), *suite.sample(t, s, np.zeros(3))
        else:
            sample = ideal_readings(t, s, np.zeros(3))
        msgs = sample_messages(*sample, DEFAULT_HOME)
        assert sample_frames(*sample, DEFAULT_HOME, sim) == b"".join(m.pack(twin)
                                                                      for m in msgs)
        sim.seq = twin.seq = (sim.seq + 1) % 256


def test_the_autopilots_answer_packs_as_pymavlink_packs_it():
    from autopilot.process.sim_link import SimLink

    link = SimLink("127.0.0.1", 0, "auto")
    rng = random.Random(8)
    for k in range(300):
        commands = np.array([rng.choice((0.0, -0.0, 1.0, rng.random())) for _ in range(4)])
        armed, lockstep = k % 3 > 0, k % 5 > 0
        link.mav.seq = k % 256
        assert link.actuators_frame(k * 10_000, commands, armed, lockstep) == \
            actuator_message(k * 10_000, commands, armed, lockstep).pack(link.mav)


def test_a_signing_link_packs_by_pymavlink_byte_for_byte():
    from autopilot.process.sim_link import SimLink

    def signing(mav: mavlink.MAVLink | None = None) -> mavlink.MAVLink:
        mav = mav or mavlink.MAVLink(None, 1, 51)
        mav.signing.secret_key, mav.signing.sign_outgoing = KEY, True
        mav.signing.link_id, mav.signing.timestamp = 3, 123_456_789
        return mav

    ours, theirs = signing(), signing()
    rng = random.Random(5)
    for k in range(40):
        msg = _message(MIRRORED[k % len(MIRRORED)], "random", rng)
        try:
            expected = msg.pack(theirs)
        except (struct.error, OverflowError):
            continue
        frame = pack_message(msg, ours)
        assert frame == expected and frame[2] == mavlink.MAVLINK_IFLAG_SIGNED
        assert ours.signing.timestamp == theirs.signing.timestamp
    link = SimLink("127.0.0.1", 0, "auto")
    signing(link.mav)
    twin = signing(mavlink.MAVLink(None, link.mav.srcSystem, link.mav.srcComponent))
    assert link.actuators_frame(7, np.full(4, 0.5), True, True) == \
        actuator_message(7, np.full(4, 0.5), True, True).pack(twin)


def test_other_messages_are_packed_by_pymavlink():
    mav = mavlink.MAVLink(None, 1, 51)
    text = mavlink.MAVLink_statustext_message(6, b"hello", 0, 0)
    assert pack_message(text, mav) == text.pack(mav)


# -- reading --------------------------------------------------------------------------
def _framed(msgid: int, payload: bytes, incompat_flags: int = 0) -> bytes:
    """A MAVLink 2 frame of ``payload`` as given (no trimming), with a good checksum."""
    body = bytes((len(payload), incompat_flags, 0, 0, 1, 1)) + \
        struct.pack("<I", msgid)[:3] + payload
    crc = mavlink.x25crc(body + bytes((mavlink.mavlink_map[msgid].crc_extra,))).crc
    return b"\xfd" + body + struct.pack("<H", crc)


def _frames_pymavlink_judges() -> dict[str, bytes]:
    """Frames of the layouts' messages that the fast path leaves to pymavlink."""
    mav = mavlink.MAVLink(None, 1, 51)
    odometry = _message(mavlink.MAVLink_odometry_message, "random", random.Random(4))
    good = odometry.pack(mav)
    signer = mavlink.MAVLink(None, 1, 51)
    signer.signing.secret_key, signer.signing.sign_outgoing = KEY, True
    actuator = actuator_message(10_000, np.full(4, 0.5), True, True)
    actuator_id = mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
    payload = struct.pack("<QQ16fB", 1, 1, *range(16), 1)
    return {
        "bad checksum": good[:-2] + bytes((good[-2] ^ 0x55, good[-1])),
        "damaged payload": good[:20] + bytes((good[20] ^ 1,)) + good[21:],
        "length byte one short": good[:1] + bytes((good[1] - 1,)) + good[2:-1],
        "MAVLink 1": actuator.pack(mav, force_mavlink1=True),
        "signed": actuator.pack(signer),
        "unknown incompatibility flag": _framed(actuator_id, payload, incompat_flags=2),
        # A sender whose dialect has more extension fields: longer, a good checksum.
        "longer than the layout": _framed(actuator_id, payload + b"\x07\x07"),
    }


def _rows(data: bytes) -> list[tuple[int, int, int]]:
    """(kind, start, end) of each row read_frames gives of ``data``, every message
    wanted."""
    table = np.zeros((MAX_FRAMES, 4), dtype=np.int64)
    values = np.zeros((MAX_FRAMES, VALUES))
    rows, _used = read_frames(np.frombuffer(data, dtype=np.uint8), EVERY_MESSAGE,
                              np.array(DEFAULT_HOME), table, values)
    return [tuple(row[:3]) for row in table[:rows].tolist()]


@pytest.mark.parametrize("case", list(_frames_pymavlink_judges()))
def test_frames_the_compiled_reader_refuses_are_judged_by_pymavlink(case):
    frame = _frames_pymavlink_judges()[case]
    assert _rows(frame)[0][0] == SLOW


def test_a_link_that_checks_signatures_reads_everything_by_pymavlink():
    """Unsigned frames are refused there (BAD_DATA, counted), good signed ones taken, as
    pymavlink alone takes them."""
    from sitl.link import AutopilotLink, LinkStats

    signer = mavlink.MAVLink(None, 1, 1)
    signer.signing.secret_key, signer.signing.sign_outgoing = KEY, True
    signer.signing.timestamp = 10**9
    msg = actuator_message(10_000, np.full(4, 0.5), True, True)
    data = msg.pack(mavlink.MAVLink(None, 1, 1)) + msg.pack(signer) + msg.pack(signer)
    link = AutopilotLink("127.0.0.1", 0, LinkStats(), lambda text: None)
    link.mav.signing.secret_key = KEY
    theirs = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
    theirs.signing.secret_key = KEY
    got = link.read(_Chunks([data]))
    expected = theirs.parse_buffer(data)
    assert [m.get_type() for m in expected] == ["BAD_DATA", "HIL_ACTUATOR_CONTROLS",
                                                "HIL_ACTUATOR_CONTROLS"]
    assert [_record(m) for m in got] == [_record(m) for m in expected[1:]]
    assert link.stats.bad_messages == 1
    assert (link.mav.signing.goodsig_count, link.mav.signing.timestamp) == (
        theirs.signing.goodsig_count, theirs.signing.timestamp)


def _mixed_stream(seed: int) -> bytes:
    """Good frames of the layouts and of other messages, garbage, and each kind of frame
    the fast path refuses, in a seeded order."""
    rng = random.Random(seed)
    mav = mavlink.MAVLink(None, 1, 51)
    parts = [m.pack(mav) for m in _messages(30, seed)]
    parts += list(_frames_pymavlink_judges().values())
    parts += [b"garbage, not mavlink", b"\x00\x01", bytes((0xFD, 3, 0)),
              mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav),
              b"\xfd\x01\x00\x00\x00\x01\x01\xff\xff\xff\x00\x12\x34"]  # unknown id
    rng.shuffle(parts)
    return b"".join(parts)


@pytest.mark.parametrize("seed", range(5))
def test_a_mixed_stream_is_read_whole_in_order(seed):
    """read_frames' rows cover a mixed stream end to end, in order; pymavlink reads the
    frames it decoded as the messages they are, and the rows it left to pymavlink as
    pymavlink reads them in the whole stream."""
    data = _mixed_stream(seed)
    rows = _rows(data)
    assert rows[0][1] == 0 and all(a[2] == b[1] for a, b in zip(rows, rows[1:], strict=False))
    decoded = [data[a:b] for kind, a, b in rows if kind > SLOW]
    assert len(decoded) >= 2  # the rest: values the decoders refuse (random fields)
    for frame in decoded:
        (msg,) = new_mavlink(1, 1).parse_buffer(frame)
        assert msg.get_type() in {cls.msgname for cls in CLASSES}
    # Parsing the rows' bytes row by row gives what parsing the whole stream gives.
    mav = new_mavlink(1, 1)
    by_rows = [m for _kind, a, b in rows for m in mav.parse_buffer(data[a:b]) or []]
    by_rows += mav.parse_buffer(data[rows[-1][2]:]) or []
    assert [_record(m) for m in by_rows] == _pymavlink(data)


# -- the links: readings and counters as before, on streams cut anywhere ----------------
class _Chunks:
    """A socket whose recv returns the given chunks one per call."""

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)

    def recv(self, _size: int) -> bytes:
        if not self.chunks:
            raise BlockingIOError
        return self.chunks.pop(0)


def _cuts(data: bytes, rng: random.Random) -> list[bytes]:
    points = sorted(rng.sample(range(1, len(data)), rng.randint(1, 8)))
    return [data[a:b] for a, b in zip([0, *points], [*points, len(data)], strict=True)]


def _exact_reading(value):
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.tobytes()
    if dataclasses.is_dataclass(value):
        return type(value).__name__, tuple(_exact_reading(getattr(value, f.name))
                                           for f in dataclasses.fields(value))
    if isinstance(value, tuple):
        return type(value).__name__, tuple(_exact_reading(v) for v in value)
    return _exact(value)


def _simulator_stream(seed: int) -> bytes:
    """What an autopilot sends the simulator, and what a broken one might."""
    rng = random.Random(seed)
    mav = mavlink.MAVLink(None, 1, 1)
    parts = []
    for k in range(12):
        commands = np.array([rng.random() for _ in range(4)])
        if k % 5 == 4:
            commands[rng.randrange(4)] = rng.choice((math.nan, 1.5, -0.2, math.inf))
        parts.append(actuator_message(k * 10_000, commands, k % 4 > 0, True).pack(mav))
    parts += list(_frames_pymavlink_judges().values())
    parts += [b"garbage, not mavlink", _message(mavlink.MAVLink_odometry_message, "random",
                                                rng).pack(mav),
              mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mav)]
    rng.shuffle(parts)
    cut = rng.randrange(len(parts))  # a frame cut short: the next one's start fills it
    parts[cut] = parts[cut][:len(parts[cut]) // 2]
    return b"".join(parts)


@pytest.mark.parametrize("seed", range(4))
def test_the_simulator_reads_the_autopilot_as_before(seed):
    """sitl's AutopilotLink.read against what it did before the layouts: one pymavlink
    parser over the received bytes, BAD_DATA counted and logged; a motor command the
    compiled reader decodes is the commands ``commands_from_actuator`` makes of it."""
    from sitl.link import Actuators, AutopilotLink, LinkStats

    def commands_record(msg) -> tuple:
        if isinstance(msg, Actuators):
            return "commands", msg.time_usec, msg.commands.tobytes()
        if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
            try:
                return "commands", msg.time_usec, commands_from_actuator(msg).tobytes()
            except LinkDataError:
                pass  # refused: the message itself goes on, for apply_actuators to refuse
        return _record(msg)

    rng = random.Random(seed)
    data = _simulator_stream(seed)
    for _ in range(25):
        chunks = _cuts(data, rng)
        said: list[str] = []
        link = AutopilotLink("127.0.0.1", 0, LinkStats(), said.append)
        conn = _Chunks(chunks)
        got = [[commands_record(m) for m in link.read(conn)] for _ in chunks]
        before = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
        expected, bad, said_before = [], 0, []
        for chunk in chunks:
            msgs = before.parse_buffer(chunk) or []
            refused = [m for m in msgs if m.get_type() == "BAD_DATA"]
            if refused:
                bad += len(refused)
                said_before.append(f"unreadable bytes from the autopilot: {refused[0].reason}")
            expected.append([commands_record(m) for m in msgs if m.get_type() != "BAD_DATA"])
        assert got == expected
        assert (link.stats.bad_messages, said) == (bad, said_before)
        assert bad > 0 and any(record[0] == "commands" for read in got for record in read)
        assert any(record[0] == "HIL_ACTUATOR_CONTROLS" for read in got for record in read)


def _autopilot_stream(seed: int) -> bytes:
    """What a simulator sends the autopilot: samples (a fix in some), one with NaN in its
    truth, and the frames the fast path refuses among them."""
    from contracts.airframe import PAPER, hover_rotor_speeds
    from sitl.plant import Plant
    from sitl.truth import ideal_readings

    rng = random.Random(seed)
    plant = Plant(PAPER, "paper", position_ned_m=(1.0, -2.0, -3.0), euler_rad=(0.3, -0.2, 1.0),
                  rotor_rad_s=hover_rotor_speeds(PAPER))
    plant.set_motor_commands(np.array([0.5, 0.45, 0.48, 0.47]))
    mav = mavlink.MAVLink(None, 1, 51)
    parts = []
    for k in range(8):
        plant.advance(0.01)
        truth, sensor, fix = ideal_readings(k * 10_000, plant.state(), np.zeros(3))
        msgs = {m.get_type(): m for m in sample_messages(truth, sensor, fix if k % 3 else None,
                                                         DEFAULT_HOME)}
        if k == 5:  # refused (LinkDataError) and counted, whichever the autopilot reads
            msgs["ODOMETRY"].vx = math.nan
            msgs["HIL_STATE_QUATERNION"].rollspeed = math.nan
            msgs["HIL_SENSOR"].xgyro = math.nan
        parts += [m.pack(mav) for m in msgs.values()]
    extra = list(_frames_pymavlink_judges().values()) + [
        b"garbage, not mavlink", mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav)]
    for part in extra:
        parts.insert(rng.randrange(len(parts) + 1), part)
    return b"".join(parts)


def _read_all(link, chunks: list[bytes]) -> list:
    """Each read's readings and the link's state after it, exactly comparable."""
    link.sock = _Chunks(chunks)
    out = []
    for _ in chunks:
        out.append(_exact_reading(tuple(link.read())))
        out.append((link.bad_messages, link.last_bad, link.odometry_seen, link.home,
                    link.home_source, link._pending))
    return out


@pytest.mark.parametrize("source", ["auto", "odometry", "hil-state", "estimator"])
@pytest.mark.parametrize("home_given", [True, False])
def test_the_autopilot_reads_the_simulator_as_before(source, home_given, monkeypatch):
    """The autopilot's SimLink.read against itself with pymavlink parsing every frame it
    wants, as before the compiled reader: the same readings, home, refusals and
    counters."""
    import autopilot.process.sim_link as sim_link
    import contracts.sim_readings as sim_readings

    def pymavlink_only(buf, wanted, home, table, values) -> tuple[int, int]:
        """read_frames' rows with nothing decoded: every wanted frame is SLOW."""
        frames, _rest = split_frames(buf.tobytes())
        at = 0
        for row, (msgid, frame) in enumerate(frames[:MAX_FRAMES]):
            kind = SLOW if msgid == -1 or msgid in wanted.tolist() else SKIP
            table[row, :3] = kind, at, at + len(frame)
            at += len(frame)
        return min(len(frames), MAX_FRAMES), at

    rng = random.Random(f"{source} {home_given}")
    data = _autopilot_stream(3)
    home = DEFAULT_HOME if home_given else None
    for _ in range(15):
        chunks = _cuts(data, rng)
        link = sim_link.SimLink("127.0.0.1", 0, source, home=home)
        got = _read_all(link, chunks)
        with monkeypatch.context() as patch:
            patch.setattr(sim_readings, "read_frames", pymavlink_only)
            assert _read_all(sim_link.SimLink("127.0.0.1", 0, source, home=home),
                             chunks) == got
        assert link.bad_messages >= 1 and link.home is not None


def test_the_actuator_answer_converts_the_same_from_either_message():
    """commands_from_actuator on pymavlink's message and the compiled reader against its
    former numpy checks: the same commands bit for bit, or the same refusal (the
    compiled reader leaves a refused one to commands_from_actuator)."""
    from contracts.mavlink import HIL_MODE_ARMED, HIL_MOTORS, LinkDataError, commands_from_actuator

    def numpy_checks(msg) -> np.ndarray:
        commands = np.array(msg.controls[:HIL_MOTORS], dtype=float)
        if not np.all(np.isfinite(commands)):
            raise LinkDataError("HIL_ACTUATOR_CONTROLS holds NaN or infinity")
        if np.any(commands < -1e-6) or np.any(commands > 1.0 + 1e-6):
            raise LinkDataError(f"motor commands must be in [0, 1], got {commands.tolist()}")
        if not msg.mode & HIL_MODE_ARMED:
            return np.zeros(HIL_MOTORS)
        return np.clip(commands, 0.0, 1.0)

    def outcome(convert, msg):
        try:
            return _exact_reading(convert(msg))
        except LinkDataError as exc:
            return str(exc)

    rng = random.Random(6)
    edges = (0.0, -0.0, 1.0, -1e-6, -2e-6, 1.0 + 1e-6, 1.000002, 0.5, math.nan, math.inf,
             -math.inf, -0.2, 1.5)
    mav = mavlink.MAVLink(None, 1, 1)
    refused = 0
    for k in range(600):
        commands = np.array([rng.choice(edges) if rng.random() < 0.4 else rng.random()
                             for _ in range(4)])
        frame = actuator_message(k, commands, k % 3 > 0, True).pack(mav)
        (heavy,) = mavlink.MAVLink(None).parse_buffer(frame)
        expected = outcome(numpy_checks, heavy)
        assert outcome(commands_from_actuator, heavy) == expected
        table = np.zeros((MAX_FRAMES, 4), dtype=np.int64)
        values = np.zeros((MAX_FRAMES, VALUES))
        read_frames(np.frombuffer(frame, dtype=np.uint8), EVERY_MESSAGE, np.zeros(3), table,
                    values)
        compiled = _exact_reading(values[0, :4].copy()) if table[0, 0] > SLOW else None
        assert compiled == (None if isinstance(expected, str) else expected)
        refused += isinstance(expected, str)
    assert 100 < refused < 500
