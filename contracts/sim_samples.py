"""The simulator link's frames, packed in compiled code: each sample the simulator sends
(its truth as HIL_STATE_QUATERNION and ODOMETRY, its IMU, magnetometer and barometer as
HIL_SENSOR, its GPS fix as HIL_GPS, in the units and integer scalings PX4's
simulator_mavlink reads) and the autopilot's answer (HIL_ACTUATOR_CONTROLS).

Each message's wire values are computed once, by the compiled ``*_values``, which
``pack_sample`` packs into one buffer without any message object (the simulator does
that every sample; the autopilot's answer is ``pack_actuators``). The Python
``*_fields`` give the same values as a pymavlink constructor's arguments, and
``*_message`` / ``sample_messages`` the pymavlink messages (for tools, tests and signing
links). Reading the frames back is ``contracts/sim_readings.py``'s, with
``contracts/mavlink.py``'s decoders for everything else.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit

from contracts.frames import GRAVITY_MPS2, Home, geodetic_from_ned_compiled, rotation_from_quat
from contracts.mavlink import MG_PER_MPS2, mavlink
from contracts.mavlink_codec import MAX_FRAME_BYTES, FrameLayout, pack_frame
from contracts.vectors import TRUTH_BODY_RATE, TRUTH_POS, TRUTH_QUAT, TRUTH_VEL

INT32_MIN, INT32_MAX = -2**31, 2**31 - 1
INT16_MIN, INT16_MAX = -32768, 32767
_NO_COVARIANCE = 21  # ODOMETRY's pose and velocity covariances: unknown (NaN)


class TruthSample(NamedTuple):
    """The simulator's true state at one sample: HIL_STATE_QUATERNION and ODOMETRY carry
    it (ground truth, what an autopilot flies on when it does not estimate)."""

    time_us: int
    position_ned_m: tuple[float, float, float]
    velocity_ned_mps: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]  # body FRD -> NED, [w, x, y, z]
    body_rate_frd_rad_s: tuple[float, float, float]
    specific_force_frd_mps2: tuple[float, float, float]  # R^T (a - g)


class SensorSample(NamedTuple):
    """HIL_SENSOR: the IMU, and the magnetometer and barometer when ``fields_updated``
    says they are fresh (sitl/sensors.py computes it)."""

    time_us: int
    accel_frd_mps2: tuple[float, float, float]  # specific force
    gyro_frd_rad_s: tuple[float, float, float]
    mag_frd_gauss: tuple[float, float, float]
    pressure_hpa: float
    pressure_alt_m: float
    temperature_c: float
    fields_updated: int  # HIL_SENSOR_* bits


class GpsSample(NamedTuple):
    """HIL_GPS: one fix, as the receiver reports it."""

    time_us: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    velocity_ned_mps: tuple[float, float, float]
    hdop: float  # horizontal dilution of precision (HIL_GPS carries it x 100)
    vdop: float
    fix_type: int  # 0-1 no fix, 2 2D, 3 3D
    satellites: int


# The messages' layouts (contracts/mavlink_codec.py) and each field's place among their
# flat values, as constants of the compiled code below.
HIL_STATE = FrameLayout(mavlink.MAVLink_hil_state_quaternion_message)
ODOMETRY = FrameLayout(mavlink.MAVLink_odometry_message)
HIL_SENSOR = FrameLayout(mavlink.MAVLink_hil_sensor_message)
HIL_GPS = FrameLayout(mavlink.MAVLink_hil_gps_message)
_HS_CODES, _HS_OFFSETS, _HS_N = HIL_STATE.codes, HIL_STATE.offsets, len(HIL_STATE.codes)
_OD_CODES, _OD_OFFSETS, _OD_N = ODOMETRY.codes, ODOMETRY.offsets, len(ODOMETRY.codes)
_SE_CODES, _SE_OFFSETS, _SE_N = HIL_SENSOR.codes, HIL_SENSOR.offsets, len(HIL_SENSOR.codes)
_GP_CODES, _GP_OFFSETS, _GP_N = HIL_GPS.codes, HIL_GPS.offsets, len(HIL_GPS.codes)
_HS_ID, _HS_CRC = HIL_STATE.msgid, HIL_STATE.crc_extra
_OD_ID, _OD_CRC = ODOMETRY.msgid, ODOMETRY.crc_extra
_SE_ID, _SE_CRC = HIL_SENSOR.msgid, HIL_SENSOR.crc_extra
_GP_ID, _GP_CRC = HIL_GPS.msgid, HIL_GPS.crc_extra
_HS_Q, _OD_Q = HIL_STATE.index("attitude_quaternion"), ODOMETRY.index("q")
_OD_COV = ODOMETRY.index("pose_covariance")
_LOCAL_NED = mavlink.MAV_FRAME_LOCAL_NED
_MOCAP = mavlink.MAV_ESTIMATOR_TYPE_MOCAP
# The sensor reading's layout (sitl/sensors.py fills it): specific force, gyro,
# magnetometer (FRD), pressure [hPa], pressure altitude [m], temperature [C], the
# HIL_SENSOR_* bits.
READING_ACCEL, READING_GYRO, READING_MAG = 0, 3, 6
READING_PRESSURE, READING_ALT, READING_TEMPERATURE, READING_FIELDS = 9, 10, 11, 12
READING_SIZE = 13
# A fix's layout: latitude, longitude [deg], altitude AMSL [m], velocity NED [m/s], hdop,
# vdop, fix type, satellites.
FIX_LAT, FIX_LON, FIX_ALT, FIX_VEL, FIX_HDOP, FIX_VDOP, FIX_TYPE, FIX_SATELLITES = (
    0, 1, 2, 3, 6, 7, 8, 9)
FIX_SIZE = 10
# The most one sample's frames take.
SAMPLE_BYTES = 4 * MAX_FRAME_BYTES


@njit(cache=True)
def _int_clamped(value: float, low: int, high: int) -> int:
    """``value`` rounded (half to even) into [low, high] (NaN: low)."""
    whole = np.rint(value)
    if not whole >= low:
        return low
    return high if whole > high else int(whole)


@njit(cache=True)
def specific_force(quaternion: np.ndarray, accel_ned: np.ndarray) -> np.ndarray:
    """R^T (a - g): what an accelerometer reads (FRD) of the kinematic acceleration
    ``accel_ned``, at the attitude ``quaternion``."""
    rot = rotation_from_quat(quaternion)
    out = np.empty(3)
    for i in range(3):
        out[i] = rot[0, i] * accel_ned[0] + rot[1, i] * accel_ned[1] + \
            rot[2, i] * (accel_ned[2] - GRAVITY_MPS2)
    return out


@njit(cache=True)
def truth_values(time_us: int, position: np.ndarray, velocity: np.ndarray,
                 quaternion: np.ndarray, body_rate: np.ndarray, specific_force: np.ndarray,
                 home: np.ndarray, hs_ints: np.ndarray, hs_floats: np.ndarray,
                 od_ints: np.ndarray, od_floats: np.ndarray) -> None:
    """The flat values of HIL_STATE_QUATERNION (its position around ``home``: latitude,
    longitude [deg], altitude AMSL [m]) and of ODOMETRY of a true state."""
    n, e, d = position[0], position[1], position[2]
    vn, ve = velocity[0], velocity[1]
    lat, lon, alt = geodetic_from_ned_compiled(home[0], home[1], home[2], n, e, d)
    speed_cm = _int_clamped(math.sqrt(vn * vn + ve * ve) * 100, 0, 65535)
    hs_ints[0] = time_us
    for i in range(4):
        hs_floats[_HS_Q + i] = quaternion[i]
        od_floats[_OD_Q + i] = quaternion[i]
    for i in range(3):
        hs_floats[_HS_Q + 4 + i] = body_rate[i]
    hs_ints[_HS_Q + 7] = _int_clamped(lat * 1e7, INT32_MIN, INT32_MAX)
    hs_ints[_HS_Q + 8] = _int_clamped(lon * 1e7, INT32_MIN, INT32_MAX)
    hs_ints[_HS_Q + 9] = _int_clamped(alt * 1000, INT32_MIN, INT32_MAX)
    for i in range(3):
        hs_ints[_HS_Q + 10 + i] = _int_clamped(velocity[i] * 100, INT16_MIN, INT16_MAX)
    hs_ints[_HS_Q + 13] = speed_cm
    hs_ints[_HS_Q + 14] = speed_cm
    for i in range(3):
        hs_ints[_HS_Q + 15 + i] = _int_clamped(specific_force[i] * MG_PER_MPS2, INT16_MIN,
                                               INT16_MAX)
    od_ints[0] = time_us
    for i in range(3):
        od_floats[1 + i] = position[i]
        od_floats[_OD_Q + 4 + i] = velocity[i]
        od_floats[_OD_Q + 7 + i] = body_rate[i]
    for i in range(2 * _NO_COVARIANCE):
        od_floats[_OD_COV + i] = math.nan
    at = _OD_COV + 2 * _NO_COVARIANCE
    od_ints[at] = _LOCAL_NED  # frame_id
    od_ints[at + 1] = _LOCAL_NED  # child_frame_id
    od_ints[at + 2] = 0  # reset_counter
    od_ints[at + 3] = _MOCAP  # estimator_type
    od_ints[at + 4] = 100  # quality


@njit(cache=True)
def sensor_values(time_us: int, reading: np.ndarray, ints: np.ndarray,
                  floats: np.ndarray) -> None:
    """The flat values of HIL_SENSOR of a reading (READING_*)."""
    ints[0] = time_us
    for i in range(9):
        floats[1 + i] = reading[i]
    floats[10] = reading[READING_PRESSURE]
    floats[11] = 0.0  # diff_pressure
    floats[12] = reading[READING_ALT]
    floats[13] = reading[READING_TEMPERATURE]
    ints[14] = int(reading[READING_FIELDS])
    ints[15] = 0  # id


@njit(cache=True)
def gps_values(time_us: int, fix: np.ndarray, ints: np.ndarray) -> None:
    """The flat values of HIL_GPS of a fix (FIX_*): all integers."""
    vn, ve, vd = fix[FIX_VEL], fix[FIX_VEL + 1], fix[FIX_VEL + 2]
    course_cdeg = math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0
    ints[0] = time_us
    ints[1] = _int_clamped(fix[FIX_LAT] * 1e7, INT32_MIN, INT32_MAX)
    ints[2] = _int_clamped(fix[FIX_LON] * 1e7, INT32_MIN, INT32_MAX)
    ints[3] = _int_clamped(fix[FIX_ALT] * 1000, INT32_MIN, INT32_MAX)
    ints[4] = _int_clamped(fix[FIX_HDOP] * 100, 0, 65535)
    ints[5] = _int_clamped(fix[FIX_VDOP] * 100, 0, 65535)
    ints[6] = _int_clamped(math.sqrt(vn * vn + ve * ve) * 100, 0, 65534)
    ints[7] = _int_clamped(vn * 100, INT16_MIN, INT16_MAX)
    ints[8] = _int_clamped(ve * 100, INT16_MIN, INT16_MAX)
    ints[9] = _int_clamped(vd * 100, INT16_MIN, INT16_MAX)
    ints[10] = _int_clamped(course_cdeg, 0, 35999)
    ints[11] = int(fix[FIX_TYPE])
    ints[12] = int(fix[FIX_SATELLITES])
    ints[13] = 0  # id
    ints[14] = 0  # yaw: not given


@njit(cache=True)
def pack_sample(out: np.ndarray, seq: int, sysid: int, compid: int, home: np.ndarray,
                time_us: int, truth: np.ndarray, accel_ned: np.ndarray, reading: np.ndarray,
                fix: np.ndarray, fix_time_us: int) -> tuple[int, int, int]:
    """One sample's frames into ``out``: HIL_GPS when a fix is out (``fix_time_us`` >= 0;
    first, so a receiver has it with the sample's IMU), HIL_SENSOR, HIL_STATE_QUATERNION
    and ODOMETRY of the true state ``truth`` (contracts/vectors.py TRUTH) and its
    kinematic acceleration, all with sequence ``seq``. Returns where the frames end,
    where the HIL_SENSOR frame ends and where the HIL_GPS frame ends (0 without one)."""
    at = 0
    gps_end = 0
    if fix_time_us >= 0:
        gp_ints = np.zeros(_GP_N, dtype=np.int64)
        gps_values(fix_time_us, fix, gp_ints)
        at = gps_end = pack_frame(out, at, gp_ints, np.zeros(_GP_N), _GP_CODES, _GP_OFFSETS,
                                  _GP_ID, _GP_CRC, seq, sysid, compid)
    se_ints, se_floats = np.zeros(_SE_N, dtype=np.int64), np.zeros(_SE_N)
    sensor_values(time_us, reading, se_ints, se_floats)
    at = sensor_end = pack_frame(out, at, se_ints, se_floats, _SE_CODES, _SE_OFFSETS,
                                 _SE_ID, _SE_CRC, seq, sysid, compid)
    hs_ints, hs_floats = np.zeros(_HS_N, dtype=np.int64), np.zeros(_HS_N)
    od_ints, od_floats = np.zeros(_OD_N, dtype=np.int64), np.zeros(_OD_N)
    quaternion = truth[TRUTH_QUAT:TRUTH_QUAT + 4]
    truth_values(time_us, truth[TRUTH_POS:TRUTH_POS + 3], truth[TRUTH_VEL:TRUTH_VEL + 3],
                 quaternion, truth[TRUTH_BODY_RATE:TRUTH_BODY_RATE + 3],
                 specific_force(quaternion, accel_ned), home, hs_ints, hs_floats, od_ints,
                 od_floats)
    at = pack_frame(out, at, hs_ints, hs_floats, _HS_CODES, _HS_OFFSETS, _HS_ID, _HS_CRC,
                    seq, sysid, compid)
    at = pack_frame(out, at, od_ints, od_floats, _OD_CODES, _OD_OFFSETS, _OD_ID, _OD_CRC,
                    seq, sysid, compid)
    return at, sensor_end, gps_end


ACTUATORS = FrameLayout(mavlink.MAVLink_hil_actuator_controls_message)
_AC_CODES, _AC_OFFSETS, _AC_N = ACTUATORS.codes, ACTUATORS.offsets, len(ACTUATORS.codes)
_AC_ID, _AC_CRC = ACTUATORS.msgid, ACTUATORS.crc_extra
_AC_FLAGS, _AC_CONTROLS = ACTUATORS.index("flags"), ACTUATORS.index("controls")
_AC_MODE = ACTUATORS.index("mode")
ACTUATORS_BYTES = MAX_FRAME_BYTES


@njit(cache=True)
def pack_actuators(out: np.ndarray, seq: int, sysid: int, compid: int, time_us: int,
                   commands: np.ndarray, mode: int, flags: int) -> int:
    """HIL_ACTUATOR_CONTROLS into ``out``: the motor commands on controls[0..3] (the rest
    zero), ``time_us`` echoing the sample they answer (``actuator_fields``' message);
    returns where the frame ends."""
    ints, floats = np.zeros(_AC_N, dtype=np.int64), np.zeros(_AC_N)
    ints[0] = time_us
    ints[_AC_FLAGS] = flags
    for i in range(commands.size):
        floats[_AC_CONTROLS + i] = commands[i]
    ints[_AC_MODE] = mode
    return pack_frame(out, 0, ints, floats, _AC_CODES, _AC_OFFSETS, _AC_ID, _AC_CRC, seq,
                      sysid, compid)


def _array(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def truth_fields(t: TruthSample, home: Home) -> tuple[tuple, tuple]:
    """The fields of HIL_STATE_QUATERNION (its position around ``home``) and of ODOMETRY
    of the true state (``truth_values``, as the simulator packs them)."""
    hs = np.zeros(_HS_N, dtype=np.int64), np.zeros(_HS_N)
    od = np.zeros(_OD_N, dtype=np.int64), np.zeros(_OD_N)
    truth_values(t.time_us, _array(t.position_ned_m), _array(t.velocity_ned_mps),
                 _array(t.quaternion), _array(t.body_rate_frd_rad_s),
                 _array(t.specific_force_frd_mps2), _array(home), *hs, *od)
    return HIL_STATE.fields(*hs), ODOMETRY.fields(*od)


def sensor_reading(s: SensorSample) -> np.ndarray:
    """The reading (READING_*) of a sensor sample."""
    return _array((*s.accel_frd_mps2, *s.gyro_frd_rad_s, *s.mag_frd_gauss, s.pressure_hpa,
                   s.pressure_alt_m, s.temperature_c, s.fields_updated))


def gps_fix(g: GpsSample) -> np.ndarray:
    """The fix (FIX_*) of a GPS sample."""
    return _array((g.lat_deg, g.lon_deg, g.alt_amsl_m, *g.velocity_ned_mps, g.hdop, g.vdop,
                   g.fix_type, g.satellites))


def sensor_fields(s: SensorSample) -> tuple:
    """The fields of HIL_SENSOR."""
    values = np.zeros(_SE_N, dtype=np.int64), np.zeros(_SE_N)
    sensor_values(s.time_us, sensor_reading(s), *values)
    return HIL_SENSOR.fields(*values)


def gps_fields(g: GpsSample) -> tuple:
    """The fields of HIL_GPS."""
    ints = np.zeros(_GP_N, dtype=np.int64)
    gps_values(g.time_us, gps_fix(g), ints)
    return HIL_GPS.fields(ints, np.zeros(_GP_N))


def truth_messages(t: TruthSample, home: Home) -> list[mavlink.MAVLink_message]:
    """HIL_STATE_QUATERNION and ODOMETRY of the true state."""
    hil_state, odometry = truth_fields(t, home)
    return [mavlink.MAVLink_hil_state_quaternion_message(*hil_state),
            mavlink.MAVLink_odometry_message(*odometry)]


def sensor_message(s: SensorSample) -> mavlink.MAVLink_hil_sensor_message:
    return mavlink.MAVLink_hil_sensor_message(*sensor_fields(s))


def gps_message(g: GpsSample) -> mavlink.MAVLink_hil_gps_message:
    return mavlink.MAVLink_hil_gps_message(*gps_fields(g))


def sample_messages(truth: TruthSample, sensor: SensorSample, gps: GpsSample | None,
                    home: Home) -> list[mavlink.MAVLink_message]:
    """One sample's messages: HIL_GPS when a fix is out (first, so a receiver has it with
    the sample's IMU), HIL_SENSOR, then the truth."""
    return ([gps_message(gps)] if gps is not None else []) + [sensor_message(sensor)] + \
        truth_messages(truth, home)


def sample_frames(truth: TruthSample, sensor: SensorSample, gps: GpsSample | None,
                  home: Home, mav: mavlink.MAVLink,
                  readings: Callable[[bytes, bytes | None], None] | None = None) -> bytes:
    """``sample_messages``' frames packed on ``mav``, byte for byte (``pack_sample``; by
    pymavlink when ``mav`` signs). ``readings``, when given, gets the HIL_SENSOR frame
    and the HIL_GPS frame (None without a fix) as sent: a log of what the autopilot
    read."""
    if mav.signing.sign_outgoing:
        msgs = sample_messages(truth, sensor, gps, home)
        frames = [m.pack(mav) for m in msgs]
        if readings is not None:
            readings(frames[1 if gps else 0], frames[0] if gps else None)
        return b"".join(frames)
    hs, od = truth_fields(truth, home)
    frames = [HIL_SENSOR.pack_fields(sensor_fields(sensor), mav),
              HIL_STATE.pack_fields(hs, mav), ODOMETRY.pack_fields(od, mav)]
    gps_frame = HIL_GPS.pack_fields(gps_fields(gps), mav) if gps is not None else None
    if readings is not None:
        readings(frames[0], gps_frame)
    return b"".join(([gps_frame] if gps_frame else []) + frames)
