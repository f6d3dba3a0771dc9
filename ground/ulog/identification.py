"""PX4 flight logs (ULog) in: identification data (docs/data-format.md) from a real
vehicle's log, the same columns as ``ivfm identify --log`` gives of a run.

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

The log is read by ground/ulog/read.py (which also holds every PX4 version's names) and
put on one clock by ground/ulog/clock.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal as scipy_signal

from autopilot.identification.dataset import Dataset
from contracts.airframe import Airframe, airframe_from_spec
from contracts.airframe_file import AirframeSpec
from ground.ulog import px4_topics as px4
from ground.ulog.clock import DEFAULT_TRIM_S, airborne_spans, held, kinematics
from ground.ulog.read import (
    IDENTIFICATION_SIGNALS,
    PARAMETERS,
    PX4Log,
    Series,
    ULogError,
    check_quad_log,
    missing_message,
    read_log,
)

DEFAULT_CUTOFF_HZ = 20.0  # the differentiated accelerations' low-pass
MIN_SAMPLES = 21  # as ivfm identify --log

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
        return px4.thrust_fraction((outputs - low) / (high - low), self.thrust_model_factor)


def thrust_model_factor(log: PX4Log, spec_command_map_speed: bool) -> tuple[float, str]:
    """THR_MDL_FAC from the log, else the airframe's command map (speed: 1, thrust: 0)."""
    found = log.parameter("thrust_model_factor")
    if found is not None:
        name, value = found
        if not 0.0 <= value <= 1.0:
            raise ULogError(f"{log.path}: {name} = {value:g} is outside [0, 1]")
        return value, f"{name} = {value:g}"
    value = px4.thrust_model_factor_of(spec_command_map_speed)
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
        fraction = model.thrust_fraction(held(motors, t))
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
