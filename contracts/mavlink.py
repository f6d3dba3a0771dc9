"""MAVLink conventions shared by the simulator, the autopilot and the ground side.

One place for: the dialect, ports and ids, the simulator-link message mapping (HIL_SENSOR
/ HIL_GPS / HIL_STATE_QUATERNION / ODOMETRY -> controller measurement, IMU reading, fix;
motor commands <-> HIL_ACTUATOR_CONTROLS) and MAVLink framing. The simulator's side of
the samples (its readings -> those messages) is ``contracts/sim_samples.py``; the flight
modes and their numbers are in ``contracts/modes.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink

from contracts.frames import (
    GRAVITY_MPS2,
    Home,
    altitude_from_pressure_m,
    body_to_world,
    euler_from_quat,
    euler_rates_from_body_rates,
    vector_norm,
)
from contracts.vectors import MEAS_EULER, MEAS_EULER_RATE, MEAS_POS, MEAS_VEL, MEASUREMENT

__all__ = ["ardupilotmega", "mavlink"]

# Each flavour's ground-link dialect (ArduPilot's: a superset); the simulator's: common.
DIALECTS = {"px4": mavlink, "ardupilot": ardupilotmega}

# MAVLink's global frames, each with whether its altitude is above home (else AMSL).
GLOBAL_FRAMES: dict[int, bool] = {
    mavlink.MAV_FRAME_GLOBAL: False,
    mavlink.MAV_FRAME_GLOBAL_INT: False,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: True,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: True,
}


def ned_from_global(home: Home, frame: int, lat_deg: float, lon_deg: float, alt_m: float,
                    relative_to_amsl_m: float | None = None) -> np.ndarray:
    """Local NED around ``home``; a relative altitude above ``relative_to_amsl_m``."""
    base = home.alt_amsl_m if relative_to_amsl_m is None else relative_to_amsl_m
    given = (lat_deg, lon_deg, alt_m + base if GLOBAL_FRAMES[frame] else alt_m)
    ned = home.ned_from_geodetic(*(v if math.isfinite(v) else h for v, h in zip(
        given, home, strict=True)))
    return np.where(np.isfinite(given), ned, np.nan)  # a coordinate left out stays NaN

SIM_TCP_PORT = 4560
GCS_UDP_PORT = 14550  # where a ground station listens (QGroundControl, MAVProxy)
API_UDP_PORT = 14540  # where an offboard API listens (MAVSDK)
GCS_LOCAL_PORT = 18570  # the autopilot's own ports for those two links, as PX4 SITL uses
API_LOCAL_PORT = 14580
AUTOPILOT_SYSID = 1
AUTOPILOT_COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1
SIMULATOR_SYSID = 1
SIMULATOR_COMPID = 51  # any id that is not the autopilot's

# What the autopilot flies on. "auto" (PX4's way with a simulator's ground truth) takes
# ODOMETRY when the simulator sends it and HIL_STATE_QUATERNION when it does not;
# "estimator" flies on the onboard estimator fed by HIL_SENSOR and HIL_GPS, as hardware.
# What the autopilot reads for each --state-source. On the truth, attitude, position and
# velocity come from ODOMETRY or HIL_STATE_QUATERNION and the body rates from HIL_SENSOR's
# gyro when the simulator sends it, as PX4's rate loop flies on the gyro and takes
# HIL_STATE_QUATERNION as ground truth only.
STATE_SOURCES = {"auto": ("ODOMETRY", "HIL_STATE_QUATERNION", "HIL_SENSOR"),
                 "odometry": ("ODOMETRY", "HIL_SENSOR"),
                 "hil-state": ("HIL_STATE_QUATERNION", "HIL_SENSOR"),
                 "estimator": ("HIL_GPS", "HIL_SENSOR")}
# A gyro reading rates a truth sample at most this far from its time (our simulator
# stamps both with the sample's time).
GYRO_MATCH_US = 20_000

# HIL_ACTUATOR_CONTROLS
HIL_FLAG_LOCKSTEP = 1  # flags bit 0
HIL_MODE_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
HIL_MOTORS = 4

# HIL_SENSOR fields_updated: accel 0-2, gyro 3-5, mag 6-8, abs/diff pressure, pressure alt,
# temperature 9-12 (the groups PX4's simulator_mavlink reads).
HIL_SENSOR_IMU = 0x3F
HIL_SENSOR_MAG = 0x1C0
HIL_SENSOR_BARO = 0x1E00  # absolute and differential pressure, pressure altitude, temperature
HIL_SENSOR_ABS_PRESSURE = 0x200
HIL_SENSOR_ALL_FIELDS = HIL_SENSOR_IMU | HIL_SENSOR_MAG | HIL_SENSOR_BARO
MG_PER_MPS2 = 1000.0 / GRAVITY_MPS2


def new_mavlink(sysid: int, compid: int, flavour: str = "px4") -> mavlink.MAVLink:
    """An encoder/parser for one link, in the flavour's dialect (DIALECTS). Robust
    parsing: bytes that are not a valid frame become BAD_DATA messages (which every
    receiver drops and counts) and parsing goes on, rather than an exception that would
    lose the frames behind them."""
    mav = DIALECTS[flavour].MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.robust_parsing = True
    return mav


class LinkDataError(ValueError):
    """A simulator-link message that must not reach the controller."""


def _finite(values: tuple[float, ...], what: str) -> None:
    if not all(map(math.isfinite, values)):
        raise LinkDataError(f"{what} holds NaN or infinity")


def _measurement(position, velocity, quaternion, body_rate) -> np.ndarray:
    q = np.asarray(quaternion, dtype=float)
    norm = vector_norm(q)
    if not 0.9 < norm < 1.1:
        raise LinkDataError(f"attitude quaternion has norm {norm:.3f}, not 1")
    out = np.empty(MEASUREMENT.size)
    _fill_measurement(out, *map(float, position), *map(float, velocity), q, norm,
                      *map(float, body_rate))
    return out


@njit(cache=True)
def _fill_measurement(out: np.ndarray, x: float, y: float, z: float, vx: float, vy: float,
                      vz: float, quaternion: np.ndarray, norm: float, p: float, q: float,
                      r: float) -> None:
    """The measurement of a position, a velocity, the attitude ``quaternion / norm`` and
    body rates, written in one compiled call (numpy's and numba's per-call costs are
    most of the work at this size)."""
    out[MEAS_POS], out[MEAS_POS + 1], out[MEAS_POS + 2] = x, y, z
    out[MEAS_VEL], out[MEAS_VEL + 1], out[MEAS_VEL + 2] = vx, vy, vz
    euler = euler_from_quat(quaternion / norm)
    out[MEAS_EULER:MEAS_EULER + 3] = euler
    _fill_euler_rates(out, p, q, r)


@njit(cache=True)
def _fill_euler_rates(out: np.ndarray, p: float, q: float, r: float) -> None:
    """The measurement's Euler rates from body rates (p, q, r), at its Euler angles."""
    out[MEAS_EULER_RATE:MEAS_EULER_RATE + 3] = euler_rates_from_body_rates(
        out[MEAS_EULER], out[MEAS_EULER + 1], p, q, r)


