"""PX4 logs (ULog) that the tests write themselves, with pyulog's writer and PX4's topic,
field and parameter names: a flight of this project's quad X 500 flown in process
(lockstep, the excitation scenario) logged as PX4 1.15 logs it, or as PX4 1.12 did
(actuator_outputs in PWM, no angular acceleration, no control-allocation parameters), with
a ground phase before and after (disarmed, then armed on the ground).

The logs are built as pyulog's own parser leaves a file (formats, flattened fields, numpy
arrays per field) and written by ``ULog.write_ulog``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pyulog import ULog

from contracts.airframe_file import AirframeSpec, read_airframe
from contracts.frames import GRAVITY_MPS2, body_rates_from_euler_rates, quat_from_euler

# ver_sw_release: 0xMMmmppTT, TT = 255 for a release.
PX4_1_15 = 0x010F00FF
PX4_1_12 = 0x010C03FF
START_US = 5_000_000  # the log starts 5 s after boot, as a real one does
GROUND_S = 2.0  # disarmed on the ground first
SPOOL_S = 1.0  # then armed on the ground, before the take-off
LANDED_S = 1.0  # armed on the ground after the landing, then disarmed
AFTER_S = 1.0
PWM_MIN_US, PWM_MAX_US, PWM_DISARMED_US = 1000.0, 2000.0, 900.0


class LogBuilder:
    """A ULog filled field by field, written with pyulog's writer."""

    def __init__(self, start_us: int = START_US) -> None:
        self.ulog = ULog(None)
        self.ulog._file_version = 1
        self.ulog._start_timestamp = start_us
        self.ulog._last_timestamp = start_us

    def info(self, key: str, value: str | int) -> None:
        kind = f"char[{len(value.encode())}]" if isinstance(value, str) else "int32_t"
        self.ulog._msg_info_dict[key] = value
        self.ulog._msg_info_dict_types[key] = kind

    def parameters(self, values: dict[str, float | int]) -> None:
        """int values are written int32, the others float32 (as PX4 types them)."""
        for name, value in values.items():
            self.ulog._initial_parameters[name] = value if isinstance(value, int) \
                else float(value)

    def topic(self, name: str, time_us: np.ndarray, fields: dict[str, tuple[str, np.ndarray]],
              multi_id: int = 0) -> None:
        """One topic: ``fields`` maps a field name to (PX4 type, values (N,) or (N, k));
        ``timestamp`` is added first."""
        time_us = np.asarray(time_us, dtype=np.uint64)
        layout = [("uint64_t", 0, "timestamp")]
        flat: dict[str, tuple[str, np.ndarray]] = {"timestamp": ("uint64_t", time_us)}
        for field_name, (kind, values) in fields.items():
            values = np.asarray(values)
            if values.ndim == 2:
                layout.append((kind, values.shape[1], field_name))
                for i in range(values.shape[1]):
                    flat[f"{field_name}[{i}]"] = (kind, values[:, i])
            else:
                layout.append((kind, 0, field_name))
                flat[field_name] = (kind, values)
        self.format(name, layout)
        self.data(name, flat, multi_id)

    def format(self, name: str, layout: list[tuple[str, int, str]]) -> None:
        """A message format: (type, array size or 0, field name) per field; a type may be
        another format's name (PX4's nested messages)."""
        if name not in self.ulog._message_formats:
            fmt = object.__new__(ULog.MessageFormat)
            fmt.name, fmt.fields = name, layout
            self.ulog._message_formats[name] = fmt

    def data(self, name: str, flat: dict[str, tuple[str, np.ndarray]], multi_id: int = 0
             ) -> None:
        """A topic's samples, field by flattened name ("esc[0].esc_rpm") in the order of
        its format, ``timestamp`` among them."""
        time_us = np.asarray(flat["timestamp"][1], dtype=np.uint64)
        data = object.__new__(ULog.Data)
        data.multi_id, data.msg_id, data.name = multi_id, len(self.ulog._data_list), name
        data.field_data = [ULog._FieldData(n, kind) for n, (kind, _v) in flat.items()]
        data.timestamp_idx = list(flat).index("timestamp")
        data.data = {n: v.astype(ULog._UNPACK_TYPES[kind][2]) for n, (kind, v) in flat.items()}
        self.ulog._data_list.append(data)
        if len(time_us):
            self.ulog._last_timestamp = max(self.ulog._last_timestamp, int(time_us.max()))

    def write(self, path: Path) -> Path:
        self.ulog.write_ulog(str(path))
        return path


