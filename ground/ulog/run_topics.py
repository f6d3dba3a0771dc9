"""A run's records as PX4 topics: the tables ``ivfm ground ulog`` writes
(ground/ulog/export.py), one array of PX4's field layout (ground/ulog/px4_topics.py) per
topic, and the motor model that maps this project's motor commands to PX4's normalized
thrust (docs/data-format.md says how a reader inverts it).

From the autopilot's control records, at every control step: what it flew on
(vehicle_attitude, vehicle_angular_velocity, vehicle_local_position and
vehicle_global_position), its setpoints, its motor commands (actuator_motors), its status
and landed state. From the simulator's state records, at every sample: the truth, under
PX4 SITL's ``*_groundtruth`` names. From the simulator's HIL_SENSOR and HIL_GPS frames,
where the run logged them (``--log-sensors``): sensor_combined and sensor_gps. Timestamps
are the vehicle's sim time [us].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from autopilot.commander.land_detector import LANDED_ALTITUDE_M, LANDED_SPEED_MPS
from contracts.airframe_file import AirframeSpec
from contracts.frames import Home, body_rates_from_euler_rates, quat_from_euler, wrap_pi_array
from contracts.mavlink import SIMULATOR_COMPID, mavlink
from contracts.modes import FlightMode
from contracts.telemetry import FLAG_ARMED, FLAG_FAILSAFE, SITL, STATE, mavlink_key, vehicle_key
from contracts.vectors import CHANNELS, MEASUREMENT, REFERENCE
from ground.record.run_files import LogRecords, iter_messages
from ground.ulog import px4_topics as px4

# vehicle_status and vehicle_land_detected: published on a change, else once a second
# (as PX4's commander and land detector do).
STATUS_PERIOD_US = 1_000_000
# The controllers whose channels are sliding surfaces s = e' + lambda e: the desired
# Euler rates follow from their logged internals (vehicle_rates_setpoint).
SLIDING_MODE_CONTROLLERS = ("ivfc", "t1fc", "smc")
ATTITUDE_GROUPS = ("ATT", "ATT", "YAW")  # the parameter group of phi, theta, psi
MODES = tuple(FlightMode)  # the control records' mode index
_CH = {name: i for i, name in enumerate(CHANNELS)}


@dataclass(frozen=True)
class RunContext:
    """What the log alone does not say: the run's own record (run.json, {} without one),
    the vehicle, its airframe and where its local frame's origin is on Earth."""

    run: dict[str, Any]
    vehicle: int
    airframe: AirframeSpec
    home: Home | None

    @property
    def parameters(self) -> dict[str, float] | None:
        return self.run.get("parameters")


# -- the motor model ---------------------------------------------------------------------

def max_thrust_n(airframe: AirframeSpec) -> np.ndarray:
    """Each rotor's thrust at full command, k W_max^2 [N]: PX4's CA_ROTORi_CT."""
    return np.array([r.thrust_coeff_ns2 * r.max_rad_s ** 2 for r in airframe.rotors])


def thrust_model_factor(airframe: AirframeSpec) -> float:
    """PX4's THR_MDL_FAC of the airframe's motor command map."""
    return px4.thrust_model_factor_of(airframe.command_map == "speed")


def normalized_thrust(commands: np.ndarray, airframe: AirframeSpec) -> np.ndarray:
    """T_i / T_max,i of motor commands c_i (clipped to [0, 1], as the plant takes them):
    what PX4's actuator_motors carries."""
    return px4.thrust_fraction(commands, thrust_model_factor(airframe))


# -- the topics --------------------------------------------------------------------------

