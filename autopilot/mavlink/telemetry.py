"""What the vehicle tells ground tools: telemetry messages built from the vehicle's state.

Pure message builders (no sockets, no clocks: the time since boot comes in), used by the
MAVLink server's streams and replies and by the Zenoh MAVLink mirror.
"""

from __future__ import annotations

import importlib.metadata
import math

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.mavlink.copter import (
    COPTER_DEFAULT_STREAMS,
    copter_autopilot_version,
    copter_heartbeat,
)
from autopilot.navigator.home import Places
from contracts.frames import quat_from_euler as _quat_from_euler
from contracts.mavlink import ardupilotmega, mavlink
from contracts.modes import custom_mode
from contracts.vectors import (
    MEAS_EULER,
    MEAS_VEL,
    MEAS_VZ,
    MEAS_YAW,
    MEAS_Z,
    MEASUREMENT,
    MEASUREMENT_SIZE,
)

# Telemetry every link streams, message id -> default interval [s].
DEFAULT_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 0.05,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 0.05,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.05,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.1,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 5.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 0.25,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,  # PX4 streams it (DroneKit waits for it)
}
# What REQUEST_MESSAGE and SET_MESSAGE_INTERVAL can have, beyond the streams.
PRODUCIBLE = set(DEFAULT_STREAMS) | {mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                     mavlink.MAVLINK_MSG_ID_RC_CHANNELS,
                                     mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW}
# ... and in the ArduPilot flavour its dialect's messages too.
PRODUCIBLE_ARDUPILOT = PRODUCIBLE | {ardupilotmega.MAVLINK_MSG_ID_EKF_STATUS_REPORT}


def producible(flavour: str) -> set[int]:
    """The message ids the flavour can send (its dialect has them)."""
    return PRODUCIBLE_ARDUPILOT if flavour == "ardupilot" else PRODUCIBLE


def default_streams(flavour: str) -> dict[int, float]:
    """What a new link streams: PX4's set, or Copter's heartbeat alone until a tool asks
    (REQUEST_DATA_STREAM or SET_MESSAGE_INTERVAL), as Copter's SRn_* default to 0."""
    return dict(COPTER_DEFAULT_STREAMS if flavour == "ardupilot" else DEFAULT_STREAMS)

SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
           | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
           | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_AHRS)
PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK


def firmware_version(version: str) -> int:
    """AUTOPILOT_VERSION's flight_sw_version of a "major.minor.patch" package version: one
    byte each, then 0xFF (a release), as PX4 packs it."""
    major, minor, patch = (int(part) for part in (version.split(".") + ["0", "0"])[:3])
    return (major << 24) | (minor << 16) | (patch << 8) | 0xFF


FIRMWARE_VERSION = firmware_version(importlib.metadata.version("ivfm-sitl"))


def autopilot_type(flavour: str) -> int:
    return mavlink.MAV_AUTOPILOT_PX4 if flavour == "px4" else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA


def heartbeat(v: Commander, flavour: str) -> mavlink.MAVLink_heartbeat_message:
    """Arming in base_mode, the mode in custom_mode, CRITICAL while a failsafe flies
    (Copter's own rules in the ArduPilot flavour: copter.py)."""
    if flavour == "ardupilot":
        return copter_heartbeat(v)
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | \
        mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    if v.armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    status = (mavlink.MAV_STATE_CRITICAL if v.failsafe and v.armed else
              mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY)
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, autopilot_type(flavour), base, custom_mode(flavour, v.mode),
        status, 3)


def prearm_problem(v: Commander) -> str | None:
    """Why arming would be refused by the state checks (SYS_STATUS's pre-arm bit and
    Copter's "PreArm: ..." texts read it), or None."""
    if not v.sim_link_ok:
        return "no state from the simulator"
    if v.navigation_problem is not None:
        return v.navigation_problem
    if not (v.armed or v.landed):
        return "not landed"
    return None


def sys_status(v: Commander, drop_rate: float, errors: int) -> mavlink.MAVLink_sys_status_message:
    """Sensor health and the pre-arm check; PX4's meanings for the link figures:
    ``drop_rate`` (0-1) goes out in centi-percent, ``errors`` are datagrams refused."""
    health = SENSORS if v.sim_link_ok else 0
    status = v.estimator_status
    if status is not None and not status.gps_ok:
        health &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
    if prearm_problem(v) is None:
        health |= PREARM
    return mavlink.MAVLink_sys_status_message(
        SENSORS | PREARM, SENSORS | PREARM, health, 0, 12000, -1, -1,
        min(10_000, round(10_000 * drop_rate)), min(errors, 65535), 0, 0, 0, 0)


