"""A run's MCAP log written as a PX4 flight log (ULog), for PX4's own tools: pyulog's
``ulog_info`` / ``ulog_params`` / ``ulog2csv``, PlotJuggler's ULog loader, Flight Review.

What the log holds, under PX4's topic and field names (ground/ulog/px4_topics.py, the
table in docs/ulog.md): what the autopilot flew on, its setpoints and motor commands at
every control step (the control records), the simulator's truth at every sample (PX4
SITL's ``*_groundtruth`` topics), the vehicle's status and landed state, the texts it
said (STATUSTEXT, as logged messages), the run's parameters under their PX4 names, the
airframe's rotors as PX4's control-allocation parameters and info fields naming the run.
Timestamps are the vehicle's sim time in microseconds.

The records are read with the run folder's readers (ground/record/run_files.py); the
file is built as pyulog's ``ULog`` object and written by its ``write_ulog``, whole or
not at all (contracts/atomic_file.py). Everything is read and checked before the file
is opened: a log that does not read leaves no file.
"""

from __future__ import annotations

import json
import math
import platform
import struct
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from pyulog.core import ULog

from autopilot.commander.land_detector import LANDED_ALTITUDE_M, LANDED_SPEED_MPS
from autopilot.copter_parameters import px4_parameters
from autopilot.parameters import PARAMETER_SPECS
from contracts.airframe_file import AirframeSpec, read_airframe, shipped_airframe_names
from contracts.atomic_file import atomic_writer
from contracts.frames import (
    GRAVITY_MPS2,
    Home,
    body_rates_from_euler_rates,
    quat_from_euler,
    wrap_pi_array,
)
from contracts.mavlink import AUTOPILOT_COMPID, StatustextAssembler, mavlink
from contracts.modes import FlightMode
from contracts.telemetry import (
    AUTOPILOT,
    FLAG_ARMED,
    FLAG_FAILSAFE,
    SITL,
    STATE,
    decode_json_record,
    mavlink_key,
    parse_key,
    vehicle_key,
)
from contracts.vectors import CHANNELS, MEASUREMENT, REFERENCE
from ground.record.run_files import RUN_FILE, LogRecords, control_records, iter_messages
from ground.ulog import px4_topics as px4

SYS_NAME = "IVFM-SITL"
VER_HW = "IVFM_SITL"
# vehicle_status and vehicle_land_detected: published on a change, else once a second
# (as PX4's commander and land detector do).
STATUS_PERIOD_US = 1_000_000
# The controllers whose channels are sliding surfaces s = e' + lambda e: the desired
# Euler rates follow from their logged internals (vehicle_rates_setpoint).
SLIDING_MODE_CONTROLLERS = ("ivfc", "t1fc", "smc")
ATTITUDE_GROUPS = ("ATT", "ATT", "YAW")  # the parameter group of phi, theta, psi
MODES = tuple(FlightMode)  # the control records' mode index
LOG_LEVEL_ZERO = ord("0")  # ULog's log level: '0' (emergency) ... '7' (debug), MAVLink's
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


@dataclass(frozen=True)
class LoggedText:
    timestamp_us: int
    severity: int  # MAVLink's MAV_SEVERITY: 0 emergency ... 7 debug
    text: str


@dataclass(frozen=True)
class ExportSummary:
    """What was written: samples per topic, parameters, texts, the span of sim time."""

    out: Path
    samples: dict[str, int]
    parameters: int
    messages: int
    duration_s: float

    def __str__(self) -> str:
        return (f"wrote {self.out}: {len(self.samples)} topics, "
                f"{sum(self.samples.values())} samples over {self.duration_s:.2f} s, "
                f"{self.parameters} parameters, {self.messages} logged messages")


# -- the run -----------------------------------------------------------------------------

def run_record(log: Path) -> dict[str, Any]:
    """The run.json of the run folder ``log`` is (or holds ``log``), {} if there is none."""
    log = Path(log)
    path = (log if log.is_dir() else log.parent) / RUN_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} does not read as JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} is not a JSON object")
    parameters = data.get("parameters")
    if parameters is not None and not (
            isinstance(parameters, dict) and all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in parameters.values())):
        raise ValueError(f"{path}: parameters must be an object of finite numbers")
    return data