# -- a flight of this project, as PX4 would log it -------------------------------------------

@dataclass(frozen=True)
class Flight:
    """Arrays of one flight, one row per control step: what the log is made of."""

    airframe: str
    time_s: np.ndarray  # from the take-off
    euler_rad: np.ndarray  # (N, 3)
    euler_rate_rad_s: np.ndarray  # (N, 3)
    motor_commands: np.ndarray  # (N, 4) in [0, 1], the airframe's command map

    @property
    def body_rates(self) -> np.ndarray:
        return np.array([body_rates_from_euler_rates(*e[:2], *r) for e, r in
                         zip(self.euler_rad, self.euler_rate_rad_s, strict=True)])

    @property
    def quaternions(self) -> np.ndarray:
        return np.array([quat_from_euler(*e) for e in self.euler_rad])


@functools.cache
def lockstep_flight(airframe: str = "quad-x-500", plant: str = "rigid-body") -> Flight:
    """The excitation scenario on ``airframe`` flown in process (the plant and the SMC
    baseline, lockstep at 100 Hz): the flight ``ivfm run excitation`` makes."""
    from contracts.airframe import airframe_from_spec
    from ground.run.inprocess import run_inprocess
    from ground.scenario.scenario_file import scenario_by_name

    spec = read_airframe(airframe)
    scenario = scenario_by_name("excitation").on_airframe(spec)
    run = run_inprocess(scenario, "smc", plant, airframe_from_spec(spec))
    m = run.measurement
    return Flight(airframe, run.time_s, m[:, 6:9], m[:, 9:12], run.motor_commands)


def thrust_fractions(commands: np.ndarray, spec: AirframeSpec) -> np.ndarray:
    """Each rotor's thrust over its maximum for motor commands under the command map:
    what PX4's actuator_motors carries."""
    return commands**2 if spec.command_map == "speed" else commands


def hover_thrust_fraction(spec: AirframeSpec) -> float:
    """The collective thrust fraction that carries the weight (alike rotors)."""
    t_max = sum(r.thrust_coeff_ns2 * r.max_rad_s**2 for r in spec.rotors)
    return spec.mass_kg * GRAVITY_MPS2 / t_max


def px4_parameters(spec: AirframeSpec, version: str = "1.15") -> dict[str, float | int]:
    """The parameters PX4 would hold for the airframe: control allocation (1.13+: rotor
    positions, moment ratio KM > 0 for a counter-clockwise rotor, thrust coefficient CT =
    the rotor's full thrust), the thrust model, hover thrust, PWM range."""
    params: dict[str, float | int] = {
        "MAV_TYPE": 2, "SYS_AUTOSTART": 4001,
        "THR_MDL_FAC": 1.0 if spec.command_map == "speed" else 0.0,
        "MPC_THR_HOVER": hover_thrust_fraction(spec), "MPC_USE_HTE": 1,
    }
    if version == "1.12":
        params.update({"PWM_MAIN_MIN": int(PWM_MIN_US), "PWM_MAIN_MAX": int(PWM_MAX_US),
                       "PWM_MAIN_DISARM": int(PWM_DISARMED_US)})
        return params
    params.update({"CA_AIRFRAME": 0, "CA_ROTOR_COUNT": len(spec.rotors)})
    for i, r in enumerate(spec.rotors):
        x, y, z = r.position_m
        params.update({
            f"CA_ROTOR{i}_PX": x, f"CA_ROTOR{i}_PY": y, f"CA_ROTOR{i}_PZ": z,
            f"CA_ROTOR{i}_AX": 0.0, f"CA_ROTOR{i}_AY": 0.0, f"CA_ROTOR{i}_AZ": -1.0,
            f"CA_ROTOR{i}_KM": -r.spin * r.moment_coeff_nms2 / r.thrust_coeff_ns2,
            f"CA_ROTOR{i}_CT": r.thrust_coeff_ns2 * r.max_rad_s**2,
            f"PWM_MAIN_FUNC{i + 1}": 101 + i,
            f"PWM_MAIN_MIN{i + 1}": int(PWM_MIN_US), f"PWM_MAIN_MAX{i + 1}": int(PWM_MAX_US)})
    return params