# ESTIMATOR_STATUS flags of a solution good for position control.
ESTIMATOR_GOOD = (mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_HORIZ
                  | mavlink.ESTIMATOR_VELOCITY_VERT | mavlink.ESTIMATOR_POS_HORIZ_REL
                  | mavlink.ESTIMATOR_POS_HORIZ_ABS | mavlink.ESTIMATOR_POS_VERT_ABS)


def estimator_status(v: Commander, time_us: int) -> mavlink.MAVLink_estimator_status_message:
    """ESTIMATOR_STATUS as PX4 fills it: what the solution is good for, the innovation test
    ratios (> 1: rejected) and the 1-sigma accuracies. On the simulator's truth: perfect."""
    s = v.estimator_status
    if s is None:
        flags = ESTIMATOR_GOOD if v.sim_link_ok else 0
        return mavlink.MAVLink_estimator_status_message(time_us, flags, 0, 0, 0, 0, 0, 0, 0, 0)
    flags = 0
    if s.aligned:
        flags |= mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_VERT | \
            mavlink.ESTIMATOR_POS_VERT_ABS
        if s.gps_ok:
            flags |= mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_POS_HORIZ_REL | \
                mavlink.ESTIMATOR_POS_HORIZ_ABS
        else:
            flags |= mavlink.ESTIMATOR_PRED_POS_HORIZ_REL
    if s.gps_test_ratio > 1.0:
        flags |= mavlink.ESTIMATOR_GPS_GLITCH
    return mavlink.MAVLink_estimator_status_message(
        time_us, flags, s.gps_velocity_test_ratio, s.gps_position_test_ratio,
        s.baro_test_ratio, s.mag_test_ratio, 0, 0, s.horizontal_sigma_m, s.vertical_sigma_m)


def home_items(flavour: str, mission_type: int = mavlink.MAV_MISSION_TYPE_MISSION) -> int:
    """How many items come before the stored mission on the wire: ArduPilot Copter lists
    home as item 0 of the mission (AP_Mission), so the stored item k is the tools' k + 1;
    PX4 lists the mission alone. Fences and rally points have no home item."""
    return int(flavour == "ardupilot" and mission_type == mavlink.MAV_MISSION_TYPE_MISSION)


def stored_seq(flavour: str, seq: int) -> int:
    """The stored mission's index of item ``seq`` as the flavour's tools number it; an
    ArduPilot tool's 0 (home) is the first item, as Copter restarts its mission there."""
    return max(seq - home_items(flavour), 0) if seq >= 0 else seq


def mission_current(v: Commander, flavour: str = "px4") -> mavlink.MAVLink_mission_current_message:
    """The mission's current item, its length and state (PX4 streams it at 1 Hz), numbered
    as the flavour's tools number the items (home_items)."""
    store = v.mission
    total = len(store.lists[mavlink.MAV_MISSION_TYPE_MISSION])
    if home_items(flavour):  # items 1..total after home: on the last one, seq == total
        return mavlink.MAVLink_mission_current_message(
            store.current + 1, total, MISSION_STATES[v.mission_state], 0)
    return mavlink.MAVLink_mission_current_message(store.current, total,
                                                   MISSION_STATES[v.mission_state], 0)


MISSION_STATES = {"none": mavlink.MISSION_STATE_NO_MISSION,
                  "not started": mavlink.MISSION_STATE_NOT_STARTED,
                  "active": mavlink.MISSION_STATE_ACTIVE,
                  "paused": mavlink.MISSION_STATE_PAUSED,
                  "complete": mavlink.MISSION_STATE_COMPLETE}


def landed_state(v: Commander) -> int:
    if not v.armed or v.landed:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    if v.landing:
        return mavlink.MAV_LANDED_STATE_LANDING
    if v.takeoff_altitude_m is not None:
        return mavlink.MAV_LANDED_STATE_TAKEOFF
    return mavlink.MAV_LANDED_STATE_IN_AIR


def home_position(places: Places) -> mavlink.MAVLink_home_position_message:
    """HOME_POSITION: home on Earth and in the local frame (x, y, z from the origin)."""
    home = places.home
    return mavlink.MAVLink_home_position_message(
        round(home.lat_deg * 1e7), round(home.lon_deg * 1e7), round(home.alt_amsl_m * 1000),
        *(float(v) for v in places.home_ned_m), [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)


def autopilot_version() -> mavlink.MAVLink_autopilot_version_message:
    # PX4's: an INT32 parameter's bytes travel in PARAM_VALUE's float field (BYTEWISE).
    caps = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
            | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)
    return mavlink.MAVLink_autopilot_version_message(
        caps, FIRMWARE_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1, [0] * 18)