def _vehicle(records: LogRecords, run: dict[str, Any], vehicle: int | None) -> int:
    in_log = sorted({parsed[0] for topic, _m, _d in records.messages
                     if (parsed := parse_key(topic)) is not None})
    if vehicle is None:
        vehicle = run.get("vehicle")
        if not isinstance(vehicle, int) or isinstance(vehicle, bool):
            if len(in_log) > 1:
                raise ValueError(f"{records} holds vehicles {', '.join(map(str, in_log))}: "
                                 "say which (--vehicle)")
            vehicle = in_log[0] if in_log else None
    if vehicle is None or vehicle not in in_log:
        raise ValueError(f"{records} holds no records of vehicle {vehicle}" if vehicle
                         else f"{records} holds no vehicle records")
    return vehicle


def _first_scene(records: LogRecords, vehicle: int) -> dict[str, Any] | None:
    key = vehicle_key(vehicle, AUTOPILOT, "scene")
    scenes = []
    for topic, _message, data in iter_messages(records, key):
        if topic == key:
            try:
                scenes.append(decode_json_record(data))
            except ValueError:
                continue
    return min(scenes, key=lambda s: s["seq"]) if scenes else None


def _airframe(run: dict[str, Any], scene: dict[str, Any] | None,
              given: AirframeSpec | None) -> AirframeSpec:
    """The airframe given, else the run's (run.json), else the one the log's scene record
    names if it is a shipped one; checked against the rotors the scene record drew."""
    drawn = (scene or {}).get("airframe") or {}
    if given is not None:
        spec = given
    elif isinstance(run.get("airframe"), str):
        try:
            spec = read_airframe(run["airframe"])
        except ValueError as exc:
            raise ValueError(f"the run's airframe does not read ({exc}); give the airframe "
                             "it flew (--airframe)") from None
    elif drawn.get("name") in shipped_airframe_names():
        spec = read_airframe(drawn["name"])
    else:
        raise ValueError("the log does not say which airframe flew it (no run.json beside "
                         "it, no shipped airframe in its scene record): give it (--airframe)")
    rotors = drawn.get("rotors")
    if isinstance(rotors, list):
        flown = [(r.position_m[0], r.position_m[1], r.position_m[2], r.spin)
                 for r in spec.rotors]
        try:
            same = len(rotors) == len(flown) and np.allclose(
                np.array(rotors, dtype=float), np.array(flown), rtol=0.0, atol=1e-9)
        except (TypeError, ValueError):
            same = False
        if not same:
            raise ValueError(f"the airframe {spec.name} ({spec.argument}) is not the one the "
                             f"log flew: its rotors (x, y, z, spin) are {flown}, the log's "
                             f"{rotors}")
    return spec


def _home(run: dict[str, Any], scene: dict[str, Any] | None) -> Home | None:
    """The local frame's origin: run.json's home, else the first scene record's."""
    for source in (run.get("home"), (scene or {}).get("home")):
        if isinstance(source, list) and len(source) == 3:
            try:
                return Home.checked(*(float(v) for v in source))
            except (TypeError, ValueError):
                continue
    return None


# -- the motor model ---------------------------------------------------------------------

def max_thrust_n(airframe: AirframeSpec) -> np.ndarray:
    """Each rotor's thrust at full command, k W_max^2 [N]: PX4's CA_ROTORi_CT."""
    return np.array([r.thrust_coeff_ns2 * r.max_rad_s ** 2 for r in airframe.rotors])


def thrust_model_factor(airframe: AirframeSpec) -> float:
    """PX4's THR_MDL_FAC f, normalized thrust = f c^2 + (1 - f) c of the motor command c:
    1 when c sets the rotor speed (T = k (c W_max)^2), 0 when it sets the thrust."""
    return 1.0 if airframe.command_map == "speed" else 0.0


def normalized_thrust(commands: np.ndarray, airframe: AirframeSpec) -> np.ndarray:
    """T_i / T_max,i of motor commands c_i (clipped to [0, 1], as the plant takes them):
    what PX4's actuator_motors carries."""
    c = np.clip(commands, 0.0, 1.0)
    return c * c if airframe.command_map == "speed" else c


# -- the topics --------------------------------------------------------------------------

def _rows(topic: px4.Topic, timestamp_us: np.ndarray, **values: Any) -> np.ndarray:
    """The topic's samples: every field filled from ``values`` (arrays of shape (n,) or
    (n, count)); ``timestamp_sample`` defaults to the timestamp."""
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
    geodetic = np.array([home.geodetic_from_ned(*p) for p in position]).reshape(-1, 3)
    return _rows(topic, t_us, lat=geodetic[:, 0], lon=geodetic[:, 1], alt=geodetic[:, 2],
                 lat_lon_valid=True, alt_valid=True)