def _rows(topic: px4.Topic, timestamp_us: np.ndarray, **values: Any) -> np.ndarray:
    """The topic's samples: every field filled from ``values`` (arrays of shape (n,) or
    (n, count)); ``timestamp_sample`` defaults to the timestamp. A value beyond float32's
    range is written as float32 writes it, infinite."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _fill(topic, timestamp_us, values)


def _fill(topic: px4.Topic, timestamp_us: np.ndarray, values: dict[str, Any]) -> np.ndarray:
    rows = np.zeros(len(timestamp_us), dtype=topic.dtype)
    values = {"timestamp": timestamp_us, **values}
    if any(f.name == "timestamp_sample" for f in topic.fields):
        values.setdefault("timestamp_sample", timestamp_us)
    for field in topic.fields:
        if field.name not in values:
            raise ValueError(f"{topic.name}.{field.name} has no values")
        data = np.asarray(values.pop(field.name))
        if field.count:
            data = np.broadcast_to(data, (len(rows), field.count))
            for i, column in enumerate(field.columns()):
                rows[column] = data[:, i]
        else:
            rows[field.name] = data
    if values:
        raise ValueError(f"{topic.name} has no field {', '.join(values)}")
    return rows


def _quaternions(euler_rad: np.ndarray) -> np.ndarray:
    return np.array([quat_from_euler(*e) for e in euler_rad]).reshape(-1, 4)


def _local_position(topic: px4.Topic, t_us: np.ndarray, position: np.ndarray,
                    velocity: np.ndarray, yaw_rad: np.ndarray, home: Home | None) -> np.ndarray:
    known = home is not None
    ref = home or Home(math.nan, math.nan, math.nan)
    return _rows(topic, t_us, xy_valid=True, z_valid=True, v_xy_valid=True, v_z_valid=True,
                 x=position[:, 0], y=position[:, 1], z=position[:, 2],
                 vx=velocity[:, 0], vy=velocity[:, 1], vz=velocity[:, 2],
                 heading=wrap_pi_array(yaw_rad), heading_good_for_control=True,
                 xy_global=known, z_global=known, ref_timestamp=t_us[:1] if known else 0,
                 ref_lat=ref.lat_deg, ref_lon=ref.lon_deg, ref_alt=ref.alt_amsl_m)


def _global_position(topic: px4.Topic, t_us: np.ndarray, position: np.ndarray,
                     home: Home) -> np.ndarray:
    geodetic = np.array([home.geodetic_from_ned(*p) if np.all(np.isfinite(p))
                         else (math.nan,) * 3 for p in position]).reshape(-1, 3)
    return _rows(topic, t_us, lat=geodetic[:, 0], lon=geodetic[:, 1], alt=geodetic[:, 2],
                 lat_lon_valid=True, alt_valid=True)


def _changes(t_us: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Indices of the rows to publish: the first, each change of ``state`` (rows of
    values), and otherwise one every STATUS_PERIOD_US (a time that went back, in a
    damaged log, publishes too)."""
    keep, last_t = [], None
    times = t_us.tolist()  # Python integers: no unsigned wrap-around
    for k, t in enumerate(times):
        if last_t is None or not np.array_equal(state[k], state[k - 1]) or \
                not 0 <= t - last_t < STATUS_PERIOD_US:
            keep.append(k)
            last_t = t
    return np.array(keep, dtype=int)


def _latest_event_time(t_us: np.ndarray, happened: np.ndarray) -> np.ndarray:
    """At each row, the time of the latest row at or before it where ``happened``
    (0 before the first)."""
    stamps = np.where(happened, t_us, 0)
    return np.maximum.accumulate(stamps)


