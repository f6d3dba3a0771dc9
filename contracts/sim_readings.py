"""The simulator link's frames read in one compiled call: the simulator's samples into the
autopilot's readings, the autopilot's answers into the simulator's motor commands.

Why: each lockstep cycle the autopilot reads three or four frames from the simulator
(HIL_GPS, HIL_SENSOR, HIL_STATE_QUATERNION, ODOMETRY); cut, checked, parsed and decoded
one by one in Python they cost a fifth of the cycle. ``read_frames`` walks a buffer
once and, for each frame, says what it is:

* ``TRUTH``, ``IMU``, ``GPS``, ``ACTUATORS``: a plain MAVLink 2 ODOMETRY (position and
  velocity in LOCAL_NED), HIL_SENSOR, HIL_GPS or (the simulator's side)
  HIL_ACTUATOR_CONTROLS frame with a good checksum whose values pass the decoders'
  checks, decoded into its row of ``values``: exactly what ``contracts/mavlink.py``'s
  ``measurement_from_odometry``, ``imu_from_hil_sensor``, ``fix_from_hil_gps`` and
  ``commands_from_actuator`` give of it (tests/contracts/test_sim_readings.py, bit for
  bit);
* ``SKIP``: a frame of a message not wanted (``wanted``: by message id), dropped unread,
  as the autopilot's link drops it;
* ``SLOW``: everything else wanted (garbage, a damaged or signed frame, MAVLink 1, a
  message or a frame not decoded here, values a decoder refuses): for pymavlink and
  those decoders to judge, in order, so that bad input is refused and reported exactly
  as it was.

Rows of ``table``: (kind, start, end, time_us), at most MAX_FRAMES a pass; a frame cut
off at the end of the buffer is left for the next read (the returned offset).
``FrameReader`` is the links' reading with it: every pass a read needs, the rows to
objects, the rest to pymavlink.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit

from contracts.frames import (
    altitude_from_pressure_m_compiled,
    ned_from_geodetic_compiled,
    vector_norm,
)
from contracts.mavlink import (
    HIL_MODE_ARMED,
    HIL_MOTORS,
    HIL_SENSOR_ABS_PRESSURE,
    HIL_SENSOR_IMU,
    HIL_SENSOR_MAG,
    _fill_measurement,
    mavlink,
)
from contracts.mavlink_codec import (
    HEADER_BYTES,
    MAGIC_V2,
    FrameLayout,
    checked_frame,
    frame_length,
    msgid_at,
    unpack_payload,
)
from contracts.vectors import MEASUREMENT

SKIP, SLOW, TRUTH, IMU, GPS, ACTUATORS = range(6)
MAX_FRAMES = 64  # per pass of read_frames (FrameReader makes as many as a read needs)
VALUES = max(MEASUREMENT.size, 11)
# An IMU row: gyro, specific force (FRD), baro altitude AMSL [m] (NaN: not fresh),
# magnetometer (FRD) [gauss], whether the magnetometer is fresh.
IMU_GYRO, IMU_ACCEL, IMU_BARO_ALT, IMU_MAG, IMU_HAS_MAG = 0, 3, 6, 7, 10
# A GPS row: position and velocity NED, fix type, satellites.
GPS_POSITION, GPS_VELOCITY, GPS_FIX_TYPE, GPS_SATELLITES = 0, 3, 6, 7
# An ACTUATORS row: the motor commands (HIL_MOTORS) as the simulator applies them.

_OD = FrameLayout(mavlink.MAVLink_odometry_message)
_SE = FrameLayout(mavlink.MAVLink_hil_sensor_message)
_GP = FrameLayout(mavlink.MAVLink_hil_gps_message)
_AC = FrameLayout(mavlink.MAVLink_hil_actuator_controls_message)
_AC_ID, _AC_CRC, _AC_SIZE, _AC_CODES, _AC_OFFSETS = (
    _AC.msgid, _AC.crc_extra, _AC.payload_bytes, _AC.codes, _AC.offsets)
_AC_CONTROLS, _AC_MODE = _AC.index("controls"), _AC.index("mode")
_OD_ID, _OD_CRC, _OD_SIZE, _OD_CODES, _OD_OFFSETS = (
    _OD.msgid, _OD.crc_extra, _OD.payload_bytes, _OD.codes, _OD.offsets)
_SE_ID, _SE_CRC, _SE_SIZE, _SE_CODES, _SE_OFFSETS = (
    _SE.msgid, _SE.crc_extra, _SE.payload_bytes, _SE.codes, _SE.offsets)
_GP_ID, _GP_CRC, _GP_SIZE, _GP_CODES, _GP_OFFSETS = (
    _GP.msgid, _GP.crc_extra, _GP.payload_bytes, _GP.codes, _GP.offsets)
_OD_FRAME = _OD.index("frame_id")
_LOCAL_NED = mavlink.MAV_FRAME_LOCAL_NED
_N = max(len(_OD.codes), len(_SE.codes), len(_GP.codes), len(_AC.codes))


@njit(cache=True)
def _all_finite(values: np.ndarray, start: int, stop: int) -> bool:
    for i in range(start, stop):  # noqa: SIM110 (a loop numba compiles)
        if not math.isfinite(values[i]):
            return False
    return True


@njit(cache=True)
def _odometry(floats: np.ndarray, ints: np.ndarray, out: np.ndarray) -> bool:
    """``measurement_from_odometry`` of a LOCAL_NED ODOMETRY; False: not decoded here."""
    if ints[_OD_FRAME] != _LOCAL_NED or ints[_OD_FRAME + 1] != _LOCAL_NED:
        return False
    if not _all_finite(floats, 1, 14):  # x .. yawspeed
        return False
    q = floats[4:8].copy()
    norm = vector_norm(q)
    if not 0.9 < norm < 1.1:
        return False
    _fill_measurement(out, floats[1], floats[2], floats[3], floats[8], floats[9],
                      floats[10], q, norm, floats[11], floats[12], floats[13])
    return True


@njit(cache=True)
def _imu(floats: np.ndarray, ints: np.ndarray, out: np.ndarray) -> bool:
    """``imu_from_hil_sensor``; False: refused (judged again by it)."""
    updated = ints[14]
    if updated & HIL_SENSOR_IMU != HIL_SENSOR_IMU or not _all_finite(floats, 1, 7):
        return False
    for i in range(3):
        out[IMU_GYRO + i] = floats[4 + i]
        out[IMU_ACCEL + i] = floats[1 + i]
    out[IMU_BARO_ALT] = math.nan
    if updated & HIL_SENSOR_ABS_PRESSURE:
        pressure = floats[10]
        if not (math.isfinite(pressure) and 100.0 < pressure < 1200.0):
            return False
        out[IMU_BARO_ALT] = altitude_from_pressure_m_compiled(pressure)
    out[IMU_HAS_MAG] = 0.0
    if updated & HIL_SENSOR_MAG:
        if not _all_finite(floats, 7, 10):
            return False
        for i in range(3):
            out[IMU_MAG + i] = floats[7 + i]
        out[IMU_HAS_MAG] = 1.0
    return True


@njit(cache=True)
def _gps(ints: np.ndarray, home: np.ndarray, out: np.ndarray) -> bool:
    """``fix_from_hil_gps``; False: refused (judged again by it)."""
    lat, lon = ints[1], ints[2]
    if not (-90e7 <= lat <= 90e7 and -180e7 <= lon <= 180e7):
        return False
    north, east, down = ned_from_geodetic_compiled(home[0], home[1], home[2], lat * 1e-7,
                                                   lon * 1e-7, ints[3] * 1e-3)
    out[GPS_POSITION], out[GPS_POSITION + 1], out[GPS_POSITION + 2] = north, east, down
    for i in range(3):
        out[GPS_VELOCITY + i] = ints[7 + i] * 0.01
    out[GPS_FIX_TYPE] = ints[11]
    out[GPS_SATELLITES] = ints[12]
    return True


@njit(cache=True)
def _actuators(floats: np.ndarray, ints: np.ndarray, out: np.ndarray) -> bool:
    """``commands_from_actuator``; False: refused (judged again by it)."""
    for i in range(HIL_MOTORS):
        v = floats[_AC_CONTROLS + i]
        if not math.isfinite(v) or v < -1e-6 or v > 1.0 + 1e-6:
            return False
    armed = ints[_AC_MODE] & HIL_MODE_ARMED
    for i in range(HIL_MOTORS):
        v = floats[_AC_CONTROLS + i]
        out[i] = ((1.0 if v >= 1.0 else v) if v > 0.0 else 0.0) if armed else 0.0
    return True


@njit(cache=True)
def _unpacked(buf: np.ndarray, at: int, crc_extra: int, payload_bytes: int,
              codes: np.ndarray, offsets: np.ndarray, ints: np.ndarray,
              floats: np.ndarray) -> bool:
    """The flat values of the plain frame at buf[at] into ``ints`` and ``floats``; False
    when it is not one (checked_frame)."""
    if not checked_frame(buf, at, crc_extra, payload_bytes):
        return False
    unpack_payload(buf, at + HEADER_BYTES, buf[at + 1], codes, offsets, ints, floats)
    return True


@njit(cache=True)
def _decoded(buf: np.ndarray, at: int, msgid: int, home: np.ndarray, out: np.ndarray,
             ints: np.ndarray, floats: np.ndarray) -> int:
    """The kind of a whole frame of a wanted message, its row decoded (SLOW: not)."""
    if msgid == _OD_ID:
        ok = _unpacked(buf, at, _OD_CRC, _OD_SIZE, _OD_CODES, _OD_OFFSETS, ints, floats)
        return TRUTH if ok and _odometry(floats, ints, out) else SLOW
    if msgid == _SE_ID:
        ok = _unpacked(buf, at, _SE_CRC, _SE_SIZE, _SE_CODES, _SE_OFFSETS, ints, floats)
        return IMU if ok and _imu(floats, ints, out) else SLOW
    if msgid == _GP_ID:
        ok = _unpacked(buf, at, _GP_CRC, _GP_SIZE, _GP_CODES, _GP_OFFSETS, ints, floats)
        return GPS if ok and _gps(ints, home, out) else SLOW
    if msgid == _AC_ID:
        ok = _unpacked(buf, at, _AC_CRC, _AC_SIZE, _AC_CODES, _AC_OFFSETS, ints, floats)
        return ACTUATORS if ok and _actuators(floats, ints, out) else SLOW
    return SLOW


@njit(cache=True)
def read_frames(buf: np.ndarray, wanted: np.ndarray, home: np.ndarray, table: np.ndarray,
                values: np.ndarray) -> tuple[int, int]:
    """The frames of ``buf`` into ``table`` and ``values`` (module docstring); ``wanted``
    holds the wanted message ids (none: every message). Returns (rows, bytes
    consumed)."""
    ints = np.zeros(_N, dtype=np.int64)
    floats = np.zeros(_N)
    n = buf.size
    i = 0
    rows = 0
    while i < n and rows < MAX_FRAMES:
        size = frame_length(buf, i)
        if size < 0:  # no frame starts here: garbage up to the next magic byte
            j = i + 1
            while j < n and buf[j] != MAGIC_V2 and buf[j] != 0xFE:
                j += 1
            table[rows, 0], table[rows, 1], table[rows, 2], table[rows, 3] = SLOW, i, j, 0
            rows += 1
            i = j
            continue
        if size == 0 or i + size > n:
            break  # cut off: the rest comes with the next read
        msgid = msgid_at(buf, i)
        want = wanted.size == 0
        for w in wanted:
            if w == msgid:
                want = True
        kind = SKIP
        if want:
            kind = _decoded(buf, i, msgid, home, values[rows], ints, floats) \
                if buf[i] == MAGIC_V2 else SLOW
        table[rows, 0], table[rows, 1], table[rows, 2] = kind, i, i + size
        table[rows, 3] = ints[0] if kind > SLOW else 0
        rows += 1
        i += size
    return rows, i


class FrameReader:
    """A link's reading of its received bytes: ``read_frames`` over them (as many passes
    as its rows need), the decoded rows turned into objects by ``decoded(kind, time_us,
    row)`` at once (the rows are reused), the rest parsed by the link's pymavlink parser
    in the order it came, consecutive frames in one buffer. ``wanted``: the message ids
    to read (none: every message); ``home``: latitude, longitude [deg], altitude AMSL
    [m] for HIL_GPS."""

    def __init__(self, decoded: Callable[[int, int, np.ndarray], object]) -> None:
        self.decoded = decoded
        self._table = np.zeros((MAX_FRAMES, 4), dtype=np.int64)
        self._values = np.zeros((MAX_FRAMES, VALUES))

    def read(self, data: bytes, wanted: np.ndarray, home: np.ndarray,
             mav: mavlink.MAVLink) -> tuple[list, bytes]:
        """(the messages of ``data`` in order: decoded objects and pymavlink's messages,
        BAD_DATA included; the bytes of a frame cut off at its end)."""
        buf = np.frombuffer(data, dtype=np.uint8)
        table, values = self._table, self._values
        out: list = []
        slow: list[bytes] = []
        at = 0
        while True:
            rows, used = read_frames(buf[at:], wanted, home, table, values)
            for r, (kind, start, end, time_us) in enumerate(table[:rows].tolist()):
                if kind == SKIP:
                    continue
                if kind == SLOW:
                    slow.append(data[at + start:at + end])
                    continue
                if slow:
                    out += mav.parse_buffer(b"".join(slow)) or []
                    slow.clear()
                out.append(self.decoded(kind, time_us, values[r]))
            at += used
            if rows < MAX_FRAMES:
                break
        if slow:
            out += mav.parse_buffer(b"".join(slow)) or []
        return out, data[at:]