# A simulated receiver's GPS: what GPS_RAW_INT says of a fix (SITL's GPS reports these).
GPS_SATELLITES = 10
GPS_EPH_CM = 121  # HDOP 1.21 x 100, as ArduPilot SITL's simulated GPS
UINT16_MAX = 65535


def gps_ok(v: Commander) -> bool:
    s = v.estimator_status
    return v.sim_link_ok and (s is None or s.gps_ok)


def gps_raw_int(v: Commander, m: np.ndarray, time_us: int) -> mavlink.MAVLink_gps_raw_int_message:
    """GPS_RAW_INT of the position the vehicle flies on (a 3D fix while the simulator's
    state or the estimator's GPS is fresh, else no fix): PX4 and Copter stream it and
    DroneKit's wait_ready and is_armable read its fix type."""
    ok = gps_ok(v)
    lat, lon, alt = v.places.origin.geodetic_from_ned(*m[MEASUREMENT.position_ned_m])
    vn, ve = float(m[MEAS_VEL]), float(m[MEAS_VEL + 1])
    cog = int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100)) % 36000
    return mavlink.MAVLink_gps_raw_int_message(
        time_us, mavlink.GPS_FIX_TYPE_3D_FIX if ok else mavlink.GPS_FIX_TYPE_NO_FIX,
        int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
        GPS_EPH_CM if ok else UINT16_MAX, GPS_EPH_CM if ok else UINT16_MAX,
        min(UINT16_MAX - 1, int(round(math.hypot(vn, ve) * 100))), cog,
        GPS_SATELLITES if ok else 0)


# EKF_STATUS_REPORT of a healthy solution (ArduPilot SITL's 0x33F: attitude, velocities,
# relative and absolute horizontal position, vertical position, and the predicted ones).
EKF_HEALTHY = (ardupilotmega.EKF_ATTITUDE | ardupilotmega.EKF_VELOCITY_HORIZ
               | ardupilotmega.EKF_VELOCITY_VERT | ardupilotmega.EKF_POS_HORIZ_REL
               | ardupilotmega.EKF_POS_HORIZ_ABS | ardupilotmega.EKF_POS_VERT_ABS
               | ardupilotmega.EKF_PRED_POS_HORIZ_REL | ardupilotmega.EKF_PRED_POS_HORIZ_ABS)


def ekf_status_report(v: Commander) -> ardupilotmega.MAVLink_ekf_status_report_message:
    """EKF_STATUS_REPORT (ArduPilot's dialect) from the onboard estimator's status, or
    healthy while flying on the simulator's truth; DroneKit's is_armable reads
    PRED_POS_HORIZ_ABS. The variances are the estimator's innovation test ratios."""
    s = v.estimator_status
    if s is None:
        flags = EKF_HEALTHY if v.sim_link_ok else ardupilotmega.EKF_UNINITIALIZED
        return ardupilotmega.MAVLink_ekf_status_report_message(flags, 0, 0, 0, 0, 0, 0)
    flags = 0
    if s.aligned:
        flags |= ardupilotmega.EKF_ATTITUDE | ardupilotmega.EKF_VELOCITY_VERT | \
            ardupilotmega.EKF_POS_VERT_ABS
        if s.gps_ok:
            flags |= ardupilotmega.EKF_VELOCITY_HORIZ | ardupilotmega.EKF_POS_HORIZ_REL | \
                ardupilotmega.EKF_POS_HORIZ_ABS | ardupilotmega.EKF_PRED_POS_HORIZ_REL | \
                ardupilotmega.EKF_PRED_POS_HORIZ_ABS
        else:
            flags |= ardupilotmega.EKF_CONST_POS_MODE
    else:
        flags |= ardupilotmega.EKF_UNINITIALIZED
    if s.gps_test_ratio > 1.0:
        flags |= ardupilotmega.EKF_GPS_GLITCHING
    return ardupilotmega.MAVLink_ekf_status_report_message(
        flags, s.gps_velocity_test_ratio, s.gps_position_test_ratio, s.baro_test_ratio,
        s.mag_test_ratio, 0.0, 0.0)


RC_CHANNELS = 18