def _changes(t_us: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Indices of the rows to publish: the first, each change of ``state`` (rows of
    values), and otherwise one every STATUS_PERIOD_US."""
    keep, last_t = [], None
    for k in range(len(t_us)):
        if last_t is None or not np.array_equal(state[k], state[k - 1]) or \
                t_us[k] - last_t >= STATUS_PERIOD_US:
            keep.append(k)
            last_t = t_us[k]
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
    if controller in SLIDING_MODE_CONTROLLERS and parameters is not None:
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


def logged_texts(records: LogRecords, vehicle: int) -> list[LoggedText]:
    """The vehicle's STATUSTEXT announcements (chunks joined), at the sim time each was
    said, with their severity."""
    key = mavlink_key(vehicle, AUTOPILOT_COMPID, "STATUSTEXT")
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    texts = StatustextAssembler()
    out = []
    for topic, message, data in iter_messages(records, key):
        if topic != key:
            continue
        try:
            msgs = parser.parse_buffer(data) or []
        except mavlink.MAVError:
            continue
        for msg in msgs:
            if msg.get_type() == "STATUSTEXT" and (text := texts.add(msg)) is not None:
                out.append(LoggedText(max(message.publish_time // 1000, 0),
                                      min(max(int(msg.severity), 0), 7), text))
    return out


# -- parameters and info -----------------------------------------------------------------

def ulog_parameters(context: RunContext) -> dict[str, int | float]:
    """The run's parameters under their PX4 names (INT32 where PX4 declares them so), the
    vehicle's id and type, and its rotors as PX4's control-allocation parameters."""
    out: dict[str, int | float] = {}
    parameters = context.parameters or {}
    for name in px4_parameters():
        if name in parameters:
            value = parameters[name]
            out[name] = int(value) if PARAMETER_SPECS[name].integer else float(value)
    airframe = context.airframe
    ct = max_thrust_n(airframe)
    derived: dict[str, int | float] = {
        px4.MAV_SYS_ID: context.vehicle, px4.MAV_TYPE: px4.MAV_TYPE_QUADROTOR,
        px4.CA_AIRFRAME: 0, px4.CA_ROTOR_COUNT: len(airframe.rotors),
        px4.THR_MDL_FAC: thrust_model_factor(airframe),
        px4.MPC_THR_HOVER: airframe.mass_kg * GRAVITY_MPS2 / float(ct.sum()),
    }
    for i, (rotor, thrust) in enumerate(zip(airframe.rotors, ct, strict=True)):
        x, y, z = rotor.position_m
        for field, value in (("PX", x), ("PY", y), ("PZ", z), ("AX", 0.0), ("AY", 0.0),
                             ("AZ", -1.0), ("CT", thrust),
                             ("KM", -rotor.spin * rotor.moment_coeff_nms2
                              / rotor.thrust_coeff_ns2)):
            derived[px4.rotor_parameter(i, field)] = float(value)
    clash = sorted(set(out) & set(derived))
    if clash:
        raise ValueError(f"the run's parameters name {', '.join(clash)}, which the export "
                         "derives from the airframe")
    return {**out, **derived}


def _package_version() -> str:
    try:
        return metadata.version("ivfm-sitl")
    except metadata.PackageNotFoundError:
        return "unknown"


def ulog_info(context: RunContext, log: Path) -> dict[str, str | int]:
    """Info fields: what wrote the file (PX4's keys) and which run it is (``ivfm_*``)."""
    airframe = context.airframe
    info: dict[str, str | int] = {
        "sys_name": SYS_NAME, "ver_hw": VER_HW, "ver_sw": _package_version(),
        "sys_toolchain": platform.python_implementation(),
        "sys_toolchain_ver": platform.python_version(),
        # Flight Review groups logs by vehicle: one airframe's runs are one vehicle.
        "sys_uuid": f"ivfm-{airframe.fingerprint()}-{context.vehicle}",
        "ivfm_source": Path(log).resolve().name,
        "ivfm_airframe": airframe.name,
        "ivfm_airframe_fingerprint": airframe.fingerprint(),
        "ivfm_vehicle": context.vehicle,
    }
    run = context.run
    for key in ("scenario", "controller", "plant", "mode", "state_source", "sensors"):
        if isinstance(run.get(key), str):
            info[f"ivfm_{key}"] = run[key]
    if isinstance(run.get("seed"), int) and not isinstance(run["seed"], bool):
        info["ivfm_seed"] = run["seed"]
    return info


# -- the file ----------------------------------------------------------------------------

def build_ulog(tables: dict[str, np.ndarray], info: dict[str, str | int],
               parameters: dict[str, int | float], texts: list[LoggedText]) -> ULog:
    """pyulog's ULog object holding the tables (topic name -> rows of its dtype), info
    fields, initial parameters and logged messages, ready for ``write_ulog``.

    pyulog 1.3 reads and writes ULog but has no public way to build one: its parsed form
    is filled here from the messages it parses (formats, subscriptions, logged strings),
    so its writer writes what its reader reads."""
    ulog = ULog(None)
    ulog._file_version = 1
    ulog._compat_flags = [0] * 8
    ulog._incompat_flags = [0] * 8
    stamps = [int(rows["timestamp"].min()) for rows in tables.values() if len(rows)]
    stamps += [m.timestamp_us for m in texts]
    ulog._start_timestamp = min(stamps, default=0)
    ulog._last_timestamp = max([int(rows["timestamp"].max()) for rows in tables.values()
                                if len(rows)] + [m.timestamp_us for m in texts], default=0)
    for key, value in info.items():
        if isinstance(value, str):
            ulog._msg_info_dict_types[key] = f"char[{len(value.encode())}]"
        else:
            ulog._msg_info_dict_types[key] = "int32_t"
        ulog._msg_info_dict[key] = value
    for name, value in parameters.items():
        if not (isinstance(value, float) or (isinstance(value, int)
                                             and not isinstance(value, bool))):
            raise TypeError(f"parameter {name} is {type(value).__name__}, not int or float")
        if name in px4.INT32_PARAMETERS and not isinstance(value, int):
            raise TypeError(f"parameter {name} is INT32 in PX4, got {value!r}")
        ulog._initial_parameters[name] = value
    for msg_id, (name, rows) in enumerate(tables.items()):
        topic = px4.TOPICS[name]
        ulog._message_formats[name] = ULog.MessageFormat(topic.format.encode(), None)
        add = ULog._MessageAddLogged(struct.pack("<BH", 0, msg_id) + name.encode(), None,
                                     ulog._message_formats)
        if add.dtype.names != rows.dtype.names or add.dtype.itemsize != rows.dtype.itemsize:
            raise AssertionError(f"{name}: pyulog reads the format as {add.dtype}, the rows "
                                 f"are {rows.dtype}")
        add.buffer = bytearray(rows.tobytes())
        ulog._data_list.append(ULog.Data(add))
    for m in texts:
        ulog._logged_messages.append(ULog.MessageLogging(
            struct.pack("<BQ", LOG_LEVEL_ZERO + m.severity, m.timestamp_us)
            + m.text.encode(), None))
    return ulog


def read_context(log: Path, records: LogRecords, vehicle: int | None = None,
                 airframe: AirframeSpec | None = None) -> RunContext:
    """The run around the log: its run.json, the vehicle, the airframe, the home."""
    run = run_record(log)
    chosen = _vehicle(records, run, vehicle)
    scene = _first_scene(records, chosen)
    return RunContext(run, chosen, _airframe(run, scene, airframe), _home(run, scene))


def export_ulog(log: Path, out: Path, vehicle: int | None = None,
                airframe: AirframeSpec | None = None) -> ExportSummary:
    """The run whose log is ``log`` (a run folder or an .mcap file) written to ``out`` as
    a ULog. ``vehicle``: which vehicle of the log (default: the run's, or the only one);
    ``airframe``: the airframe it flew (default: the run's). ValueError (nothing written)
    when the log does not read or lacks the autopilot's control records."""
    log = Path(log)
    records = LogRecords(log, ("ivfm/vehicle/", "mavlink/"))
    context = read_context(log, records, vehicle, airframe)
    c = control_records(records, context.vehicle)
    if np.any(c["sim_time_us"] < 0):
        raise ValueError(f"{log}: a control record at negative sim time")
    tables = control_topics(c, context)
    tables.update(truth_topics(records, context))
    texts = logged_texts(records, context.vehicle)
    parameters = ulog_parameters(context)
    ulog = build_ulog({name: tables[name] for name in px4.TOPICS if name in tables},
                      ulog_info(context, log), parameters, texts)
    with atomic_writer(out) as f:
        ulog.write_ulog(f)
    t = c["sim_time_us"]
    return ExportSummary(Path(out), {name: len(rows) for name, rows in tables.items()},
                         len(parameters), len(texts), float(t[-1] - t[0]) / 1e6)