# ODOMETRY velocity frames understood (child_frame_id): NED, or body FRD as PX4 sends it.
ODOMETRY_VELOCITY_FRAMES = (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD)


def measurement_from_odometry(msg: mavlink.MAVLink_odometry_message) -> np.ndarray:
    """Controller measurement from ODOMETRY: position in LOCAL_NED, velocity in LOCAL_NED
    or BODY_FRD (turned into NED by the message's own attitude)."""
    if msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED or \
            msg.child_frame_id not in ODOMETRY_VELOCITY_FRAMES:
        raise LinkDataError(
            f"ODOMETRY frames {msg.frame_id}/{msg.child_frame_id}: position in "
            f"MAV_FRAME_LOCAL_NED ({mavlink.MAV_FRAME_LOCAL_NED}) and velocity in it or in "
            f"MAV_FRAME_BODY_FRD ({mavlink.MAV_FRAME_BODY_FRD}) are understood")
    _finite((msg.x, msg.y, msg.z, *msg.q, msg.vx, msg.vy, msg.vz, msg.rollspeed,
             msg.pitchspeed, msg.yawspeed), "ODOMETRY")
    velocity = (msg.vx, msg.vy, msg.vz)
    if msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
        w, x, y, z = (float(v) for v in msg.q)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not 0.9 < norm < 1.1:
            raise LinkDataError(f"attitude quaternion has norm {norm:.3f}, not 1")
        velocity = body_to_world(w / norm, x / norm, y / norm, z / norm, *velocity)
    return _measurement((msg.x, msg.y, msg.z), velocity, msg.q,
                        (msg.rollspeed, msg.pitchspeed, msg.yawspeed))


