"""The simulator link's frames read in one compiled pass (contracts/sim_readings.py) against
pymavlink and the Python decoders of contracts/mavlink.py: the same readings, bit for
bit, where the frame is plain and its values good; everything else left to them."""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME
from contracts.mavlink import (
    LinkDataError,
    commands_from_actuator,
    fix_from_hil_gps,
    imu_from_hil_sensor,
    mavlink,
    measurement_from_odometry,
    new_mavlink,
)
from contracts.sim_readings import (
    ACTUATORS,
    GPS,
    IMU,
    MAX_FRAMES,
    SKIP,
    SLOW,
    TRUTH,
    VALUES,
    read_frames,
)
from contracts.vectors import MEASUREMENT

HOME = np.array(DEFAULT_HOME)
WANTED = np.array([mavlink.MAVLINK_MSG_ID_ODOMETRY, mavlink.MAVLINK_MSG_ID_HIL_SENSOR,
                   mavlink.MAVLINK_MSG_ID_HIL_GPS, mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS],
                  dtype=np.int64)


def _float(rng: random.Random) -> float:
    if rng.random() < 0.05:
        return rng.choice((math.nan, math.inf, -math.inf, 0.0, -0.0, 1e30))
    return rng.gauss(0.0, 10.0 ** rng.randint(-3, 4))


def _odometry(rng: random.Random) -> mavlink.MAVLink_odometry_message:
    q = [rng.gauss(0, 1) for _ in range(4)]
    norm = math.sqrt(sum(v * v for v in q)) * (1.0 if rng.random() < 0.8 else
                                              rng.uniform(0.5, 1.5))
    frames = (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD, 7)
    return mavlink.MAVLink_odometry_message(
        rng.randint(0, 2**40), rng.choice(frames[:1] * 8 + frames[2:]),
        rng.choice(frames * 3), *(_float(rng) for _ in range(3)), [v / norm for v in q],
        *(_float(rng) for _ in range(6)), [math.nan] * 21, [math.nan] * 21, 0, 6, 100)


def _sensor(rng: random.Random) -> mavlink.MAVLink_hil_sensor_message:
    pressure = rng.choice((rng.uniform(50, 1250), rng.uniform(900, 1100), math.nan))
    bits = rng.choice((0x1FFF, 0x3F, 0x1FF, 0x1E3F, 0x3E, rng.randint(0, 0x1FFF)))
    return mavlink.MAVLink_hil_sensor_message(
        rng.randint(0, 2**40), *(_float(rng) for _ in range(9)), pressure, 0.0, 0.0, 20.0,
        bits, 0)


def _gps(rng: random.Random) -> mavlink.MAVLink_hil_gps_message:
    lat = rng.choice((rng.randint(-900_000_000, 900_000_000), 473977420 + rng.randint(-9999, 9999),
                      rng.randint(-2**31, 2**31 - 1)))
    lon = rng.choice((rng.randint(-1_800_000_000, 1_799_999_999), 85455940,
                      rng.randint(-2**31, 2**31 - 1)))
    return mavlink.MAVLink_hil_gps_message(
        rng.randint(0, 2**40), rng.randint(0, 3), lat, lon, rng.randint(-10**6, 10**7),
        80, 120, 100, *(rng.randint(-32768, 32767) for _ in range(3)), 0,
        rng.randint(0, 20))


def _actuators(rng: random.Random) -> mavlink.MAVLink_hil_actuator_controls_message:
    controls = [rng.choice((rng.random(), rng.uniform(-2e-6, 1 + 2e-6), 0.0, -0.0, 1.0))
                if rng.random() < 0.97 else rng.choice((math.nan, math.inf, 1.5, -0.2))
                for _ in range(16)]
    return mavlink.MAVLink_hil_actuator_controls_message(
        rng.randint(0, 2**40), controls, rng.choice((0, 128, 129, 255)), 1)


def _python(msg) -> tuple[str, tuple] | None:
    """What the Python decoders make of a message: (kind, values), or None (refused)."""
    try:
        kind = msg.get_type()
        if kind == "HIL_ACTUATOR_CONTROLS":
            return "commands", tuple(commands_from_actuator(msg).tolist())
        if kind == "ODOMETRY":
            return "truth", tuple(measurement_from_odometry(msg).tolist())
        if kind == "HIL_SENSOR":
            gyro, accel, baro, mag = imu_from_hil_sensor(msg)
            return "imu", (*gyro.tolist(), *accel.tolist(), baro,
                           *(mag.tolist() if mag is not None else ()))
        position, velocity, fix_type, satellites = fix_from_hil_gps(msg, DEFAULT_HOME)
        return "gps", (*position.tolist(), *velocity.tolist(), fix_type, satellites)
    except LinkDataError:
        return None


