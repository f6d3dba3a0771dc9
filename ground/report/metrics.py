"""Metrics of a run: per-axis tracking errors after a transient, control effort, chattering.

Stated definitions (the paper does not print its metric): for each tracked axis,
e_k = reference_k - output_k over the samples with t >= transient_s;
rmse = sqrt(mean e^2), mse = mean e^2, max_abs = max |e|. Control effort is the mean of
sum_i c_i^2 over the same window (c_i the normalised motor commands); chattering is the
total variation sum_k sum_i |c_i[k] - c_i[k-1]| over that window, and per second.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from autopilot.navigator.home import Places
from autopilot.navigator.mission_runner import WAYPOINT_COMMANDS, item_position_ned
from autopilot.parameters import validate_parameters
from contracts.frames import wrap_pi_array
from contracts.mavlink import mavlink
from contracts.vectors import MEAS_EULER_RATE, REF_EULER, REF_POS
from ground.record.run_files import RunRecord
from ground.scenario.scenario_file import Scenario

# axis -> (index into the reference vector, index into the measurement vector)
AXES: dict[str, tuple[int, int]] = {
    "x": (REF_POS, 0),
    "y": (REF_POS + 1, 1),
    "z": (REF_POS + 2, 2),
    "phi": (REF_EULER, 6),
    "theta": (REF_EULER + 1, 7),
    "psi": (REF_EULER + 2, 8),
}


ESTIMATION_DEFINITION = (
    "estimate - truth at each control step over t >= transient_s: attitude_rmse_rad pools "
    "roll and pitch (sqrt of the mean of both squared errors), position_rmse_m is the "
    "horizontal distance, velocity_rmse_mps the 3-D one")


def estimation_metrics(record: RunRecord, window: np.ndarray) -> dict[str, float]:
    """How far the onboard estimate was from the truth (the controller flew on it)."""
    e = (record.measurement - record.truth)[window]
    e[:, 6:9] = wrap_pi_array(e[:, 6:9].ravel()).reshape(-1, 3)

    def rms(values: np.ndarray) -> float:
        return float(math.sqrt(np.mean(values))) if values.size else math.nan

    return {
        "attitude_rmse_rad": rms((e[:, 6] ** 2 + e[:, 7] ** 2) / 2.0),
        "roll_rmse_rad": rms(e[:, 6] ** 2),
        "pitch_rmse_rad": rms(e[:, 7] ** 2),
        "yaw_rmse_rad": rms(e[:, 8] ** 2),
        "position_rmse_m": rms(e[:, 0] ** 2 + e[:, 1] ** 2),
        "altitude_rmse_m": rms(e[:, 2] ** 2),
        "velocity_rmse_mps": rms(np.sum(e[:, 3:6] ** 2, axis=1)),
        "euler_rate_rmse_rad_s": rms(np.mean(e[:, 9:12] ** 2, axis=1)),
    }


PATH_DEFINITION = (
    "cross-track: distance from the true position to the nearest point of the planned "
    "legs (straight lines from home through the mission's positions, take-off straight "
    "up), over the "
    "samples from the arrival at the first item to the arrival at the last; arrival: the "
    "first sample, after the arrival at the item before, within the item's acceptance "
    "radius (NAV_ACC_RAD if it gives none) and NAV_MC_ALT_RAD of its altitude")


def distance_to_path(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Each point's distance [m] to the nearest point of the polyline ``path`` (n, 3)."""
    best = np.full(len(points), np.inf)
    for a, b in zip(path[:-1], path[1:], strict=True):
        ab = b - a
        length2 = float(ab @ ab)
        t = np.zeros(len(points)) if length2 == 0.0 else \
            np.clip((points - a) @ ab / length2, 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


def planned_legs(scenario: Scenario) -> tuple[list[np.ndarray], list[float], list[int]]:
    """The mission's positioned items in local NED around home (from the take-off point),
    with each one's acceptance radius [m] and its item number."""

    p = validate_parameters(scenario.parameters)
    start_ned = np.zeros(3)
    legs, radii, seqs = [], [], []
    for item in scenario.mission_items:
        if item.command not in (mavlink.MAV_CMD_NAV_TAKEOFF, *WAYPOINT_COMMANDS):
            continue
        legs.append(item_position_ned(item, legs[-1] if legs else start_ned,
                                      Places.at(scenario.home)))
        given = item.params[1] if item.command == mavlink.MAV_CMD_NAV_WAYPOINT else 0.0
        radii.append(given if np.isfinite(given) and given > 0 else p["NAV_ACC_RAD"])
        seqs.append(item.seq)
    return legs, radii, seqs


def path_metrics(record: RunRecord, scenario: Scenario) -> dict[str, Any]:
    """How the vehicle followed its mission: arrival at each positioned item, cross-track
    error along the planned legs (PATH_DEFINITION)."""

    p = validate_parameters(scenario.parameters)
    legs, radii, seqs = planned_legs(scenario)
    position = record.true_state[:, 0:3]
    arrivals: list[float | None] = []
    index = 0
    for target, radius in zip(legs, radii, strict=True):
        error = position[index:] - target
        inside = np.nonzero((np.hypot(error[:, 0], error[:, 1]) <= radius)
                            & (np.abs(error[:, 2]) <= p["NAV_MC_ALT_RAD"]))[0]
        if inside.size == 0:
            arrivals.append(None)
            break
        index += int(inside[0])
        arrivals.append(float(record.time_s[index]))
    arrivals += [None] * (len(legs) - len(arrivals))
    out: dict[str, Any] = {
        "items": seqs, "arrival_s": arrivals,
        "all_reached": all(a is not None for a in arrivals),
        "cross_track_rmse_m": None, "cross_track_max_m": None}
    if len(legs) >= 2 and arrivals[0] is not None:
        end = arrivals[-1] if arrivals[-1] is not None else record.time_s[-1]
        window = (record.time_s >= arrivals[0]) & (record.time_s <= end)
        deviation = distance_to_path(position[window], np.array([np.zeros(3), *legs]))
        if deviation.size:
            out["cross_track_rmse_m"] = float(np.sqrt(np.mean(deviation**2)))
            out["cross_track_max_m"] = float(np.max(deviation))
    return out


def axis_error(record: RunRecord, axis: str) -> np.ndarray:
    """Reference minus output for one axis (angles wrapped to [-pi, pi))."""
    ref_index, meas_index = AXES[axis]
    reference = record.reference[:, ref_index].copy()
    if axis in ("phi", "theta"):
        reference += record.kick[:, 0 if axis == "phi" else 1]
    error = reference - record.true_state[:, meas_index]
    if axis in ("phi", "theta", "psi"):
        error = wrap_pi_array(error)
    return error


def compute_metrics(record: RunRecord, scenario: Scenario, airframe_name: str) -> dict[str, Any]:
    window = record.time_s >= scenario.transient_s
    axes = {}
    for axis in scenario.axes:
        e = axis_error(record, axis)[window]
        if e.size == 0:
            axes[axis] = {"rmse": None, "mse": None, "max_abs": None}
            continue
        mse = float(np.mean(e**2))
        axes[axis] = {"rmse": math.sqrt(mse), "mse": mse, "max_abs": float(np.max(np.abs(e)))}
    c = record.motor_commands[window]
    estimation = estimation_metrics(record, window) if record.truth is not None else None
    duration = float(np.count_nonzero(window)) * record.period_s
    tv = float(np.sum(np.abs(np.diff(c, axis=0)))) if len(c) > 1 else 0.0
    # How hard roll and pitch swing: an attitude limit cycle shows here whatever the
    # position does (RMS of the truth's |(phi_dot, theta_dot)|).
    rates = record.true_state[window][:, MEAS_EULER_RATE:MEAS_EULER_RATE + 2]
    with np.errstate(over="ignore"):  # a damaged log's absurd rates: inf, not a warning
        tilt_rate = float(np.sqrt(np.mean(np.sum(rates**2, axis=1)))) if len(rates) else None
    sim_time = float(len(record.time_s)) * record.period_s
    return {
        "scenario": record.scenario,
        "controller": record.controller,
        "plant": record.plant,
        "airframe": airframe_name,
        "control_period_s": record.period_s,
        "sim_time_s": sim_time,
        "wall_time_s": record.wall_time_s,
        "real_time_factor": sim_time / record.wall_time_s if record.wall_time_s > 0 else None,
        **({"startup_wall_s": record.startup_wall_s} if record.startup_wall_s else {}),
        "transient_s": scenario.transient_s,
        "diverged": record.diverged,
        "axes": axes,
        **({"estimation": estimation} if estimation is not None else {}),
        **({"path": path_metrics(record, scenario)} if scenario.plan is not None else {}),
        "control": {
            "effort_mean_sum_c2": float(np.mean(np.sum(c**2, axis=1))) if len(c) else None,
            "chattering_total_variation": tv,
            "chattering_per_s": tv / duration if duration > 0 else None,
            "saturated_fraction": float(np.mean((c >= 0.999) | (c <= 0.001))) if len(c) else None,
            "tilt_rate_rms_rad_s": tilt_rate,
        },
        "definitions": {
            "error": "reference - output over t >= transient_s (angles wrapped)",
            "effort_mean_sum_c2": "mean over samples of sum_i c_i^2, c_i = W_i / W_max",
            "chattering_total_variation": "sum_k sum_i |c_i[k] - c_i[k-1]|",
            "tilt_rate_rms_rad_s": "RMS over t >= transient_s of the truth's "
                                   "sqrt(phi_dot^2 + theta_dot^2)",
            **({"estimation": ESTIMATION_DEFINITION} if estimation is not None else {}),
            **({"path": PATH_DEFINITION} if scenario.plan is not None else {}),
        },
    }


def format_metrics(metrics: dict[str, Any]) -> str:
    """A run's metrics as ``ivfm run`` and ``ivfm report`` print them."""
    lines = [f"{metrics['scenario']} | {metrics['controller']} | {metrics['plant']} plant | "
             f"{metrics['sim_time_s']:.1f} s sim in {metrics['wall_time_s']:.2f} s wall "
             f"({metrics['real_time_factor']:.0f}x real time)"
             + (" | DIVERGED" if metrics["diverged"] else "")]
    if metrics.get("startup_wall_s", 0.0) > 1.0:
        lines.append(f"  the first step loaded the compiled numerical core in "
                     f"{metrics['startup_wall_s']:.1f} s (compiling it: a fresh install; "
                     "cached after), not counted above")
    if "loop_real_time_factor" in metrics:
        lines.append(f"  loop {metrics['loop_real_time_factor']:.1f}x real time after warm-up; "
                     f"whole command {metrics.get('command_wall_time_s', math.nan):.2f} s wall")
    lines.append(f"  errors after {metrics['transient_s']:g} s:")
    for axis, m in metrics["axes"].items():
        lines.append(f"    {axis:>5}: rmse {m['rmse']:.5f}  mse {m['mse']:.3e}  "
                     f"max {m['max_abs']:.4f}")
    est = metrics.get("estimation")
    if est:
        lines.append(f"  estimation: attitude {est['attitude_rmse_rad']:.4f} rad  yaw "
                     f"{est['yaw_rmse_rad']:.4f} rad  position {est['position_rmse_m']:.3f} m  "
                     f"altitude {est['altitude_rmse_m']:.3f} m  velocity "
                     f"{est['velocity_rmse_mps']:.3f} m/s (RMSE against truth)")
    path = metrics.get("path")
    if path:
        arrivals = ", ".join("-" if t is None else f"{t:.2f}" for t in path["arrival_s"])
        lines.append(f"  path: {'every item reached' if path['all_reached'] else 'NOT ALL REACHED'}"
                     f" (arrivals [s]: {arrivals})")
        if path["cross_track_rmse_m"] is not None:
            lines.append(f"  cross-track: rmse {path['cross_track_rmse_m']:.4f} m  max "
                         f"{path['cross_track_max_m']:.4f} m")
    c = metrics["control"]
    lines.append(f"  effort {c['effort_mean_sum_c2']:.4f}  chattering "
                 f"{c['chattering_per_s']:.3f}/s  saturated {100 * c['saturated_fraction']:.1f} %")
    return "\n".join(lines)