@dataclass(frozen=True)
class Timeline:
    """Where the flight sits in the log [s from the log's start]."""

    takeoff_s: float
    landing_s: float
    armed_s: float
    disarmed_s: float
    end_s: float


def timeline(flight: Flight, simulator: bool = False) -> Timeline:
    """Ground phases around the flight; ``simulator``: none (a simulator's log is in the
    air, armed, from its first sample to its last)."""
    if simulator:
        end = float(flight.time_s[-1]) + 0.01
        return Timeline(0.0, end, 0.0, end, end)
    takeoff = GROUND_S + SPOOL_S
    landing = takeoff + float(flight.time_s[-1]) + 0.01
    return Timeline(takeoff, landing, GROUND_S, landing + LANDED_S,
                    landing + LANDED_S + AFTER_S)


def _us(t_s: np.ndarray | float, start_us: int = START_US) -> np.ndarray:
    return start_us + np.round(np.asarray(t_s) * 1e6).astype(np.int64)


def flight_log(path: Path, flight: Flight, version: str = "1.15", *,
               parameters: dict[str, float | int] | None = None,
               drop_topics: tuple[str, ...] = (), attitude_every: int = 1,
               motors_every: int = 1, acceleration: bool = True,
               landed_between: tuple[tuple[float, float], ...] = (),
               rates_gap: tuple[float, float] | None = None,
               nan_at: tuple[str, float] | None = None, esc: bool = False,
               simulator: bool = False) -> Path:
    """``flight`` as PX4 ``version`` ("1.15" or "1.12") logs it. ``attitude_every`` /
    ``motors_every`` log every n-th sample of those topics (PX4's logger rates);
    ``parameters`` replace or add to the airframe's; ``drop_topics`` are left out;
    ``acceleration`` False leaves out 1.15's xyz_derivative; the land detector also says
    landed in ``landed_between`` (log times [s]); ``rates_gap`` drops the body rates'
    samples in (start, end) [s]; ``nan_at`` (field, time [s]) makes that motor field NaN
    in the sample at that time ("control[2]" / "output[2]"); ``esc`` adds ESC telemetry
    (esc_status at 10 Hz, each rotor's rpm, the ESCs in reverse order of the motors they
    drive, as ``actuator_function`` says); ``simulator``: as a simulator logs a run, from
    time 0 (the log's start at 0 us), armed and in the air throughout."""
    spec = read_airframe(flight.airframe)
    line = timeline(flight, simulator)
    start_us = 0 if simulator else START_US
    period = float(flight.time_s[1] - flight.time_s[0])
    before = np.arange(0.0, line.takeoff_s - 1e-9, period)
    after = np.arange(line.landing_s, line.end_s - 1e-9, period)
    t = np.concatenate([before, line.takeoff_s + flight.time_s, after])
    n0, n1 = len(before), len(after)
    level = np.array([[1.0, 0.0, 0.0, 0.0]])
    q = np.concatenate([np.repeat(level, n0, 0), flight.quaternions, np.repeat(level, n1, 0)])
    body = np.concatenate([np.zeros((n0, 3)), flight.body_rates, np.zeros((n1, 3))])
    # PX4's derivative of the body rates, as the command of step k drives them over
    # [t_k, t_k+1]: forward differences.
    flown = flight.body_rates
    flown_acc = np.zeros_like(flown)
    flown_acc[:-1] = np.diff(flown, axis=0) / period
    flown_acc[-1] = flown_acc[-2]
    body_acc = np.concatenate([np.zeros((n0, 3)), flown_acc, np.zeros((n1, 3))])
    fraction = np.concatenate([np.zeros((n0, 4)), thrust_fractions(flight.motor_commands, spec),
                               np.zeros((n1, 4))])
    armed = (t >= line.armed_s) & (t < line.disarmed_s)
    b = LogBuilder(start_us)
    b.info("sys_name", "PX4")
    b.info("ver_hw", "PX4_SITL")
    b.info("ver_sw", "0123456789abcdef0123456789abcdef01234567")
    b.info("ver_sw_release", PX4_1_15 if version == "1.15" else PX4_1_12)
    b.parameters({**px4_parameters(spec, version), **(parameters or {})})
    us = _us(t, start_us)
    topics = {}
    topics["vehicle_attitude"] = (us[::attitude_every], {
        "timestamp_sample": ("uint64_t", us[::attitude_every]),
        "q": ("float", q[::attitude_every])})
    rates = {"timestamp_sample": ("uint64_t", us), "xyz": ("float", body)}
    if version == "1.15" and acceleration:
        rates["xyz_derivative"] = ("float", body_acc)
    topics["vehicle_angular_velocity"] = (us, rates)
    if version == "1.15":
        control = np.full((len(t), 12), np.nan)  # PX4 sends NaN to a motor that is off
        control[armed, :4] = fraction[armed]
        topics["actuator_motors"] = (us[::motors_every], {
            "timestamp_sample": ("uint64_t", us[::motors_every]),
            "reversible_flags": ("uint16_t", np.zeros(len(us[::motors_every]))),
            "control": ("float", control[::motors_every])})
    else:  # the output signal x with THR_MDL_FAC's curve giving the thrust, in whole us
        f = 1.0 if spec.command_map == "speed" else 0.0
        x = (np.sqrt(fraction) if f == 1.0 else fraction)
        pwm = np.full((len(t), 16), PWM_DISARMED_US)
        pwm[armed, :4] = np.round(PWM_MIN_US + x[armed] * (PWM_MAX_US - PWM_MIN_US))
        topics["actuator_outputs"] = (us[::motors_every], {
            "noutputs": ("uint32_t", np.full(len(us[::motors_every]), 4)),
            "output": ("float", pwm[::motors_every])})
    # State topics at 2 Hz and on every change, as PX4 publishes them.
    changes = [0.0, line.armed_s, line.takeoff_s, line.landing_s, line.disarmed_s]
    if simulator:  # no landing in the log: armed and in the air to its last sample
        changes = [0.0]
        line = Timeline(0.0, float(t[-1]) + 1.0, 0.0, float(t[-1]) + 1.0, float(t[-1]))
    status_t = np.union1d(np.arange(0.0, line.end_s, 0.5), changes)
    status_t = np.union1d(status_t, [t for span in landed_between for t in span])
    arming = np.where((status_t >= line.armed_s) & (status_t < line.disarmed_s), 2, 1)
    topics["vehicle_status"] = (_us(status_t, start_us), {
        "arming_state": ("uint8_t", arming), "nav_state": ("uint8_t", np.full(len(status_t), 2)),
        "vehicle_type": ("uint8_t", np.ones(len(status_t)))})
    landed = ~((status_t >= line.takeoff_s) & (status_t < line.landing_s))
    for a, b_s in landed_between:
        landed |= (status_t >= a) & (status_t < b_s)
    topics["vehicle_land_detected"] = (_us(status_t, start_us), {
        "landed": ("bool", landed), "maybe_landed": ("bool", landed),
        "ground_contact": ("bool", landed)})
    if version == "1.15":
        air = np.arange(line.takeoff_s, line.landing_s, 0.1)
        topics["hover_thrust_estimate"] = (_us(air, start_us), {
            "timestamp_sample": ("uint64_t", _us(air, start_us)),
            "hover_thrust": ("float", np.full(len(air), hover_thrust_fraction(spec))),
            "hover_thrust_var": ("float", np.full(len(air), 1e-4)),
            "valid": ("bool", np.ones(len(air)))})
    if rates_gap is not None:
        stamps, fields = topics["vehicle_angular_velocity"]
        gap = _us(np.array(rates_gap), start_us)
        keep = (stamps <= gap[0]) | (stamps >= gap[1])
        topics["vehicle_angular_velocity"] = (stamps[keep], {
            k: (kind, v[keep]) for k, (kind, v) in fields.items()})
    if nan_at is not None:
        motor_topic = "actuator_motors" if version == "1.15" else "actuator_outputs"
        stamps, fields = topics[motor_topic]
        row = int(np.argmin(np.abs(stamps - _us(nan_at[1], start_us))))
        name, index = nan_at[0].rstrip("]").split("[")
        fields[name][1][row, int(index)] = np.nan
    for name, (stamps, fields) in topics.items():
        if name not in drop_topics:
            b.topic(name, stamps, fields)
    if esc:
        _esc_status(b, _us(t, start_us), fraction, spec)
    return b.write(path)


