"""Reports from a run folder's MCAP log alone: ``ivfm report RUN_DIR``.

``run.json`` (written by ``ivfm run``) says how the run was flown, ``scenario.toml`` is
the scenario it flew; every number comes from the autopilot's control records in the
log, so a report can be re-computed, or computed for a log from elsewhere.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic_file import write_atomic
from contracts.vectors import MEAS_Z
from ground.record.events import run_events
from ground.record.run_files import (
    METRICS_FILE,
    RUN_FILE,
    SCENARIO_FILE,
    RunRecord,
    perturbation_events,
    record_from_log,
    write_json,
)
from ground.record.timeline import figures as timeline_figures
from ground.report.figures import Marks, plot_run
from ground.report.metrics import compute_metrics, planned_legs
from ground.report.run_page import marks_of, path_figure, run_page
from ground.scenario.expectations import COMPLETED, evaluate
from ground.scenario.scenario_file import Scenario, load_scenario

PAGE_FILE = "report.html"


def report(run_dir: Path, figures: bool = True) -> tuple[dict[str, Any], RunRecord]:
    """metrics.json (and figures) of a run folder, from its log."""
    run_dir = Path(run_dir)
    try:
        run = json.loads((run_dir / RUN_FILE).read_text())
    except FileNotFoundError:
        raise ValueError(f"{run_dir} has no {RUN_FILE}: is it a folder ivfm run wrote?") from None
    except ValueError as exc:
        raise ValueError(f"{run_dir / RUN_FILE} is not JSON: {exc}") from None
    scenario = load_scenario(run_dir / SCENARIO_FILE)
    record = record_from_log(run_dir, run["vehicle"], scenario, run["controller"], run["plant"],
                             run["rate_hz"], with_truth=run.get("state_source") == "estimator")
    metrics = compute_metrics(record, scenario, run["airframe"])
    metrics["mode"] = run["mode"]
    metrics["sensors"] = run.get("sensors", "ideal")
    metrics["state_source"] = run.get("state_source", "auto")
    metrics["seed"] = run.get("seed", 0)
    metrics["parameters"] = run.get("parameters", {})
    metrics["perturbations_applied"] = [
        {k: e[k] for k in ("process", "sim_time_us", "event", "id", "kind")}
        for e in perturbation_events(run_dir, run["vehicle"])]
    metrics["events"] = [e.to_json() for e in run_events(
        run_dir, run["vehicle"], record.sim_time_us, record.mode_index, record.flags,
        -record.true_state[:, MEAS_Z])]
    for extra in ("telemetry", "timing"):
        if run.get(extra):
            metrics[extra] = run[extra]
    metrics.update(timeline_figures(run_dir))  # the loop's speed, the command's wall time
    write_json(run_dir / METRICS_FILE, metrics)
    if figures:
        marks = marks_of(metrics, record.sim_time_us, record.time_s)
        plot_run(record, scenario, run_dir, marks)
        write_page(run_dir, metrics, run, record, scenario, marks)
    return metrics, record


def write_page(run_dir: Path, metrics: dict[str, Any], run: dict[str, Any], record: RunRecord,
               scenario: Scenario, marks: Marks) -> Path:
    """report.html: the run on one self-contained page (ground/report/run_page.py)."""
    planned = None
    if metrics.get("path"):
        planned = np.array(planned_legs(scenario)[0])
    truth = record.true_state
    path_png = (path_figure(truth[:, 0:3], record.reference[:, 0:3], planned)
                if scenario.plan is not None or np.ptp(truth[:, 0:2]) > 0.5 else None)
    outcomes = None
    if scenario.expect.names() != [COMPLETED]:
        outcomes = [(o.name, o.passed, o.message) for o in evaluate(scenario.expect, metrics)]
    page = run_dir / PAGE_FILE
    write_atomic(page, run_page(run_dir, metrics, run, marks, path_png, outcomes))
    return page


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