def _compiled(kind: int, row: np.ndarray) -> tuple[str, tuple]:
    if kind == TRUTH:
        return "truth", tuple(row[:MEASUREMENT.size].tolist())
    if kind == ACTUATORS:
        return "commands", tuple(row[:4].tolist())
    if kind == IMU:
        return "imu", tuple(row[:7].tolist()) + (tuple(row[7:10].tolist()) if row[10] else ())
    return "gps", (*row[:6].tolist(), int(row[6]), int(row[7]))


def _bits(values: tuple) -> tuple:
    """Floats by their bits, but NaN (the baro's "not fresh") as NaN of any sign."""
    return tuple("nan" if isinstance(v, float) and math.isnan(v) else
                 struct.pack("<d", v) if isinstance(v, float) else v for v in values)


def test_decoded_as_the_python_decoders_decode_or_left_to_them():
    rng = random.Random(3)
    mav = mavlink.MAVLink(None, 1, 51)
    decoded = refused = 0
    table = np.zeros((MAX_FRAMES, 4), dtype=np.int64)
    values = np.zeros((MAX_FRAMES, VALUES))
    for k in range(8000):
        msg = (_odometry, _sensor, _gps, _actuators)[k % 4](rng)
        try:
            frame = msg.pack(mav)
        except (struct.error, OverflowError):
            continue
        rows, used = read_frames(np.frombuffer(frame, dtype=np.uint8), WANTED, HOME, table,
                                 values)
        assert (rows, used) == (1, len(frame))
        kind = table[0, 0]
        theirs = _python(new_mavlink(1, 1).parse_buffer(frame)[0])
        if kind == SLOW:  # refused by the decoder, or a frame not decoded here (body FRD)
            assert theirs is None or msg.get_type() == "ODOMETRY" and \
                msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD, k
            refused += theirs is None
            continue
        assert theirs is not None, k
        ours = _compiled(kind, values[0])
        assert ours[0] == theirs[0] and _bits(ours[1]) == _bits(theirs[1]), k
        assert table[0, 3] == msg.time_usec
        decoded += 1
    assert decoded > 2500 and refused > 500


def test_garbage_unwanted_and_cut_frames():
    """Garbage before a frame is one SLOW row up to the next magic byte; a frame of an
    unwanted message is skipped; a frame cut off is left for the next read."""
    mav = mavlink.MAVLink(None, 1, 51)
    sensor = mavlink.MAVLink_hil_sensor_message(
        10, 0.0, 0.0, -9.81, 0.1, 0.2, 0.3, 0.2, 0.0, 0.4, 1000.0, 0.0, 100.0, 20.0,
        0x1FFF, 0).pack(mav)
    heartbeat = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mav)
    data = b"\x01\x02\x03" + heartbeat + sensor + sensor[:20]
    table = np.zeros((MAX_FRAMES, 4), dtype=np.int64)
    values = np.zeros((MAX_FRAMES, VALUES))
    rows, used = read_frames(np.frombuffer(data, dtype=np.uint8), WANTED, HOME, table, values)
    assert rows == 3 and used == len(data) - 20
    assert table[:3, :3].tolist() == [[SLOW, 0, 3], [SKIP, 3, 3 + len(heartbeat)],
                                      [IMU, 3 + len(heartbeat), used]]
    assert GPS != IMU


def test_a_read_of_more_frames_than_one_pass_holds_reads_them_all():
    """Garbage and other messages ahead of a sample, more rows than one pass of
    read_frames holds: the links' reader makes the passes a read needs, so the sample is
    read now, not left waiting for bytes that may never come (lockstep waits for it)."""
    from autopilot.process.sim_link import SimLink

    mav = mavlink.MAVLink(None, 1, 51)
    heartbeat = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mav)
    sensor = mavlink.MAVLink_hil_sensor_message(
        10, 0.0, 0.0, -9.81, 0.1, 0.2, 0.3, 0.2, 0.0, 0.4, 1000.0, 0.0, 100.0, 20.0,
        0x1FFF, 0).pack(mav)
    data = (b"\x01" + heartbeat) * (3 * MAX_FRAMES) + sensor + sensor[:7]
    link = SimLink("127.0.0.1", 0, "estimator", home=DEFAULT_HOME)
    readings = link.readings_of(data)
    assert [type(r).__name__ for r in readings] == ["ImuReading"]
    assert readings[0].time_us == 10 and readings[0].gyro.tolist() == pytest.approx(
        [0.1, 0.2, 0.3])
    assert link._pending == sensor[:7]