def rc_channels(v: Commander, boot_ms: int) -> mavlink.MAVLink_rc_channels_message:
    """RC_CHANNELS from the vehicle's ``rc_channels_pwm`` (18 values, 0: no channel);
    without RC all 0 and chancount 0, as Copter sends it; rssi 255: unknown."""
    pwm = [int(c) for c in v.rc_channels_pwm][:RC_CHANNELS]
    pwm += [0] * (RC_CHANNELS - len(pwm))
    count = max((i + 1 for i, c in enumerate(pwm) if c), default=0)
    return mavlink.MAVLink_rc_channels_message(boot_ms, count, *pwm, 255)


PWM_MIN_US, PWM_MAX_US = 1000, 2000  # Copter's MOT_PWM_MIN / MOT_PWM_MAX defaults


def servo_output_raw(v: Commander, time_us: int) -> mavlink.MAVLink_servo_output_raw_message:
    """SERVO_OUTPUT_RAW: the motors' PWM, 1000 + 1000 x command (disarmed: 1000, as
    Copter's outputs at MOT_PWM_MIN), in the airframe's motor order on servos 1-4."""
    commands = np.clip(np.asarray(v.last_commands, dtype=float), 0.0, 1.0) if v.armed \
        else np.zeros(4)
    pwm = [int(round(PWM_MIN_US + (PWM_MAX_US - PWM_MIN_US) * c)) for c in commands[:4]]
    return mavlink.MAVLink_servo_output_raw_message(
        time_us & 0xFFFFFFFF, 0, *pwm, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


def telemetry_message(msg_id: int, v: Commander, flavour: str, boot_ms: int,
                      drop_rate: float = 0.0, errors: int = 0):
    """The telemetry message ``msg_id`` now (raises ValueError for one not produced)."""
    m = v.measurement if v.measurement is not None else np.zeros(MEASUREMENT_SIZE)
    if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        return heartbeat(v, flavour)
    if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
        return sys_status(v, drop_rate, errors)
    if msg_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_MC,
                                                          landed_state(v))
    if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
        return mavlink.MAVLink_attitude_message(boot_ms, *m[MEASUREMENT.euler_rad],
                                                *m[MEASUREMENT.euler_rate_rad_s])
    if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
        q = _quat_from_euler(m[MEAS_EULER], m[MEAS_EULER + 1], m[MEAS_YAW])
        return mavlink.MAVLink_attitude_quaternion_message(
            boot_ms, *q, *m[MEASUREMENT.euler_rate_rad_s], [0.0, 0.0, 0.0, 0.0])
    if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
        return mavlink.MAVLink_local_position_ned_message(
            boot_ms, *m[MEASUREMENT.position_ned_m], *m[MEASUREMENT.velocity_ned_mps])
    if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        places = v.places
        lat, lon, alt = places.origin.geodetic_from_ned(*m[MEASUREMENT.position_ned_m])
        heading = int(math.degrees(m[MEAS_YAW]) % 360.0 * 100) % 36000
        return mavlink.MAVLink_global_position_int_message(
            boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
            int(round(places.above_home_m(m[MEAS_Z]) * 1000)),
            *(int(min(max(round(c * 100), -32768), 32767))  # np.clip's, 10x cheaper
              for c in m[MEASUREMENT.velocity_ned_mps]), heading)
    if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
        return home_position(v.places)
    if msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
        speed = float(np.hypot(m[MEAS_VEL], m[MEAS_VEL + 1]))
        heading = int(math.degrees(m[MEAS_YAW]) % 360.0)
        throttle = int(round(100 * float(np.mean(v.last_commands))))
        return mavlink.MAVLink_vfr_hud_message(speed, speed, heading, throttle,
                                               v.places.origin.alt_amsl_m - m[MEAS_Z], -m[MEAS_VZ])
    if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        return copter_autopilot_version() if flavour == "ardupilot" else autopilot_version()
    if msg_id == mavlink.MAVLINK_MSG_ID_GPS_RAW_INT:
        return gps_raw_int(v, m, round(v.sim_t_s * 1e6))
    if msg_id == mavlink.MAVLINK_MSG_ID_RC_CHANNELS:
        return rc_channels(v, boot_ms)
    if msg_id == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
        return servo_output_raw(v, round(v.sim_t_s * 1e6))
    if msg_id == ardupilotmega.MAVLINK_MSG_ID_EKF_STATUS_REPORT and flavour == "ardupilot":
        return ekf_status_report(v)
    if msg_id == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
        return mission_current(v, flavour)
    if msg_id == mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
        return estimator_status(v, round(v.sim_t_s * 1e6))
    raise ValueError(f"no telemetry for message {msg_id}")