def _esc_status(b: LogBuilder, time_us: np.ndarray, fraction: np.ndarray, spec: AirframeSpec
                ) -> None:
    """PX4's esc_status (nested esc_report[8]): the rotors' rpm, ESC k driving motor 4 - k."""
    b.format("esc_report", [("uint64_t", 0, "timestamp"), ("int32_t", 0, "esc_rpm"),
                            ("uint8_t", 0, "actuator_function")])
    b.format("esc_status", [("uint64_t", 0, "timestamp"), ("uint8_t", 0, "esc_count"),
                            ("esc_report", 8, "esc")])
    rows = np.arange(0, len(time_us), 10)
    us = time_us[rows]
    w_max = np.array([r.max_rad_s for r in spec.rotors])
    rpm = np.round(w_max * np.sqrt(fraction[rows]) * 60.0 / (2.0 * np.pi))
    flat: dict[str, tuple[str, np.ndarray]] = {"timestamp": ("uint64_t", us),
                                               "esc_count": ("uint8_t", np.full(len(us), 4))}
    for k in range(8):
        motor = 3 - k
        flat[f"esc[{k}].timestamp"] = ("uint64_t", us)
        flat[f"esc[{k}].esc_rpm"] = ("int32_t", rpm[:, motor] if k < 4 else np.zeros(len(us)))
        flat[f"esc[{k}].actuator_function"] = ("uint8_t", np.full(len(us), 101 + motor)
                                               if k < 4 else np.zeros(len(us)))
    b.data("esc_status", flat)


def small_log(path: Path, version: str = "1.15", seconds: float = 6.0) -> Path:
    """A short flight of smooth sines (no simulation): the fuzz targets' seed."""
    t = np.arange(0.0, seconds, 0.01)
    euler = np.column_stack([0.3 * np.sin(2.0 * t), 0.3 * np.cos(1.7 * t), 0.2 * np.sin(t)])
    rates = np.column_stack([0.6 * np.cos(2.0 * t), -0.51 * np.sin(1.7 * t), 0.2 * np.cos(t)])
    commands = 0.75 + 0.1 * np.column_stack([np.sin(3.0 * t + k) for k in range(4)])
    flight = Flight("quad-x-500", t, euler, rates, commands)
    return flight_log(path, flight, version)