def control_topics(c: dict[str, np.ndarray], context: RunContext) -> dict[str, np.ndarray]:
    """The topics of the autopilot's control records: what it flew on, its setpoints, its
    motor commands, its status and landed state."""
    t = c["sim_time_us"].astype(np.uint64)
    m, ref = c["measurement"], c["reference"]
    euler, rates = m[:, MEASUREMENT.euler_rad], m[:, MEASUREMENT.euler_rate_rad_s]
    position, velocity = m[:, MEASUREMENT.position_ned_m], m[:, MEASUREMENT.velocity_ned_mps]
    body_rates = np.array([body_rates_from_euler_rates(*e[:2], *r)
                           for e, r in zip(euler, rates, strict=True)]).reshape(-1, 3)
    channel_ref = c["ch_ref"]  # (n, 6): each channel's desired value (NaN: channel off)
    airframe = context.airframe
    controller = context.run.get("controller")
    out = {
        "vehicle_attitude": _rows(px4.VEHICLE_ATTITUDE, t, q=_quaternions(euler)),
        "vehicle_angular_velocity": _rows(px4.VEHICLE_ANGULAR_VELOCITY, t, xyz=body_rates),
        "vehicle_local_position": _local_position(px4.VEHICLE_LOCAL_POSITION, t, position,
                                                  velocity, euler[:, 2], context.home),
    }
    if context.home is not None:
        out["vehicle_global_position"] = _global_position(px4.VEHICLE_GLOBAL_POSITION, t,
                                                          position, context.home)
    # The position setpoint is the reference; a sliding-mode controller's x, y and z
    # channels say when their loop is off (internals NaN): PX4 marks those NaN.
    setpoint_pos = ref[:, REFERENCE.position_ned_m].copy()
    setpoint_vel = ref[:, REFERENCE.velocity_ned_mps].copy()
    setpoint_acc = ref[:, REFERENCE.accel_ned_mps2].copy()
    if controller in SLIDING_MODE_CONTROLLERS:
        for axis, channel in enumerate(("x", "y", "z")):
            off = np.isnan(channel_ref[:, _CH[channel]])
            for array in (setpoint_pos, setpoint_vel, setpoint_acc):
                array[off, axis] = np.nan
    out["vehicle_local_position_setpoint"] = _rows(
        px4.VEHICLE_LOCAL_POSITION_SETPOINT, t, x=setpoint_pos[:, 0], y=setpoint_pos[:, 1],
        z=setpoint_pos[:, 2], yaw=wrap_pi_array(ref[:, REFERENCE.start("euler_rad") + 2]),
        yawspeed=ref[:, REFERENCE.start("euler_rate_rad_s") + 2],
        vx=setpoint_vel[:, 0], vy=setpoint_vel[:, 1], vz=setpoint_vel[:, 2],
        acceleration=setpoint_acc)
    control = normalized_thrust(c["motor_commands"], airframe)
    ct = max_thrust_n(airframe)
    thrust_body = np.zeros((len(t), 3))
    thrust_body[:, 2] = -(control @ ct) / ct.sum()
    desired_euler = channel_ref[:, [_CH["phi"], _CH["theta"], _CH["psi"]]]
    out["vehicle_attitude_setpoint"] = _rows(
        px4.VEHICLE_ATTITUDE_SETPOINT, t, q_d=_quaternions(desired_euler),
        thrust_body=thrust_body)
    parameters = context.parameters
    if controller in SLIDING_MODE_CONTROLLERS and parameters is not None and all(
            f"{group}_LAM" in parameters for group in ATTITUDE_GROUPS):
        # s = e' + lambda e with e' = yd' - y': yd' = (s - lambda e) + y'.
        lam = np.array([parameters[f"{group}_LAM"] for group in ATTITUDE_GROUPS])
        channels = [_CH["phi"], _CH["theta"], _CH["psi"]]
        e = c["ch_e"][:, channels]
        e_s = c["ch_e_s"][:, channels]
        desired_rates = (e_s - lam * e) + rates
        body = np.array([body_rates_from_euler_rates(*a[:2], *r)
                         for a, r in zip(euler, desired_rates, strict=True)]).reshape(-1, 3)
        out["vehicle_rates_setpoint"] = _rows(
            px4.VEHICLE_RATES_SETPOINT, t, roll=body[:, 0], pitch=body[:, 1],
            yaw=body[:, 2], thrust_body=thrust_body)
    motors = np.full((len(t), px4.ACTUATOR_MOTORS_COUNT), np.nan)
    motors[:, :control.shape[1]] = control
    out["actuator_motors"] = _rows(px4.ACTUATOR_MOTORS, t, reversible_flags=0,
                                   control=motors)
    out["vehicle_status"] = _status(t, c["mode"], c["flags"], context.vehicle)
    armed = (c["flags"] & FLAG_ARMED) != 0
    on_ground = (-position[:, 2] < LANDED_ALTITUDE_M) & (np.abs(velocity[:, 2])
                                                          < LANDED_SPEED_MPS)
    landed = ~armed | on_ground
    keep = _changes(t, landed[:, None])
    out["vehicle_land_detected"] = _rows(
        px4.VEHICLE_LAND_DETECTED, t[keep], ground_contact=landed[keep],
        maybe_landed=landed[keep], landed=landed[keep])
    return out


def _status(t: np.ndarray, mode: np.ndarray, flags: np.ndarray, vehicle: int) -> np.ndarray:
    """vehicle_status: arming state, PX4's nav_state of the mode, failsafe."""
    bad = (mode < 0) | (mode >= len(MODES))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(f"the control record at t = {int(t[k]) / 1e6:.3f} s has mode "
                         f"{int(mode[k])}, not a mode this version knows")
    nav_state = np.array([px4.NAV_STATE_OF_MODE[MODES[int(i)]] for i in mode])
    armed = (flags & FLAG_ARMED) != 0
    failsafe = (flags & FLAG_FAILSAFE) != 0
    first = np.zeros(len(t), dtype=bool)
    first[:1] = True
    mode_changed = first | np.concatenate(([False], mode[1:] != mode[:-1]))
    armed_rose = armed & ~np.concatenate(([False], armed[:-1]))
    keep = _changes(t, np.stack([mode, armed, failsafe], axis=1))
    return _rows(
        px4.VEHICLE_STATUS, t[keep],
        armed_time=_latest_event_time(t, armed_rose)[keep],
        arming_state=np.where(armed, px4.ARMING_STATE_ARMED, px4.ARMING_STATE_DISARMED)[keep],
        nav_state_timestamp=_latest_event_time(t, mode_changed)[keep],
        nav_state=nav_state[keep], failsafe=failsafe[keep],
        vehicle_type=px4.VEHICLE_TYPE_ROTARY_WING, system_type=px4.MAV_TYPE_QUADROTOR,
        system_id=vehicle, component_id=px4.MAV_COMP_ID_AUTOPILOT1)


