"""The PX4 topics, fields, numbers and parameter names this project's ULog files use, as
data: one definition per topic, written in PX4's own message syntax (``float32[4] q``)
with the fields it carries, and the PX4 message it comes from (PX4-Autopilot's
``msg/``, current main). PX4's names and types, never our own: a PX4 tool reads the file
as one of its logs. Fields a topic does not carry are left out, not filled with zeros
(a ULog names its fields; a reader looks them up by name).

No pyulog here: the definitions are plain data, importable anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from contracts.modes import FlightMode

# PX4 message types -> ULog's type names and sizes.
ULOG_TYPES: dict[str, tuple[str, str]] = {  # msg type: (ULog type, numpy type)
    "uint64": ("uint64_t", "<u8"), "int64": ("int64_t", "<i8"),
    "float64": ("double", "<f8"), "uint32": ("uint32_t", "<u4"), "int32": ("int32_t", "<i4"),
    "float32": ("float", "<f4"), "uint16": ("uint16_t", "<u2"), "int16": ("int16_t", "<i2"),
    "uint8": ("uint8_t", "<u1"), "int8": ("int8_t", "<i1"), "bool": ("bool", "<i1"),
}


@dataclass(frozen=True)
class Field:
    """One field as a PX4 ``.msg`` file declares it: ``float32[4] q`` is
    Field("q", "float32", 4); ``count`` 0 is a scalar."""

    name: str
    msg_type: str
    count: int = 0

    @property
    def ulog_type(self) -> str:
        return ULOG_TYPES[self.msg_type][0]

    @property
    def size(self) -> int:
        """Bytes of one element (PX4 orders a topic's fields by it)."""
        return np.dtype(ULOG_TYPES[self.msg_type][1]).itemsize

    def columns(self) -> list[str]:
        """The names a ULog reader gives its values: ``q[0]`` ... ``q[3]``, or ``x``."""
        if self.count:
            return [f"{self.name}[{i}]" for i in range(self.count)]
        return [self.name]


def parse_fields(text: str) -> tuple[Field, ...]:
    """Fields from ``.msg`` lines (``type name``, ``type[n] name``; ``#`` comments and
    constants ``type NAME = value`` skipped)."""
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue
        kind, name = line.split()
        count = 0
        if kind.endswith("]"):
            kind, size = kind[:-1].split("[")
            count = int(size)
        if kind not in ULOG_TYPES:
            raise ValueError(f"unknown PX4 field type {kind!r} in {raw!r}")
        fields.append(Field(name, kind, count))
    return tuple(fields)


@dataclass(frozen=True)
class Topic:
    """A PX4 topic as this project writes it: its name, the PX4 message that defines it
    (msg/ of PX4-Autopilot) and the fields written."""

    name: str
    message: str
    declaration: str  # the fields, in PX4's .msg syntax

    @cached_property
    def fields(self) -> tuple[Field, ...]:
        fields = parse_fields(self.declaration)
        if not fields or fields[0] != Field("timestamp", "uint64"):
            raise ValueError(f"{self.name}: every PX4 message starts with uint64 timestamp")
        return fields

    @cached_property
    def ulog_fields(self) -> tuple[Field, ...]:
        """The fields in the order PX4's logger writes them: by element size, largest
        first, in declaration order among equals (PX4's message generator packs them so);
        timestamp, the first 8-byte field, stays first."""
        return tuple(sorted(self.fields, key=lambda f: -f.size))

    @property
    def format(self) -> str:
        """The ULog format message's text: ``name:uint64_t timestamp;float[4] q;``."""
        return self.name + ":" + "".join(
            f"{f.ulog_type}{f'[{f.count}]' if f.count else ''} {f.name};"
            for f in self.ulog_fields)

    @cached_property
    def dtype(self) -> np.dtype:
        """One sample, packed, with a ULog reader's column names (``q[0]``)."""
        return np.dtype([(column, ULOG_TYPES[f.msg_type][1])
                         for f in self.ulog_fields for column in f.columns()])

    def columns(self) -> list[str]:
        return [column for f in self.ulog_fields for column in f.columns()]


# -- the topics ------------------------------------------------------------------------
# Every timestamp is the vehicle's sim time in microseconds (a run starts at 0).

_ATTITUDE = """
uint64 timestamp
uint64 timestamp_sample
float32[4] q                  # body FRD -> NED, Hamilton, [w, x, y, z]
"""
_ANGULAR_VELOCITY = """
uint64 timestamp
uint64 timestamp_sample
float32[3] xyz                # body rates FRD [rad/s]
"""
_LOCAL_POSITION = """
uint64 timestamp
uint64 timestamp_sample
bool xy_valid
bool z_valid
bool v_xy_valid
bool v_z_valid
float32 x                     # NED from home [m]
float32 y
float32 z
float32 vx                    # NED [m/s]
float32 vy
float32 vz
float32 heading               # yaw [rad]
bool heading_good_for_control
bool xy_global
bool z_global
uint64 ref_timestamp
float64 ref_lat               # home [deg]
float64 ref_lon
float32 ref_alt               # home AMSL [m]
"""
_GLOBAL_POSITION = """
uint64 timestamp
uint64 timestamp_sample
float64 lat                   # [deg]
float64 lon
float32 alt                   # AMSL [m]
bool lat_lon_valid
bool alt_valid
"""

VEHICLE_ATTITUDE = Topic("vehicle_attitude", "VehicleAttitude", _ATTITUDE)
VEHICLE_ANGULAR_VELOCITY = Topic("vehicle_angular_velocity", "VehicleAngularVelocity",
                                 _ANGULAR_VELOCITY)
VEHICLE_LOCAL_POSITION = Topic("vehicle_local_position", "VehicleLocalPosition",
                               _LOCAL_POSITION)
VEHICLE_GLOBAL_POSITION = Topic("vehicle_global_position", "VehicleGlobalPosition",
                                _GLOBAL_POSITION)
# The simulator's truth, under the names PX4's own SITL logs it.
VEHICLE_ATTITUDE_GROUNDTRUTH = Topic("vehicle_attitude_groundtruth", "VehicleAttitude",
                                     _ATTITUDE)
VEHICLE_ANGULAR_VELOCITY_GROUNDTRUTH = Topic("vehicle_angular_velocity_groundtruth",
                                             "VehicleAngularVelocity", _ANGULAR_VELOCITY)
VEHICLE_LOCAL_POSITION_GROUNDTRUTH = Topic("vehicle_local_position_groundtruth",
                                           "VehicleLocalPosition", _LOCAL_POSITION)
VEHICLE_GLOBAL_POSITION_GROUNDTRUTH = Topic("vehicle_global_position_groundtruth",
                                            "VehicleGlobalPosition", _GLOBAL_POSITION)

VEHICLE_LOCAL_POSITION_SETPOINT = Topic("vehicle_local_position_setpoint",
                                        "VehicleLocalPositionSetpoint", """
uint64 timestamp
float32 x                     # NED [m]
float32 y
float32 z
float32 yaw                   # [rad]
float32 yawspeed              # [rad/s]
float32 vx                    # [m/s]
float32 vy
float32 vz
float32[3] acceleration       # [m/s^2]
""")
VEHICLE_ATTITUDE_SETPOINT = Topic("vehicle_attitude_setpoint", "VehicleAttitudeSetpoint", """
uint64 timestamp
float32[4] q_d                # desired attitude, body FRD -> NED
float32[3] thrust_body        # normalized collective thrust, FRD: [0, 0, -T / T_max]
""")
VEHICLE_RATES_SETPOINT = Topic("vehicle_rates_setpoint", "VehicleRatesSetpoint", """
uint64 timestamp
float32 roll                  # body rates FRD [rad/s]
float32 pitch
float32 yaw
float32[3] thrust_body
""")
ACTUATOR_MOTORS = Topic("actuator_motors", "ActuatorMotors", """
uint64 timestamp
uint64 timestamp_sample
uint16 reversible_flags
float32[12] control           # normalized thrust T_i / T_max,i per motor, NaN unused
""")
VEHICLE_STATUS = Topic("vehicle_status", "VehicleStatus", """
uint64 timestamp
uint64 armed_time
uint8 arming_state
uint64 nav_state_timestamp
uint8 nav_state
bool failsafe
uint8 vehicle_type
uint8 system_type
uint8 system_id
uint8 component_id
""")
VEHICLE_LAND_DETECTED = Topic("vehicle_land_detected", "VehicleLandDetected", """
uint64 timestamp
bool ground_contact
bool maybe_landed
bool landed
""")

# The simulator's readings as the autopilot got them (HIL_SENSOR, HIL_GPS), where the run
# logged them (ivfm run --ulog): what PX4's simulator_mavlink publishes of the same.
SENSOR_COMBINED = Topic("sensor_combined", "SensorCombined", """
uint64 timestamp
float32[3] gyro_rad                   # body FRD [rad/s]
uint32 gyro_integral_dt               # sample period [us]
int32 accelerometer_timestamp_relative
float32[3] accelerometer_m_s2         # specific force, body FRD [m/s^2]
uint32 accelerometer_integral_dt      # [us]
""")
SENSOR_GPS = Topic("sensor_gps", "SensorGps", """
uint64 timestamp
uint64 timestamp_sample
uint32 device_id
float64 latitude_deg
float64 longitude_deg
float64 altitude_msl_m
uint8 fix_type                        # 0-1 none, 2 2D, 3 3D
float32 eph                           # [m], as PX4's simulator reads HIL_GPS (cm)
float32 epv
float32 hdop
float32 vdop
float32 vel_m_s                       # ground speed [m/s]
float32 vel_n_m_s
float32 vel_e_m_s
float32 vel_d_m_s
float32 cog_rad                       # course over ground [rad]
bool vel_ned_valid
uint8 satellites_used
""")

TOPICS: dict[str, Topic] = {t.name: t for t in (
    VEHICLE_ATTITUDE, VEHICLE_ANGULAR_VELOCITY, VEHICLE_LOCAL_POSITION,
    VEHICLE_GLOBAL_POSITION, VEHICLE_LOCAL_POSITION_SETPOINT, VEHICLE_ATTITUDE_SETPOINT,
    VEHICLE_RATES_SETPOINT, ACTUATOR_MOTORS, VEHICLE_STATUS, VEHICLE_LAND_DETECTED,
    VEHICLE_ATTITUDE_GROUNDTRUTH, VEHICLE_ANGULAR_VELOCITY_GROUNDTRUTH,
    VEHICLE_LOCAL_POSITION_GROUNDTRUTH, VEHICLE_GLOBAL_POSITION_GROUNDTRUTH,
    SENSOR_COMBINED, SENSOR_GPS)}
ACTUATOR_MOTORS_COUNT = 12  # ActuatorMotors.NUM_CONTROLS

# -- numbers (VehicleStatus.msg, MAVLink) ----------------------------------------------
ARMING_STATE_DISARMED, ARMING_STATE_ARMED = 1, 2
VEHICLE_TYPE_ROTARY_WING = 1
MAV_TYPE_QUADROTOR = 2
MAV_COMP_ID_AUTOPILOT1 = 1
NAVIGATION_STATES = {  # VehicleStatus.NAVIGATION_STATE_*
    "ALTCTL": 1, "POSCTL": 2, "AUTO_MISSION": 3, "AUTO_LOITER": 4, "AUTO_RTL": 5,
    "OFFBOARD": 14, "STAB": 15, "AUTO_TAKEOFF": 17, "AUTO_LAND": 18,
    "AUTO_FOLLOW_TARGET": 19, "ORBIT": 21,
}
# Our modes as PX4's nav_state. REFERENCE (the onboard reference generator) and GUIDED
# (ArduPilot's setpoint mode) follow setpoints from outside PX4's navigator: PX4's
# OFFBOARD, as the PX4 flavour's HEARTBEAT says (contracts/modes.py). BRAKE (ArduPilot
# only: stop and hold) holds where it stopped: PX4's AUTO_LOITER.
NAV_STATE_OF_MODE: dict[FlightMode, int] = {
    FlightMode.HOLD: NAVIGATION_STATES["AUTO_LOITER"],
    FlightMode.TAKEOFF: NAVIGATION_STATES["AUTO_TAKEOFF"],
    FlightMode.LAND: NAVIGATION_STATES["AUTO_LAND"],
    FlightMode.OFFBOARD: NAVIGATION_STATES["OFFBOARD"],
    FlightMode.GUIDED: NAVIGATION_STATES["OFFBOARD"],
    FlightMode.REFERENCE: NAVIGATION_STATES["OFFBOARD"],
    FlightMode.MISSION: NAVIGATION_STATES["AUTO_MISSION"],
    FlightMode.RTL: NAVIGATION_STATES["AUTO_RTL"],
    FlightMode.POSCTL: NAVIGATION_STATES["POSCTL"],
    FlightMode.ALTCTL: NAVIGATION_STATES["ALTCTL"],
    FlightMode.STABILIZED: NAVIGATION_STATES["STAB"],
    FlightMode.ORBIT: NAVIGATION_STATES["ORBIT"],
    FlightMode.FOLLOW_TARGET: NAVIGATION_STATES["AUTO_FOLLOW_TARGET"],
    FlightMode.BRAKE: NAVIGATION_STATES["AUTO_LOITER"],
}
assert set(NAV_STATE_OF_MODE) == set(FlightMode)

# -- parameters (PX4's names; INT32 where PX4 declares them so) -------------------------
# Control allocation: rotor i (0-based, PX4's numbering) at CA_ROTORi_PX/PY/PZ [m, FRD],
# thrust axis CA_ROTORi_AX/AY/AZ, CT its thrust at full normalized thrust [N], KM its
# drag torque per thrust [m] (positive for a counter-clockwise rotor).
CA_AIRFRAME = "CA_AIRFRAME"  # INT32, 0 = multirotor
CA_ROTOR_COUNT = "CA_ROTOR_COUNT"  # INT32
THR_MDL_FAC = "THR_MDL_FAC"  # normalized thrust = f c^2 + (1 - f) c of the motor command c
MPC_THR_HOVER = "MPC_THR_HOVER"  # normalized collective thrust that hovers
MAV_TYPE = "MAV_TYPE"  # INT32
MAV_SYS_ID = "MAV_SYS_ID"  # INT32
INT32_PARAMETERS = frozenset((CA_AIRFRAME, CA_ROTOR_COUNT, MAV_TYPE, MAV_SYS_ID))


# -- PX4's motor model: both ways (a run's ULog out, a PX4 log's identification in) ------

def thrust_model_factor_of(speed_command_map: bool) -> float:
    """THR_MDL_FAC of a motor command map: 1 when the command sets the rotor speed
    (T = k (c W_max)^2), 0 when it sets the thrust."""
    return 1.0 if speed_command_map else 0.0


def thrust_fraction(signal: np.ndarray, thr_mdl_fac: float) -> np.ndarray:
    """Each rotor's thrust over its maximum of motor signals x (clipped to [0, 1]):
    f x^2 + (1 - f) x with f = THR_MDL_FAC."""
    x = np.clip(signal, 0.0, 1.0)
    return thr_mdl_fac * x * x + (1.0 - thr_mdl_fac) * x
ROTOR_FIELDS = ("PX", "PY", "PZ", "AX", "AY", "AZ", "CT", "KM")


def rotor_parameter(index: int, field: str) -> str:
    """``CA_ROTOR{index}_{field}``: PX4's control-allocation parameter of rotor ``index``
    (0-based)."""
    if field not in ROTOR_FIELDS:
        raise ValueError(f"no rotor parameter {field!r}; PX4 has {', '.join(ROTOR_FIELDS)}")
    return f"CA_ROTOR{index}_{field}"
