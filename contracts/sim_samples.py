"""What the simulator sends each sample, and the messages that carry it: its truth
(HIL_STATE_QUATERNION, ODOMETRY), its IMU, magnetometer and barometer (HIL_SENSOR) and
its GPS fix (HIL_GPS), in the units and integer scalings PX4's simulator_mavlink reads.

Each message's fields are made once, by ``*_fields`` (the arguments of its pymavlink
constructor); ``*_message`` builds the pymavlink message of them, and ``sample_frames``
packs a whole sample straight into frames (``contracts/sim_link_codec.py``) without
building the message objects: the simulator does that every sample. Reading them back is
``contracts/mavlink.py``'s (measurements, IMU readings, fixes).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from contracts.frames import Home
from contracts.mavlink import MG_PER_MPS2, mavlink
from contracts.sim_link_codec import pack_fields

INT32 = (-2**31, 2**31 - 1)
INT16 = (-32768, 32767)
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


def _int_clamped(value: float, low: int, high: int) -> int:
    """``value`` rounded (half to even) into [low, high]."""
    whole = round(value)
    return low if whole < low else high if whole > high else int(whole)


def truth_fields(t: TruthSample, home: Home) -> tuple[tuple, tuple]:
    """The fields of HIL_STATE_QUATERNION (its position around ``home``) and of ODOMETRY
    of the true state."""
    w, x, y, z = t.quaternion
    n, e, d = t.position_ned_m
    vn, ve, vd = t.velocity_ned_mps
    p, q, r = t.body_rate_frd_rad_s
    ax, ay, az = t.specific_force_frd_mps2
    lat, lon, alt = home.geodetic_from_ned(n, e, d)
    speed_cm = _int_clamped(math.hypot(vn, ve) * 100, 0, 65535)
    hil_state = (t.time_us, [w, x, y, z], p, q, r, _int_clamped(lat * 1e7, *INT32),
                 _int_clamped(lon * 1e7, *INT32), _int_clamped(alt * 1000, *INT32),
                 _int_clamped(vn * 100, *INT16), _int_clamped(ve * 100, *INT16),
                 _int_clamped(vd * 100, *INT16), speed_cm, speed_cm,
                 _int_clamped(ax * MG_PER_MPS2, *INT16), _int_clamped(ay * MG_PER_MPS2, *INT16),
                 _int_clamped(az * MG_PER_MPS2, *INT16))
    odometry = (t.time_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, n, e, d,
                [w, x, y, z], vn, ve, vd, p, q, r, [math.nan] * _NO_COVARIANCE,
                [math.nan] * _NO_COVARIANCE, 0, mavlink.MAV_ESTIMATOR_TYPE_MOCAP, 100)
    return hil_state, odometry


def sensor_fields(s: SensorSample) -> tuple:
    """The fields of HIL_SENSOR."""
    return (s.time_us, *s.accel_frd_mps2, *s.gyro_frd_rad_s, *s.mag_frd_gauss, s.pressure_hpa,
            0.0, s.pressure_alt_m, s.temperature_c, s.fields_updated, 0)


def gps_fields(g: GpsSample) -> tuple:
    """The fields of HIL_GPS."""
    vn, ve, vd = g.velocity_ned_mps
    course_cdeg = math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0
    return (g.time_us, g.fix_type, _int_clamped(g.lat_deg * 1e7, *INT32),
            _int_clamped(g.lon_deg * 1e7, *INT32), _int_clamped(g.alt_amsl_m * 1000, *INT32),
            _int_clamped(g.hdop * 100, 0, 65535), _int_clamped(g.vdop * 100, 0, 65535),
            _int_clamped(math.hypot(vn, ve) * 100, 0, 65534),
            _int_clamped(vn * 100, *INT16), _int_clamped(ve * 100, *INT16),
            _int_clamped(vd * 100, *INT16), _int_clamped(course_cdeg, 0, 35999),
            g.satellites)


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
    """``sample_messages``' frames packed on ``mav``, byte for byte, without the message
    objects. ``readings``, when given, gets the HIL_SENSOR frame and the HIL_GPS frame
    (None without a fix) as sent: a log of what the autopilot read."""
    hil_state, odometry = truth_fields(truth, home)
    sensor_frame = pack_fields(mavlink.MAVLink_hil_sensor_message, sensor_fields(sensor), mav)
    frames = [sensor_frame,
              pack_fields(mavlink.MAVLink_hil_state_quaternion_message, hil_state, mav),
              pack_fields(mavlink.MAVLink_odometry_message, odometry, mav)]
    gps_frame = None
    if gps is not None:
        gps_frame = pack_fields(mavlink.MAVLink_hil_gps_message, gps_fields(gps), mav)
        frames.insert(0, gps_frame)
    if readings is not None:
        readings(sensor_frame, gps_frame)
    return b"".join(frames)
