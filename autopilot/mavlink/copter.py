"""How the ArduPilot flavour presents itself, as ArduCopter SITL 4.5 does: HEARTBEAT's
base_mode and system_status, AUTOPILOT_VERSION, the banner texts, and the stream groups
REQUEST_DATA_STREAM starts and stops (GCS_Mavlink.cpp's STREAM_* tables, only the
messages this vehicle produces). Pure builders, as telemetry.py's.
"""

from __future__ import annotations

from autopilot.commander.commander import Commander
from contracts.mavlink import ardupilotmega as apm
from contracts.modes import FlightMode, custom_mode

# The Copter release this flavour answers as (its HEARTBEAT, version and texts).
COPTER_VERSION = (4, 5, 7)
# AUTOPILOT_VERSION.flight_custom_version: Copter puts the first 8 characters of its git
# hash there; ours names this simulator instead of a commit it is not.
CUSTOM_VERSION = b"ivfmsitl"
BANNER = (f"ArduCopter V{'.'.join(map(str, COPTER_VERSION))} "
          f"({CUSTOM_VERSION.decode()})")
FRAME_TEXT = "Frame: QUAD/X"

# Modes whose horizontal position controller runs (Copter sets GUIDED_ENABLED while
# pos_control's NE controller is active: flying in these, never on the ground disarmed).
POSITION_MODES = (FlightMode.HOLD, FlightMode.GUIDED, FlightMode.TAKEOFF, FlightMode.MISSION,
                  FlightMode.RTL, FlightMode.ORBIT, FlightMode.POSCTL, FlightMode.LAND,
                  FlightMode.FOLLOW_TARGET, FlightMode.OFFBOARD, FlightMode.REFERENCE)

CAPABILITIES = (apm.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
                | apm.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | apm.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | apm.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | apm.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | apm.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | apm.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
                | apm.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                | apm.MAV_PROTOCOL_CAPABILITY_COMPASS_CALIBRATION
                | apm.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | apm.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | apm.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
                | apm.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)


def copter_version_number() -> int:
    """flight_sw_version: major, minor, patch a byte each, then the release type."""
    major, minor, patch = COPTER_VERSION
    return (major << 24) | (minor << 16) | (patch << 8) | apm.FIRMWARE_VERSION_TYPE_OFFICIAL


def copter_heartbeat(v: Commander) -> apm.MAVLink_heartbeat_message:
    """HEARTBEAT as Copter's GCS_MAVLINK_Copter::base_mode and vehicle_system_status set
    it: STABILIZE, MANUAL_INPUT and CUSTOM_MODE always, GUIDED while the position
    controller flies, SAFETY_ARMED armed; CRITICAL in a failsafe, STANDBY landed
    (disarmed is landed), else ACTIVE."""
    base = (apm.MAV_MODE_FLAG_STABILIZE_ENABLED | apm.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            | apm.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    flying = v.armed and not v.landed
    if flying and v.mode in POSITION_MODES:
        base |= apm.MAV_MODE_FLAG_GUIDED_ENABLED
    if v.armed:
        base |= apm.MAV_MODE_FLAG_SAFETY_ARMED
    status = (apm.MAV_STATE_CRITICAL if v.failsafe and v.armed else
              apm.MAV_STATE_ACTIVE if flying else apm.MAV_STATE_STANDBY)
    return apm.MAVLink_heartbeat_message(
        apm.MAV_TYPE_QUADROTOR, apm.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
        custom_mode("ardupilot", v.mode), status, 3)


def copter_autopilot_version() -> apm.MAVLink_autopilot_version_message:
    """AUTOPILOT_VERSION with Copter's capability bits (no FTP: there is no FTP server,
    no TERRAIN: no terrain data) and its version number."""
    return apm.MAVLink_autopilot_version_message(
        CAPABILITIES, copter_version_number(), 0, 0, 0, list(CUSTOM_VERSION), [0] * 8,
        [0] * 8, 0, 0, 0, [0] * 18)


def banner_texts() -> list[str]:
    """What DO_SEND_BANNER (and a boot) says: the firmware line, then the frame."""
    return [BANNER, FRAME_TEXT]


# REQUEST_DATA_STREAM groups: MAV_DATA_STREAM id -> the messages this vehicle produces of
# Copter's group (SYS_STATUS, MISSION_CURRENT, GPS_RAW_INT of EXTENDED_STATUS; ...).
STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    apm.MAV_DATA_STREAM_RAW_SENSORS: (),
    apm.MAV_DATA_STREAM_EXTENDED_STATUS: (apm.MAVLINK_MSG_ID_SYS_STATUS,
                                          apm.MAVLINK_MSG_ID_MISSION_CURRENT,
                                          apm.MAVLINK_MSG_ID_GPS_RAW_INT),
    apm.MAV_DATA_STREAM_RC_CHANNELS: (apm.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
                                      apm.MAVLINK_MSG_ID_RC_CHANNELS),
    apm.MAV_DATA_STREAM_RAW_CONTROLLER: (),
    apm.MAV_DATA_STREAM_POSITION: (apm.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                   apm.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    apm.MAV_DATA_STREAM_EXTRA1: (apm.MAVLINK_MSG_ID_ATTITUDE,),
    apm.MAV_DATA_STREAM_EXTRA2: (apm.MAVLINK_MSG_ID_VFR_HUD,),
    apm.MAV_DATA_STREAM_EXTRA3: (apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT,),
}
# What a Copter link streams before a tool asks (SRn_* default 0): heartbeats only.
COPTER_DEFAULT_STREAMS: dict[int, float] = {apm.MAVLINK_MSG_ID_HEARTBEAT: 1.0}
STREAM_RATE_MAX_HZ = 50.0  # ArduPilot caps a stream's rate here


def data_stream_intervals(stream_id: int, rate_hz: int, start: int
                          ) -> dict[int, float | None] | None:
    """Message id -> interval [s] (None: stop) that REQUEST_DATA_STREAM asks for, or None
    for a request Copter ignores (start_stop other than 0/1, an unknown group). Rate 0 or
    start_stop 0 stops the group; ALL sets every group."""
    if start not in (0, 1):
        return None
    if stream_id == apm.MAV_DATA_STREAM_ALL:
        ids = [m for group in STREAM_GROUPS.values() for m in group]
    elif stream_id in STREAM_GROUPS:
        ids = list(STREAM_GROUPS[stream_id])
    else:
        return None
    hz = min(float(rate_hz), STREAM_RATE_MAX_HZ) if start else 0.0
    return {m: (1.0 / hz if hz > 0 else None) for m in ids}