def truth_topics(records: LogRecords, context: RunContext) -> dict[str, np.ndarray]:
    """The simulator's truth at every sample, as PX4 SITL's ``*_groundtruth`` topics."""
    key = vehicle_key(context.vehicle, SITL, "state")
    by_time: dict[int, dict[str, Any]] = {}
    for topic, _message, data in iter_messages(records, key):
        if topic == key:
            r = STATE.decode(data)
            by_time[int(r["sim_time_us"])] = r
    if not by_time:
        return {}
    times = sorted(by_time)
    if times[0] < 0:
        raise ValueError(f"{records}: a simulator record at negative sim time {times[0]} us")
    t = np.array(times, dtype=np.uint64)
    rows = [by_time[k] for k in times]
    position = np.array([r["position_ned_m"] for r in rows])
    velocity = np.array([r["velocity_ned_mps"] for r in rows])
    yaw = np.array([r["euler_rad"][2] for r in rows])
    out = {
        "vehicle_attitude_groundtruth": _rows(
            px4.VEHICLE_ATTITUDE_GROUNDTRUTH, t,
            q=np.array([r["quaternion"] for r in rows])),
        "vehicle_angular_velocity_groundtruth": _rows(
            px4.VEHICLE_ANGULAR_VELOCITY_GROUNDTRUTH, t,
            xyz=np.array([r["body_rate_rad_s"] for r in rows])),
        "vehicle_local_position_groundtruth": _local_position(
            px4.VEHICLE_LOCAL_POSITION_GROUNDTRUTH, t, position, velocity, yaw, context.home),
    }
    if context.home is not None:
        out["vehicle_global_position_groundtruth"] = _global_position(
            px4.VEHICLE_GLOBAL_POSITION_GROUNDTRUTH, t, position, context.home)
    return out


def sensor_topics(records: LogRecords, context: RunContext) -> dict[str, np.ndarray]:
    """The simulator's readings as the autopilot got them, where the run logged them
    (the simulator's ``--log-sensors``): sensor_combined and sensor_gps. None logged:
    neither topic."""
    prefix = mavlink_key(context.vehicle, SIMULATOR_COMPID, "")
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True  # a damaged frame is BAD_DATA, skipped
    sensors, fixes = [], []
    for topic, _message, data in iter_messages(records, prefix):
        if not topic.startswith(prefix):
            continue
        for msg in parser.parse_buffer(data) or []:
            kind = msg.get_type()
            if kind == "HIL_SENSOR":
                sensors.append(msg)
            elif kind == "HIL_GPS":
                fixes.append(msg)
    return readings_topics(sensors, fixes)


def readings_topics(sensors: list, fixes: list) -> dict[str, np.ndarray]:
    """sensor_combined of HIL_SENSOR messages and sensor_gps of HIL_GPS messages, in
    time order, in PX4's units: HIL_GPS's integers scaled back (degE7, mm, cm/s,
    centidegrees), its eph/epv read as centimetres as PX4's simulator_mavlink reads them
    (this simulator fills them with the dilution of precision x 100, also written as
    hdop/vdop)."""
    out = {}
    if sensors:
        sensors = sorted(sensors, key=lambda m: m.time_usec)
        t = np.array([m.time_usec for m in sensors], dtype=np.uint64)
        dt = np.diff(t.astype(np.int64), prepend=0)
        dt[0] = dt[1] if len(dt) > 1 else 0  # the first sample's period: the next one's
        out["sensor_combined"] = _rows(
            px4.SENSOR_COMBINED, t,
            gyro_rad=np.array([(m.xgyro, m.ygyro, m.zgyro) for m in sensors]),
            gyro_integral_dt=dt, accelerometer_timestamp_relative=0,
            accelerometer_m_s2=np.array([(m.xacc, m.yacc, m.zacc) for m in sensors]),
            accelerometer_integral_dt=dt)
    if fixes:
        fixes = sorted(fixes, key=lambda m: m.time_usec)
        t = np.array([m.time_usec for m in fixes], dtype=np.uint64)

        def scaled(name: str, scale: float) -> np.ndarray:
            return np.array([getattr(m, name) for m in fixes], dtype=float) * scale

        out["sensor_gps"] = _rows(
            px4.SENSOR_GPS, t, device_id=0,
            latitude_deg=scaled("lat", 1e-7), longitude_deg=scaled("lon", 1e-7),
            altitude_msl_m=scaled("alt", 1e-3), fix_type=scaled("fix_type", 1),
            eph=scaled("eph", 1e-2), epv=scaled("epv", 1e-2),
            hdop=scaled("eph", 1e-2), vdop=scaled("epv", 1e-2),
            vel_m_s=scaled("vel", 1e-2), vel_n_m_s=scaled("vn", 1e-2),
            vel_e_m_s=scaled("ve", 1e-2), vel_d_m_s=scaled("vd", 1e-2),
            cog_rad=wrap_pi_array(np.radians(scaled("cog", 1e-2))), vel_ned_valid=True,
            satellites_used=scaled("satellites_visible", 1))
    return out
