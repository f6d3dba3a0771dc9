"""PX4 flight logs (ULog) in: identification data (docs/data-format.md) from a real
vehicle's log, read with pyulog (PX4's own parser).

What comes from where (docs/px4-logs.md has the worked example and the tables):

* Euler angles from ``vehicle_attitude.q`` (Hamilton [w, x, y, z], body FRD -> NED, as
  here), Euler rates from the body rates ``vehicle_angular_velocity.xyz`` through the ZYX
  kinematics (contracts/frames.py).
* Angular accelerations from PX4's own derivative of the body rates
  (``vehicle_angular_velocity.xyz_derivative``, or ``vehicle_angular_acceleration`` before
  1.13), turned into Euler accelerations; when the log has neither, the forward
  difference of the Euler rates on the common clock (as ``ivfm identify --log`` does),
  then a zero-phase low-pass (a 2nd-order Butterworth run forwards and backwards,
  ``scipy.signal.filtfilt``) applied alike to the accelerations and to the inputs U, so
  the linear relation acc = f + b U between them is kept.
* Rotor speeds from the motor outputs through the airframe's motor model, then the inputs
  U and W_r from the airframe's geometry (contracts/airframe.py):
  ``actuator_motors.control`` is each rotor's thrust as a fraction of its maximum (PX4
  applies THR_MDL_FAC after it, in its output driver); ``actuator_outputs.output`` (PWM)
  is the signal x = (pwm - PWM_MIN) / (PWM_MAX - PWM_MIN), whose thrust fraction is
  THR_MDL_FAC x^2 + (1 - THR_MDL_FAC) x. A thrust fraction tau spins the rotor at
  W = W_max sqrt(tau) (T = k W^2, T_max = k W_max^2). The motors' lag is not modelled.
* One clock: a uniform grid at ``period_s`` over each armed, airborne span (vehicle_status
  armed and vehicle_land_detected not landed), trimmed at both ends and cut at gaps in any
  signal; measured signals interpolated (attitude by slerp, rates linearly), motor
  outputs held (the last output before each instant is what the motor was given).

Topic and field names changed between PX4 versions; every name the reader knows is in
``SIGNALS`` and ``PARAMETERS`` below, the one place to add another.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pyulog import ULog
from scipy import signal as scipy_signal
from scipy.interpolate import make_interp_spline
from scipy.spatial.transform import Rotation, Slerp

from autopilot.identification.dataset import Dataset
from autopilot.trajectories import abs_reach, tail_reach
from contracts.airframe import Airframe, airframe_from_spec
from contracts.airframe_file import AirframeSpec


class ULogError(ValueError):
    """A log that cannot give what was asked; the message names the file and the problem."""


@dataclass(frozen=True)
class Source:
    """Where one signal is in one generation of PX4's logs."""

    topic: str
    fields: tuple[str, ...]
    versions: str  # the PX4 versions that log it so
    sample_time: bool = True  # stamped by ``timestamp_sample`` (the sensor's) when logged

    @property
    def label(self) -> str:
        first = self.fields[0]
        if first.endswith("[0]") and self.fields == _indexed(first[:-3], len(self.fields)):
            return f"{self.topic}.{first[:-3]}[0..{len(self.fields) - 1}]"
        return f"{self.topic}.{', '.join(self.fields)}"


def _indexed(name: str, n: int) -> tuple[str, ...]:
    return tuple(f"{name}[{i}]" for i in range(n))