def set_body_rates(measurement: np.ndarray, body_rate_frd_rad_s: np.ndarray) -> None:
    """The measurement's Euler rates from these body rates (the gyro's), in place."""
    _fill_euler_rates(measurement, *map(float, body_rate_frd_rad_s))


def measurement_from_hil_state(msg: mavlink.MAVLink_hil_state_quaternion_message,
                               home: Home) -> np.ndarray:
    """Controller measurement from HIL_STATE_QUATERNION alone (1e-7 deg, mm, cm/s)."""
    _finite((*msg.attitude_quaternion, msg.rollspeed, msg.pitchspeed, msg.yawspeed),
            "HIL_STATE_QUATERNION")
    _on_earth(msg, "HIL_STATE_QUATERNION")
    position = home.ned_from_geodetic(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
    velocity = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
    return _measurement(position, velocity, msg.attitude_quaternion,
                        (msg.rollspeed, msg.pitchspeed, msg.yawspeed))


def imu_from_hil_sensor(msg: mavlink.MAVLink_hil_sensor_message
                        ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None]:
    """(gyro FRD, specific force FRD, baro altitude AMSL [m] or NaN, magnetometer FRD
    [gauss] or None) of HIL_SENSOR, the baro and magnetometer only when fields_updated says
    they are fresh. The altitude is the standard atmosphere's for abs_pressure, as a
    flight controller computes it."""
    updated = msg.fields_updated
    if updated & HIL_SENSOR_IMU != HIL_SENSOR_IMU:
        raise LinkDataError(f"HIL_SENSOR without its IMU fields (fields_updated "
                            f"{updated:#x})")
    gyro = (msg.xgyro, msg.ygyro, msg.zgyro)
    accel = (msg.xacc, msg.yacc, msg.zacc)
    _finite((*gyro, *accel), "HIL_SENSOR's IMU")
    baro_alt = math.nan
    if updated & HIL_SENSOR_ABS_PRESSURE:
        if not (math.isfinite(msg.abs_pressure) and 100.0 < msg.abs_pressure < 1200.0):
            raise LinkDataError(f"HIL_SENSOR abs_pressure {msg.abs_pressure!r} hPa is not a "
                                "pressure in the air")
        baro_alt = altitude_from_pressure_m(msg.abs_pressure)
    mag = None
    if updated & HIL_SENSOR_MAG:
        mag = (msg.xmag, msg.ymag, msg.zmag)
        _finite(mag, "HIL_SENSOR's magnetometer")
        mag = np.array(mag)
    return np.array(gyro), np.array(accel), baro_alt, mag


def _on_earth(msg, what: str) -> None:
    if not (-90e7 <= msg.lat <= 90e7 and -180e7 <= msg.lon <= 180e7):
        raise LinkDataError(f"{what} position {msg.lat}, {msg.lon} (1e-7 deg) is not on Earth")


def home_from_message(msg: mavlink.MAVLink_message) -> Home | None:
    """The home a simulator's first HIL_STATE_QUATERNION or HIL_GPS (with a 3D fix) gives,
    as PX4 takes its reference from the first position it receives; None from others."""
    kind = msg.get_type()
    if kind == "HIL_GPS" and msg.fix_type < 3 or kind not in ("HIL_GPS",
                                                               "HIL_STATE_QUATERNION"):
        return None
    try:
        return Home.checked(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
    except ValueError as exc:
        raise LinkDataError(f"{kind} cannot be home: {exc}") from None


def fix_from_hil_gps(msg: mavlink.MAVLink_hil_gps_message, home: Home
                     ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(position NED [m] from home, velocity NED [m/s], fix type, satellites) of HIL_GPS."""
    _on_earth(msg, "HIL_GPS")
    position = np.array(home.ned_from_geodetic(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3))
    velocity = np.array((msg.vn, msg.ve, msg.vd)) * 0.01
    return position, velocity, int(msg.fix_type), int(msg.satellites_visible)


def actuator_fields(time_us: int, commands: np.ndarray, armed: bool,
                    lockstep: bool) -> tuple:
    """HIL_ACTUATOR_CONTROLS' fields: motor commands in [0, 1] on controls[0..3]; time_us
    echoes the sample they answer."""
    controls = [0.0] * 16
    controls[:HIL_MOTORS] = map(float, commands)
    return (time_us, controls, HIL_MODE_ARMED if armed else 0,
            HIL_FLAG_LOCKSTEP if lockstep else 0)


def actuator_message(time_us: int, commands: np.ndarray, armed: bool,
                     lockstep: bool) -> mavlink.MAVLink_hil_actuator_controls_message:
    return mavlink.MAVLink_hil_actuator_controls_message(
        *actuator_fields(time_us, commands, armed, lockstep))


def commands_from_actuator(msg: mavlink.MAVLink_hil_actuator_controls_message) -> np.ndarray:
    """Motor commands from HIL_ACTUATOR_CONTROLS; disarmed means all motors off."""
    values = np.array(msg.controls[:HIL_MOTORS], dtype=float).tolist()
    if not all(map(math.isfinite, values)):  # 4x cheaper than numpy
        raise LinkDataError("HIL_ACTUATOR_CONTROLS holds NaN or infinity")
    if min(values) < -1e-6 or max(values) > 1.0 + 1e-6:
        raise LinkDataError(f"motor commands must be in [0, 1], got {values}")
    if not msg.mode & HIL_MODE_ARMED:
        return np.zeros(HIL_MOTORS)
    # np.clip(commands, 0, 1) value for value (so -0.0 becomes 0.0), without its overhead
    return np.array([(1.0 if v >= 1.0 else v) if v > 0.0 else 0.0 for v in values])


STATUSTEXT_CHUNK_BYTES = 50
# MAV_SEVERITY's names without the prefix (0 EMERGENCY ... 7 DEBUG), for logs people read.
SEVERITY_NAMES = {value: entry.name.removeprefix("MAV_SEVERITY_")
                  for value, entry in mavlink.enums["MAV_SEVERITY"].items()
                  if entry.name.startswith("MAV_SEVERITY_") and not entry.name.endswith("_END")}


def statustext_messages(severity: int, text: str, chunk_id: int
                        ) -> list[mavlink.MAVLink_statustext_message]:
    """STATUSTEXT for ``text``: one message (id 0) when it fits in 50 bytes, else chunks of
    50 bytes with ``chunk_id`` (1-65535) and chunk_seq 0, 1, ...; the last chunk holds a
    NUL (an empty one when the text fills the chunks), so QGroundControl and MAVSDK
    reassemble it and no refusal loses its reason."""
    data = text.encode()
    if len(data) <= STATUSTEXT_CHUNK_BYTES:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    if not 1 <= chunk_id <= 65535:
        raise ValueError(f"STATUSTEXT chunk id must be in 1-65535, got {chunk_id}")
    chunks = [data[i:i + STATUSTEXT_CHUNK_BYTES]
              for i in range(0, len(data), STATUSTEXT_CHUNK_BYTES)]
    if len(chunks[-1]) == STATUSTEXT_CHUNK_BYTES:
        chunks.append(b"")  # pymavlink pads with NULs: an empty chunk ends the text
    return [mavlink.MAVLink_statustext_message(severity, chunk, chunk_id, seq)
            for seq, chunk in enumerate(chunks[:256])]


class StatustextAssembler:
    """Whole texts from STATUSTEXT messages, chunked or not (the receiving side of
    ``statustext_messages``): ``add`` returns a text when it is complete."""

    def __init__(self, max_pending: int = 16) -> None:
        self.max_pending = max_pending
        self._pending: dict[tuple[int, int], list[str]] = {}

    def add(self, msg: mavlink.MAVLink_statustext_message) -> str | None:
        text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
        if not msg.id:
            return text
        key = (msg.get_srcSystem(), msg.id)
        parts = self._pending.setdefault(key, [])
        if msg.chunk_seq != len(parts):  # a chunk lost or out of order: start again
            parts.clear()
            if msg.chunk_seq != 0:
                del self._pending[key]
                return None
        parts.append(text)
        if len(text.encode()) < STATUSTEXT_CHUNK_BYTES:  # it held a NUL: the last chunk
            del self._pending[key]
            return "".join(parts)
        if len(self._pending) > self.max_pending:  # bounded: the oldest is dropped
            del self._pending[next(iter(self._pending))]
        return None


def frame_size(buffer: bytes, i: int) -> int:
    """Length of the MAVLink frame starting at ``buffer[i]`` from its header (signature
    included); 0 if its header is incomplete, -1 if no frame starts there. Bytes or a
    uint8 array (compiled as ``contracts.mavlink_codec.frame_length``)."""
    magic = buffer[i]
    if magic == 0xFD:
        return 12 + buffer[i + 1] + (13 if buffer[i + 2] & 1 else 0) if i + 10 <= len(buffer) \
            else 0
    if magic == 0xFE:
        return 8 + buffer[i + 1] if i + 6 <= len(buffer) else 0
    return -1


def frame_msgid(buffer: bytes, i: int) -> int:
    """Message id of the frame whose header starts at ``buffer[i]``."""
    if buffer[i] == 0xFD:
        return buffer[i + 7] | buffer[i + 8] << 8 | buffer[i + 9] << 16
    return buffer[i + 5]


def split_frames(buffer: bytes) -> tuple[list[tuple[int, bytes]], bytes]:
    """Cut a byte stream into whole MAVLink frames ``(msgid, frame)`` and the remainder.

    Lets a receiver hand pymavlink only the frames it reads (the autopilot needs one
    message of the simulator's four). Bytes that are not a frame start are passed on as
    msgid -1 for pymavlink to judge.
    """
    frames = []
    i, n = 0, len(buffer)
    while i < n:
        size = frame_size(buffer, i)
        if size < 0:
            j = i + 1
            while j < n and buffer[j] not in (0xFD, 0xFE):
                j += 1
            frames.append((-1, buffer[i:j]))
            i = j
            continue
        if size == 0 or i + size > n:
            break  # incomplete
        frames.append((frame_msgid(buffer, i), buffer[i:i + size]))
        i += size
    return frames, buffer[i:]


def datagram_frames(datagram: bytes) -> list[bytes] | None:
    """The frames of one datagram, or None unless it is whole frames end to end (a check
    on headers only: cheap enough to run on every datagram of a flood)."""
    frames = []
    i, n = 0, len(datagram)
    while i < n:
        size = frame_size(datagram, i)
        if size <= 0 or i + size > n:
            return None
        frames.append(datagram[i:i + size])
        i += size
    return frames or None
