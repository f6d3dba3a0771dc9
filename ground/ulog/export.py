"""A run's MCAP log written as a PX4 flight log (ULog), for PX4's own tools: pyulog's
``ulog_info`` / ``ulog_params`` / ``ulog2csv``, PlotJuggler's ULog loader, Flight Review.

What the file holds, under PX4's names (the table in docs/ulog.md): the run's records as
PX4 topics (ground/ulog/run_topics.py), the texts the vehicle said (STATUSTEXT, as
logged messages), the run's parameters under their PX4 names, the airframe's rotors as
PX4's control-allocation parameters, and info fields naming what wrote it and which run
it is. Timestamps are the vehicle's sim time in microseconds.

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

from autopilot.copter_parameters import px4_parameters
from autopilot.parameters import PARAMETER_SPECS
from contracts.airframe_file import AirframeSpec, read_airframe, shipped_airframe_names
from contracts.atomic_file import atomic_writer
from contracts.frames import (
    GRAVITY_MPS2,
    Home,
)
from contracts.telemetry import (
    AUTOPILOT,
    decode_json_record,
    parse_key,
    vehicle_key,
)
from ground.record.events import statustexts
from ground.record.run_files import RUN_FILE, LogRecords, control_records, iter_messages
from ground.ulog import px4_topics as px4
from ground.ulog.run_topics import (
    RunContext,
    control_topics,
    max_thrust_n,
    sensor_topics,
    thrust_model_factor,
    truth_topics,
)

SYS_NAME = "IVFM-SITL"
VER_HW = "IVFM_SITL"
LOG_LEVEL_ZERO = ord("0")  # ULog's log level: '0' (emergency) ... '7' (debug), MAVLink's


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



def logged_texts(records: LogRecords, vehicle: int) -> list[LoggedText]:
    """The vehicle's STATUSTEXT announcements (chunks joined), at the sim time each was
    said, with their severity."""
    return [LoggedText(max(t_ns // 1000, 0), min(max(severity, 0), 7), text)
            for t_ns, severity, text in statustexts(records, vehicle)]


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
    tables.update(sensor_topics(records, context))
    texts = logged_texts(records, context.vehicle)
    parameters = ulog_parameters(context)
    ulog = build_ulog({name: tables[name] for name in px4.TOPICS if name in tables},
                      ulog_info(context, log), parameters, texts)
    with atomic_writer(out) as f:
        ulog.write_ulog(f)
    t = c["sim_time_us"]
    return ExportSummary(Path(out), {name: len(rows) for name, rows in tables.items()},
                         len(parameters), len(texts), float(t[-1] - t[0]) / 1e6)