# Each signal's places in PX4's logs, the preferred first: the version aliases
# (docs/px4-logs.md#px4-versions).
SIGNALS: dict[str, tuple[Source, ...]] = {
    "attitude": (Source("vehicle_attitude", _indexed("q", 4), "every version"),),
    "rates": (
        Source("vehicle_angular_velocity", _indexed("xyz", 3), "1.10 and later"),
        Source("vehicle_attitude", ("rollspeed", "pitchspeed", "yawspeed"), "before 1.10"),
    ),
    "acceleration": (
        Source("vehicle_angular_velocity", _indexed("xyz_derivative", 3), "1.13 and later"),
        Source("vehicle_angular_acceleration", _indexed("xyz", 3), "1.10 to 1.12"),
    ),
    # The time a motor output went out (``timestamp``), not the sample it was computed from.
    "motors": (
        Source("actuator_motors", _indexed("control", 4),
               "1.13 and later (thrust fraction 0..1)", sample_time=False),
        Source("actuator_outputs", _indexed("output", 4), "every version (PWM [us])",
               sample_time=False),
    ),
    "armed": (
        Source("vehicle_status", ("arming_state",), "every version", sample_time=False),
        Source("actuator_armed", ("armed",), "every version", sample_time=False),
    ),
    "landed": (Source("vehicle_land_detected", ("landed",), "every version",
                      sample_time=False),),
    "hover_thrust": (Source("hover_thrust_estimate", ("hover_thrust", "valid"),
                            "1.12 and later"),),
    "nav_state": (Source("vehicle_status", ("nav_state",), "every version",
                         sample_time=False),),
}
# The value of each armed source that means armed: vehicle_status's ARMING_STATE_ARMED (2
# in every version), actuator_armed's flag.
ARMED_VALUE = {"vehicle_status": 2, "actuator_armed": 1}
# Parameters, per meaning, the preferred first; {n} is the output's number (from 1).
PARAMETERS: dict[str, tuple[str, ...]] = {
    "thrust_model_factor": ("THR_MDL_FAC",),
    "hover_thrust": ("MPC_THR_HOVER",),
    "pwm_min": ("PWM_MAIN_MIN{n}", "PWM_MAIN_MIN", "PWM_MIN"),  # 1.13+, 1.12, 1.11 and before
    "pwm_max": ("PWM_MAIN_MAX{n}", "PWM_MAIN_MAX", "PWM_MAX"),
    "output_function": ("PWM_MAIN_FUNC{n}",),  # 1.13+: 101 = Motor 1, ...
}
MOTOR1_FUNCTION = 101  # PX4's output function of Motor 1 (PWM_MAIN_FUNCn)
# The topics the reader loads (pyulog parses only these).
TOPICS = sorted({s.topic for sources in SIGNALS.values() for s in sources} | {"esc_status"})
IDENTIFICATION_SIGNALS = ("attitude", "rates", "motors", "armed", "landed")

# Left out at the start and the end of each airborne span: the take-off (ground effect;
# ivfm identify --log skips 2 s likewise) and the landing (the land detector says landed
# a second or more after the touch-down).
DEFAULT_TRIM_S = (2.0, 2.0)
DEFAULT_CUTOFF_HZ = 20.0  # the differentiated accelerations' low-pass
MAX_RATE_HZ = 100.0  # the default clock: the body rates' own, at most the control rate here
MIN_SPAN_S = 1.0  # shorter airborne pieces are left out
MIN_SAMPLES = 21  # as ivfm identify --log


@dataclass(frozen=True)
class Series:
    """One signal as logged: sample times [s since the log's start], values (N, k)."""

    signal: str
    source: Source
    time_s: np.ndarray
    values: np.ndarray
    fields: tuple[str, ...]  # the fields read (a remapped output channel differs)

    @property
    def label(self) -> str:
        return Source(self.source.topic, self.fields, self.source.versions).label

    def interval_s(self) -> float:
        """The median sample interval (inf for one sample)."""
        return float(np.median(np.diff(self.time_s))) if len(self.time_s) > 1 else math.inf


@dataclass
class PX4Log:
    """A parsed PX4 log and what the reader needs of it."""

    path: Path
    ulog: ULog
    warnings: list[str] = field(default_factory=list)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameters as the log starts (PX4 logs every one)."""
        return self.ulog.initial_parameters

    @property
    def duration_s(self) -> float:
        return max(0.0, (self.ulog.last_timestamp - self.ulog.start_timestamp) / 1e6)

    def parameter(self, meaning: str, n: int | None = None) -> tuple[str, float] | None:
        """(name, value) of the first alias of ``meaning`` the log sets (per output
        ``n`` where the name has one; -1 means unset in PX4 1.11)."""
        for name in PARAMETERS[meaning]:
            if "{n}" in name:
                if n is None:
                    continue
                name = name.format(n=n)
            value = self.parameters.get(name)
            if value is not None and value != -1:
                return name, float(value)
        return None

    def topic(self, name: str, multi_id: int = 0) -> ULog.Data | None:
        for data in self.ulog.data_list:
            if data.name == name and data.multi_id == multi_id:
                return data
        return None

    def source(self, signal: str) -> tuple[Source, ULog.Data] | None:
        """The first of the signal's sources the log has, with every field."""
        for source in SIGNALS[signal]:
            data = self.topic(source.topic)
            if data is not None and all(f in data.data for f in source.fields):
                return source, data
        return None

    def series(self, signal: str) -> Series:
        """The signal as logged; ULogError names the topics and fields looked for."""
        found = self.source(signal)
        if found is None:
            raise ULogError(f"{self.path}: {missing_message(signal)}")
        source, data = found
        fields = source.fields
        if signal == "motors" and source.topic == "actuator_outputs":
            fields = self._motor_channels(data)
        stamps = data.data["timestamp"]
        if source.sample_time and "timestamp_sample" in data.data:
            sampled = data.data["timestamp_sample"]
            if np.all(sampled > 0) and np.all(np.diff(sampled.astype(np.int64)) >= 0):
                stamps = sampled
        values = np.column_stack([data.data[f].astype(float) for f in fields])
        keep = stamps > 0  # PX4 leaves unset stamps at 0
        t = (stamps[keep].astype(np.int64) - int(self.ulog.start_timestamp)) / 1e6
        values = values[keep]
        order = np.argsort(t, kind="stable")
        t, values = t[order], values[order]
        last = np.append(np.diff(t) > 0, True)  # one sample per instant: the last
        return Series(signal, source, t[last], values[last], fields)

    def _motor_channels(self, data: ULog.Data) -> tuple[str, ...]:
        """actuator_outputs' channels of motors 1-4: by PWM_MAIN_FUNCn where set (1.13+),
        else the first four (the mixer's order before 1.13)."""
        channels = {}
        for n in range(1, 17):
            function = self.parameter("output_function", n)
            if function is not None and MOTOR1_FUNCTION <= function[1] < MOTOR1_FUNCTION + 4:
                channels[int(function[1]) - MOTOR1_FUNCTION] = n - 1
        if not channels:
            return _indexed("output", 4)
        if sorted(channels) != [0, 1, 2, 3]:
            raise ULogError(f"{self.path}: PWM_MAIN_FUNC1-16 assign motors "
                            f"{sorted(i + 1 for i in channels)}, not motors 1-4")
        fields = tuple(f"output[{channels[i]}]" for i in range(4))
        missing = [f for f in fields if f not in data.data]
        if missing:
            raise ULogError(f"{self.path}: actuator_outputs has no {missing[0]}")
        return fields

    def version(self) -> str:
        """PX4's version as the log states it (ver_sw_release, else the git hash)."""
        release = self.ulog.msg_info_dict.get("ver_sw_release")
        git = self.ulog.msg_info_dict.get("ver_sw")
        text = px4_release(release) if isinstance(release, int) and release else None
        if text and git:
            return f"{text} ({str(git)[:8]})"
        return text or (f"unknown release (git {str(git)[:8]})" if git else "unknown")


def px4_release(value: int) -> str:
    """ver_sw_release (0xMMmmppTT) as v1.14.0, with its type when not a release."""
    major, minor, patch, kind = (value >> 24) & 0xFF, (value >> 16) & 0xFF, \
        (value >> 8) & 0xFF, value & 0xFF
    suffix = "" if kind == 255 else " rc" if kind >= 192 else " beta" if kind >= 128 \
        else " alpha" if kind >= 64 else " dev"
    return f"v{major}.{minor}.{patch}{suffix}"


def missing_message(signal: str) -> str:
    """What the log lacks, naming every place the signal was looked for."""
    what = {"attitude": "attitude", "rates": "body rates",
            "acceleration": "angular acceleration", "motors": "motor outputs",
            "armed": "arming state", "landed": "land detector state",
            "hover_thrust": "hover thrust estimate", "nav_state": "flight mode"}
    places = "; ".join(f"{s.label} ({s.versions})" for s in SIGNALS[signal])
    return f"the log has no {what[signal]}: looked for {places}"


def read_log(path: str | Path) -> PX4Log:
    """Parse a ULog file; ULogError (a ValueError) says why one cannot be read."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(ULog.HEADER_BYTES))
    except OSError as exc:
        raise ULogError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not head:
        raise ULogError(f"{path}: empty file, not a ULog")
    if head != ULog.HEADER_BYTES[:len(head)] or len(head) < len(ULog.HEADER_BYTES):
        raise ULogError(f"{path}: not a ULog file (it does not start with ULog's magic "
                        f"bytes 'ULog' 01 12 35)")
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):  # pyulog prints its warnings
            ulog = ULog(str(path), message_name_filter_list=TOPICS)
    except Exception as exc:  # noqa: BLE001 - a hostile file can break the parser anywhere
        raise ULogError(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    log = PX4Log(path, ulog)
    if ulog.file_corruption or "corrupt" in said.getvalue():
        log.warnings.append("pyulog found corrupt data in the log and skipped it")
    if not ulog.data_list:
        raise ULogError(f"{path}: the log holds no data (cut short in its header?)")
    return log


# -- airborne spans ------------------------------------------------------------------------

@dataclass(frozen=True)
class Spans:
    """The armed, airborne time of a log [s since its start], trimmed."""

    spans: tuple[tuple[float, float], ...]
    airborne_s: float  # before trimming
    armed_s: float
    ends_airborne: bool  # the log stops with the vehicle in the air (cut short?)


def _state_at(series: Series, t: np.ndarray, predicate) -> np.ndarray:
    """The state in force at each instant (False before the first sample)."""
    idx = np.searchsorted(series.time_s, t, side="right") - 1
    state = predicate(series.values[np.clip(idx, 0, None), 0])
    return np.where(idx >= 0, state, False)


def _intervals(t: np.ndarray, state: np.ndarray, end_s: float) -> list[tuple[float, float]]:
    """The intervals where ``state`` (given at the change times ``t``) holds."""
    out: list[tuple[float, float]] = []
    for k in np.flatnonzero(state):
        a, b = float(t[k]), float(t[k + 1]) if k + 1 < len(t) else end_s
        if out and out[-1][1] == a:
            out[-1] = (out[-1][0], b)
        elif b > a:
            out.append((a, b))
    return out


def airborne_spans(log: PX4Log, trim_s: tuple[float, float] = DEFAULT_TRIM_S) -> Spans:
    """The spans where the vehicle was armed and the land detector said not landed,
    each trimmed by ``trim_s`` (start, end)."""
    armed = log.series("armed")
    landed = log.series("landed")
    armed_value = ARMED_VALUE[armed.source.topic]
    end_s = log.duration_s
    t = np.union1d(armed.time_s, landed.time_s)
    is_armed = _state_at(armed, t, lambda v: v == armed_value)
    in_air = is_armed & ~_state_at(landed, t, lambda v: v != 0)
    armed_spans = _intervals(t, is_armed, end_s)
    air = _intervals(t, in_air, end_s)
    trimmed = tuple((a + trim_s[0], b - trim_s[1]) for a, b in air
                    if b - a > trim_s[0] + trim_s[1])
    return Spans(trimmed, sum(b - a for a, b in air), sum(b - a for a, b in armed_spans),
                 bool(air) and air[-1][1] >= end_s)


def _cut_at_gaps(spans: Sequence[tuple[float, float]], series: Sequence[Series],
                 min_span_s: float) -> list[tuple[float, float]]:
    """The spans within every series' samples, cut where one has a gap (5 of its own
    intervals, at least 0.05 s): nothing is interpolated across a dropout."""
    pieces = list(spans)
    for s in series:
        if len(s.time_s) < 2:
            return []
        limit = max(5.0 * s.interval_s(), 0.05)
        gaps = np.flatnonzero(np.diff(s.time_s) > limit)
        holes = [(s.time_s[g], s.time_s[g + 1]) for g in gaps]
        cut = []
        for a, b in pieces:
            a, b = max(a, float(s.time_s[0])), min(b, float(s.time_s[-1]))
            for h0, h1 in holes:
                if h1 <= a or h0 >= b:
                    continue
                if h0 > a:
                    cut.append((a, float(h0)))
                a = max(a, float(h1))
            if b > a:
                cut.append((a, b))
        pieces = cut
    return [(a, b) for a, b in pieces if b - a >= min_span_s]


def _grid(spans: Sequence[tuple[float, float]], anchor: Series, period_s: float
          ) -> list[np.ndarray]:
    """Uniform instants per span, starting on the anchor's first sample in it (so a log
    sampled at the grid's rate is taken at its own samples)."""
    out = []
    for a, b in spans:
        k = np.searchsorted(anchor.time_s, a, side="left")
        start = float(anchor.time_s[k]) if k < len(anchor.time_s) else a
        n = int(math.ceil((b - start) / period_s - 1e-9))  # the instants before b
        if n >= 2:
            out.append(start + period_s * np.arange(n))
    return out


def _check_finite(series: Series, spans: Sequence[tuple[float, float]], path: Path) -> None:
    """Every sample that a span's instants are taken from is a finite number."""
    for a, b in spans:
        i0 = max(0, int(np.searchsorted(series.time_s, a, side="right")) - 1)
        i1 = int(np.searchsorted(series.time_s, b, side="left")) + 1
        block = series.values[i0:i1]
        bad = np.argwhere(~np.isfinite(block))
        if bad.size:
            row, col = bad[0]
            raise ULogError(
                f"{path}: {series.source.topic}.{series.fields[col]} is "
                f"{block[row, col]} at {series.time_s[i0 + row]:.3f} s, inside the "
                f"airborne span {a:.2f}-{b:.2f} s")


# -- kinematics ------------------------------------------------------------------------------

def euler_from_quaternions(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (N, 3) of quaternions (N, 4) [w, x, y, z]:
    contracts.frames.euler_from_quat, row by row."""
    w, x, y, z = q.T
    phi = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    theta = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    psi = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.column_stack([phi, theta, psi])


def _euler_terms(euler: np.ndarray) -> tuple[np.ndarray, ...]:
    cphi, sphi = np.cos(euler[:, 0]), np.sin(euler[:, 0])
    ctheta = np.cos(euler[:, 1])
    ctheta = np.copysign(np.maximum(np.abs(ctheta), 1e-6), ctheta)
    return cphi, sphi, ctheta, np.sin(euler[:, 1]) / ctheta


def euler_rates(euler: np.ndarray, body_rates: np.ndarray) -> np.ndarray:
    """[phi', theta', psi'] (N, 3) from body rates [p, q, r]:
    contracts.frames.euler_rates_from_body_rates, row by row."""
    cphi, sphi, ctheta, ttheta = _euler_terms(euler)
    p, q, r = body_rates.T
    return np.column_stack([p + (q * sphi + r * cphi) * ttheta, q * cphi - r * sphi,
                            (q * sphi + r * cphi) / ctheta])


def euler_accelerations(euler: np.ndarray, rates: np.ndarray, body_rates: np.ndarray,
                        body_acc: np.ndarray) -> np.ndarray:
    """d/dt of the Euler rates: E(phi, theta) w' + (dE/dt) w, with E the map of
    :func:`euler_rates` and ``rates`` the Euler rates."""
    cphi, sphi, ctheta, ttheta = _euler_terms(euler)
    p, q, r = body_rates.T
    phi_dot, theta_dot = rates[:, 0], rates[:, 1]
    out = euler_rates(euler, body_acc)
    a = q * sphi + r * cphi  # its phi-derivative is q cphi - r sphi
    da = phi_dot * (q * cphi - r * sphi)
    sec2 = 1.0 / (ctheta * ctheta)
    out[:, 0] += da * ttheta + a * sec2 * theta_dot
    out[:, 1] += -phi_dot * (q * sphi + r * cphi)
    out[:, 2] += da / ctheta + a * ttheta / ctheta * theta_dot
    return out


@dataclass(frozen=True)
class Kinematics:
    """Attitude, Euler rates and (when logged) accelerations on the common clock."""

    pieces: list[np.ndarray]  # the instants, one array per span piece
    euler_rad: list[np.ndarray]
    euler_rate_rad_s: list[np.ndarray]
    body_rates: list[np.ndarray]
    euler_acc_rad_s2: list[np.ndarray] | None  # None: the log has no acceleration
    sources: dict[str, str]


def _slerp(series: Series, t: np.ndarray, path: Path) -> np.ndarray:
    """The attitude quaternions [w, x, y, z] at ``t`` by spherical interpolation."""
    i0 = max(0, int(np.searchsorted(series.time_s, t[0], side="right")) - 1)
    i1 = int(np.searchsorted(series.time_s, t[-1], side="left")) + 1
    q = series.values[i0:i1]
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 0.01)
    if bad.size:
        raise ULogError(f"{path}: vehicle_attitude.q is not a unit quaternion at "
                        f"{series.time_s[i0 + bad[0]]:.3f} s (norm {norms[bad[0]]:.4g})")
    if len(q) == 1:
        return np.repeat(q / norms[:, None], len(t), axis=0)
    rotations = Rotation.from_quat(q[:, [1, 2, 3, 0]])  # scipy: scalar last
    xyzw = Slerp(series.time_s[i0:i1], rotations)(t).as_quat()
    return xyzw[:, [3, 0, 1, 2]]


def _linear(series: Series, t: np.ndarray) -> np.ndarray:
    return make_interp_spline(series.time_s, series.values, k=1, axis=0)(t)


# Logged times are whole microseconds: an instant within half of one of a sample is at it
# (the grid's sums of periods round).
TIME_TOLERANCE_S = 0.5e-6


def _held(series: Series, t: np.ndarray) -> np.ndarray:
    """The last sample at or before each instant."""
    return series.values[np.searchsorted(series.time_s, t + TIME_TOLERANCE_S,
                                         side="right") - 1]


def kinematics(log: PX4Log, spans: Sequence[tuple[float, float]], period_s: float | None,
               also: Sequence[Series] = ()) -> tuple[Kinematics, float]:
    """The attitude signals on the common clock over ``spans`` (cut at the gaps of these
    and of ``also``), and the clock's period."""
    attitude = log.series("attitude")
    rates = log.series("rates")
    found = log.source("acceleration")
    acceleration = log.series("acceleration") if found is not None else None
    if period_s is None:
        interval = rates.interval_s() if len(rates.time_s) > 1 else 1.0 / MAX_RATE_HZ
        period_s = max(round(interval, 6), 1.0 / MAX_RATE_HZ)
    used = [attitude, rates, *also] + ([acceleration] if acceleration is not None else [])
    pieces = _cut_at_gaps(spans, used, max(MIN_SPAN_S, 3 * period_s))
    for s in used:
        _check_finite(s, pieces, log.path)
    grid = _grid(pieces, rates, period_s)
    euler, euler_rate, body, acc = [], [], [], []
    for t in grid:
        e = euler_from_quaternions(_slerp(attitude, t, log.path))
        w = _linear(rates, t)
        er = euler_rates(e, w)
        euler.append(e)
        euler_rate.append(er)
        body.append(w)
        if acceleration is not None:
            acc.append(euler_accelerations(e, er, w, _linear(acceleration, t)))
    sources = {"attitude": attitude.label, "rates": rates.label}
    if acceleration is not None:
        sources["acceleration"] = acceleration.label
    return Kinematics(grid, euler, euler_rate, body, acc if acceleration is not None else None,
                      sources), period_s


def flight_reach(log: PX4Log, trim_s: tuple[float, float] = DEFAULT_TRIM_S
                 ) -> tuple[float, float, float] | None:
    """How far the airborne flight reached: roll/pitch attitude [rad], roll/pitch rate and
    yaw rate [rad/s], each the smaller side at the coverage tails (as the coverage check
    counts a rate); None when the log cannot say."""
    try:
        spans = airborne_spans(log, trim_s).spans
        kin, _period = kinematics(log, spans, None)
    except ULogError:
        return None
    if not kin.pieces:
        return None
    euler = np.concatenate(kin.euler_rad)
    rates = np.concatenate(kin.euler_rate_rad_s)
    return (min(abs_reach(euler[:, 0]), abs_reach(euler[:, 1])),
            min(tail_reach(rates[:, 0]), tail_reach(rates[:, 1])), tail_reach(rates[:, 2]))


# -- the motor model -------------------------------------------------------------------------

@dataclass(frozen=True)
class MotorModel:
    """How a logged motor output becomes a rotor's thrust fraction (docs/px4-logs.md)."""

    kind: str  # "thrust" (actuator_motors) or "pwm" (actuator_outputs)
    thrust_model_factor: float  # THR_MDL_FAC: thrust = f x^2 + (1 - f) x of the signal x
    pwm_min_us: tuple[float, ...] = ()
    pwm_max_us: tuple[float, ...] = ()
    said: str = ""

    def thrust_fraction(self, outputs: np.ndarray) -> np.ndarray:
        """Each rotor's thrust over its maximum, (N, 4), in [0, 1]."""
        if self.kind == "thrust":
            return np.clip(outputs, 0.0, 1.0)
        low, high = np.array(self.pwm_min_us), np.array(self.pwm_max_us)
        x = np.clip((outputs - low) / (high - low), 0.0, 1.0)
        f = self.thrust_model_factor
        return f * x * x + (1.0 - f) * x


def thrust_model_factor(log: PX4Log, spec_command_map_speed: bool) -> tuple[float, str]:
    """THR_MDL_FAC from the log, else the airframe's command map (speed: 1, thrust: 0)."""
    found = log.parameter("thrust_model_factor")
    if found is not None:
        name, value = found
        if not 0.0 <= value <= 1.0:
            raise ULogError(f"{log.path}: {name} = {value:g} is outside [0, 1]")
        return value, f"{name} = {value:g}"
    value = 1.0 if spec_command_map_speed else 0.0
    return value, (f"no THR_MDL_FAC in the log: the airframe's command map "
                   f"({'speed' if spec_command_map_speed else 'thrust'}, {value:g})")


def motor_model(log: PX4Log, motors: Series, command_map_speed: bool,
                pwm_range_us: tuple[float, float] | None = None) -> MotorModel:
    """The motor model of the log's outputs; ULogError names a missing PWM range."""
    factor, said = thrust_model_factor(log, command_map_speed)
    if motors.source.topic == "actuator_motors":
        return MotorModel("thrust", factor, said="thrust fractions")
    lows, highs, names = [], [], []
    for field_name in motors.fields:
        n = int(field_name[field_name.index("[") + 1:-1]) + 1
        if pwm_range_us is not None:
            low, high = pwm_range_us
            names.append("--pwm-range")
        else:
            found_low, found_high = log.parameter("pwm_min", n), log.parameter("pwm_max", n)
            if found_low is None or found_high is None:
                aliases = " / ".join(a.replace("{n}", str(n)) for a in PARAMETERS["pwm_min"])
                raise ULogError(f"{log.path}: actuator_outputs are PWM, but the log sets "
                                f"no PWM range of output {n} ({aliases} and the MAX "
                                f"likewise); give --pwm-range MIN_US,MAX_US")
            (name_low, low), (name_high, high) = found_low, found_high
            names.append(f"{name_low}/{name_high}")
        if not high > low:
            raise ULogError(f"{log.path}: the PWM range of output {n} is {low:g}-{high:g} us")
        lows.append(low)
        highs.append(high)
    ranges = sorted({f"{lo:g}-{hi:g} us" for lo, hi in zip(lows, highs, strict=True)})
    return MotorModel("pwm", factor, tuple(lows), tuple(highs),
                      f"PWM {', '.join(ranges)} ({names[0]}), "
                      f"thrust = f x^2 + (1 - f) x with {said}")


def rotor_speeds(fraction: np.ndarray, airframe: Airframe) -> np.ndarray:
    """Rotor speeds [rad/s] (N, 4) of thrust fractions: T = k W^2 and T_max = k W_max^2
    give W = W_max sqrt(tau)."""
    return airframe.max_rad_s * np.sqrt(fraction)


# -- identification data ---------------------------------------------------------------------

@dataclass(frozen=True)
class ULogData:
    """The identification data of a log, and how it was made (said to the user)."""

    dataset: Dataset
    spans: tuple[tuple[float, float], ...]  # the pieces the rows come from [s]
    period_s: float
    sources: dict[str, str]
    notes: tuple[str, ...]


def _lowpass(period_s: float, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray] | None:
    nyquist_hz = 0.5 / period_s
    if cutoff_hz <= 0.0 or cutoff_hz >= 0.9 * nyquist_hz:
        return None
    return scipy_signal.butter(2, cutoff_hz / nyquist_hz)


def identification_data(path: str | Path, airframe: Airframe | AirframeSpec,
                        period_s: float | None = None, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
                        trim_s: tuple[float, float] = DEFAULT_TRIM_S,
                        pwm_range_us: tuple[float, float] | None = None) -> ULogData:
    """The identification samples of a PX4 log, on ``airframe`` (a Dataset with the same
    columns as ``ivfm identify --log`` gives: f = acc - b U with the airframe's b)."""
    if isinstance(airframe, AirframeSpec):
        airframe = airframe_from_spec(airframe)
    log = read_log(path)
    return identification_data_of(log, airframe, period_s, cutoff_hz, trim_s, pwm_range_us)


def identification_data_of(log: PX4Log, airframe: Airframe, period_s: float | None,
                           cutoff_hz: float, trim_s: tuple[float, float],
                           pwm_range_us: tuple[float, float] | None) -> ULogData:
    """:func:`identification_data` of a parsed log."""
    missing = [s for s in IDENTIFICATION_SIGNALS if log.source(s) is None]
    if missing:
        raise ULogError(f"{log.path}: cannot identify from this log: "
                        + "; ".join(missing_message(s) for s in missing))
    check_quad_log(log)
    span_info = airborne_spans(log, trim_s)
    if not span_info.spans:
        raise ULogError(f"{log.path}: the vehicle was never armed and airborne for more "
                        f"than {trim_s[0] + trim_s[1]:g} s (armed {span_info.armed_s:.1f} s, "
                        f"airborne {span_info.airborne_s:.1f} s by vehicle_status and "
                        f"vehicle_land_detected)")
    motors = log.series("motors")
    model = motor_model(log, motors, not airframe.thrust_command_map, pwm_range_us)
    kin, period_s = kinematics(log, span_info.spans, period_s, also=[motors])
    notes = list(log.warnings)
    if span_info.ends_airborne:
        notes.append("the log ends with the vehicle in the air (cut short?): its last "
                     "span runs to the last sample")
    b = airframe.input_gains
    filt = None if kin.euler_acc_rad_s2 is not None else _lowpass(period_s, cutoff_hz)
    columns: dict[str, list[np.ndarray]] = {}
    kept = []
    for i, t in enumerate(kin.pieces):
        fraction = model.thrust_fraction(_held(motors, t))
        w = rotor_speeds(fraction, airframe)
        u = (w * w) @ airframe.input_map[1:].T
        w_r = w @ airframe.spin
        euler, rates = kin.euler_rad[i], kin.euler_rate_rad_s[i]
        if kin.euler_acc_rad_s2 is not None:
            acc = kin.euler_acc_rad_s2[i]
        else:  # the command at t_k acts over [t_k, t_k+1]: forward differences
            acc = np.diff(rates, axis=0) / np.diff(t)[:, None]
            t, euler, rates, u, w_r = t[:-1], euler[:-1], rates[:-1], u[:-1], w_r[:-1]
            if filt is not None and len(t) > 9:
                acc = scipy_signal.filtfilt(*filt, acc, axis=0)
                u = scipy_signal.filtfilt(*filt, u, axis=0)
        kept.append((float(t[0]), float(t[-1])))
        part = {"time_s": t, "w_r_rad_s": w_r}
        for j, ch in enumerate(("phi", "theta", "psi")):
            part[f"{ch}_rad"] = euler[:, j]
            part[f"{ch}_rate_rad_s"] = rates[:, j]
            part[("u_phi_n", "u_theta_n", "u_psi_nm")[j]] = u[:, j]
            part[f"{ch}_acc_rad_s2"] = acc[:, j]
            part[f"f_{ch}"] = acc[:, j] - b[j] * u[:, j]
        for name, values in part.items():
            columns.setdefault(name, []).append(values)
    n_rows = sum(len(t) for t in columns.get("time_s", []))
    if n_rows < MIN_SAMPLES:
        raise ULogError(f"{log.path}: {n_rows} samples in the airborne spans (after "
                        f"trimming {trim_s[0]:g} s and {trim_s[1]:g} s at the ends and cutting at "
                        f"gaps); "
                        f"identification needs at least {MIN_SAMPLES}")
    sources = {**kin.sources, "motors": f"{motors.label}: {model.said}"}
    if kin.euler_acc_rad_s2 is None:
        sources["acceleration"] = (
            "differentiated (forward differences of the Euler rates), then "
            + (f"a zero-phase 2nd-order Butterworth low-pass at {cutoff_hz:g} Hz on the "
               "accelerations and U alike" if filt is not None else "not filtered"))
    else:
        sources["acceleration"] += " (PX4's filtered derivative), to Euler accelerations"
    dataset = Dataset({name: np.concatenate(parts) for name, parts in columns.items()},
                      source=f"ulog({log.path}, {n_rows} samples, {len(kept)} spans)")
    return ULogData(dataset, tuple(kept), period_s, sources, tuple(notes))


def dataset_from_ulog(path: str | Path, airframe: Airframe | AirframeSpec, **options
                      ) -> Dataset:
    """Identification data from a PX4 log: what ``ivfm identify --ulog`` identifies (the
    same Dataset as ``ground.identify.excitation.dataset_from_log`` gives of a run)."""
    return identification_data(path, airframe, **options).dataset


# -- the vehicle ------------------------------------------------------------------------------

def rotor_count(log: PX4Log) -> tuple[int | None, str]:
    """The rotor count and where it comes from: CA_ROTOR_COUNT (1.13+), else MAV_TYPE."""
    count = log.parameters.get("CA_ROTOR_COUNT")
    if count is not None:
        return int(count), "CA_ROTOR_COUNT"
    mav_type = log.parameters.get("MAV_TYPE")
    if mav_type is not None and int(mav_type) in MULTICOPTER_ROTORS:
        return MULTICOPTER_ROTORS[int(mav_type)], f"MAV_TYPE {int(mav_type)}"
    return None, "neither CA_ROTOR_COUNT nor a multicopter's MAV_TYPE"


def mav_type_name(value: float | None) -> str:
    """MAV_TYPE's name (MAVLink's enum, as pymavlink has it)."""
    if value is None:
        return "not set"
    from pymavlink.dialects.v20 import common

    entry = common.enums["MAV_TYPE"].get(int(value))
    name = entry.name.removeprefix("MAV_TYPE_") if entry is not None else "unknown"
    return f"{int(value)} ({name})"


def check_quad_log(log: PX4Log) -> None:
    """A quadrotor's log, as far as the log says; ULogError names what is not."""
    airframe = log.parameters.get("CA_AIRFRAME")
    if airframe is not None and int(airframe) != 0:
        raise ULogError(f"{log.path}: CA_AIRFRAME = {int(airframe)} "
                        f"({CA_AIRFRAMES.get(int(airframe), 'unknown')}): this stack flies "
                        "multicopters (CA_AIRFRAME 0) with 4 rotors")
    count, where = rotor_count(log)
    if count is not None and count != 4:
        raise ULogError(f"{log.path}: {where} says {count} rotors: this stack flies "
                        "quadrotors (4 rotors)")
    mav_type = log.parameters.get("MAV_TYPE")
    if count is None and mav_type is not None:
        raise ULogError(f"{log.path}: MAV_TYPE = {mav_type_name(mav_type)} and no "
                        "CA_ROTOR_COUNT: this stack flies quadrotors (MAV_TYPE 2)")


# Rotors per multicopter MAV_TYPE: quadrotor, hexarotor, octorotor, tricopter.
MULTICOPTER_ROTORS = {2: 4, 13: 6, 14: 8, 15: 3}
CA_AIRFRAMES = {0: "Multirotor", 1: "Fixed Wing", 2: "Standard VTOL", 3: "Tiltrotor VTOL",
                4: "Tailsitter VTOL", 5: "Rover (Ackermann)", 6: "Rover (Differential)",
                7: "Motors (6DOF)", 8: "Multirotor with Tilt", 9: "Custom",
                10: "Helicopter (tail ESC)", 11: "Helicopter (tail Servo)",
                12: "Helicopter (Coaxial)"}
