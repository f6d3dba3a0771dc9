"""Reports from a run folder's MCAP log alone: ``ivfm report RUN_DIR``.

``run.json`` (written by ``ivfm run``) says how the run was flown, ``scenario.toml`` is
the scenario it flew; every number comes from the autopilot's control records in the
log, so a report can be re-computed, or computed for a log from elsewhere.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic_file import write_atomic
from contracts.mavlink import AUTOPILOT_COMPID
from contracts.telemetry import AUTOPILOT, SITL, mavlink_key, vehicle_key
from contracts.vectors import MEAS_Z
from ground.record.events import run_events
from ground.record.run_files import (
    METRICS_FILE,
    RUN_FILE,
    SCENARIO_FILE,
    LogRecords,
    RunRecord,
    perturbation_events,
    record_from_log,
    write_json,
)
from ground.record.timeline import figures as timeline_figures
from ground.report.metrics import compute_metrics, planned_legs
from ground.scenario.expectations import COMPLETED, evaluate
from ground.scenario.scenario_file import Scenario, load_scenario

PAGE_FILE = "report.html"
# report(figures=TRACKING_ONLY): the tracking figure alone, no page (a rehearsal's page
# shows each flight's tracking; the rest is ivfm report's, on request).
TRACKING_ONLY = "tracking"


def report(run_dir: Path, figures: bool | str = True) -> tuple[dict[str, Any], RunRecord]:
    """metrics.json (and figures: all with the page, none, or ``TRACKING_ONLY``) of a run
    folder, from its log."""
    run_dir = Path(run_dir)
    try:
        run = json.loads((run_dir / RUN_FILE).read_text())
    except FileNotFoundError:
        raise ValueError(f"{run_dir} has no {RUN_FILE}: is it a folder ivfm run wrote?") from None
    except ValueError as exc:
        raise ValueError(f"{run_dir / RUN_FILE} is not JSON: {exc}") from None
    scenario = load_scenario(run_dir / SCENARIO_FILE)
    vehicle, with_truth = run["vehicle"], run.get("state_source") == "estimator"
    log = LogRecords(run_dir, (  # one pass over the log for everything below
        vehicle_key(vehicle, AUTOPILOT, "control"),
        *((vehicle_key(vehicle, SITL, "state"),) if with_truth else ()),
        *(vehicle_key(vehicle, p, "perturbation") for p in (SITL, AUTOPILOT)),
        mavlink_key(vehicle, AUTOPILOT_COMPID, "STATUSTEXT")))
    record = record_from_log(log, vehicle, scenario, run["controller"], run["plant"],
                             run["rate_hz"], with_truth=with_truth)
    metrics = compute_metrics(record, scenario, run["airframe"])
    metrics["mode"] = run["mode"]
    metrics["sensors"] = run.get("sensors", "ideal")
    metrics["state_source"] = run.get("state_source", "auto")
    metrics["seed"] = run.get("seed", 0)
    metrics["parameters"] = run.get("parameters", {})
    metrics["perturbations_applied"] = [
        {k: e[k] for k in ("process", "sim_time_us", "event", "id", "kind")}
        for e in perturbation_events(log, vehicle)]
    metrics["events"] = [e.to_json() for e in run_events(
        log, vehicle, record.sim_time_us, record.mode_index, record.flags,
        -record.true_state[:, MEAS_Z])]
    for extra in ("telemetry", "timing"):
        if run.get(extra):
            metrics[extra] = run[extra]
    metrics.update(timeline_figures(run_dir))  # the loop's speed, the command's wall time
    write_json(run_dir / METRICS_FILE, metrics)
    if figures == TRACKING_ONLY:
        from ground.report.figures import plot_tracking
        from ground.report.run_page import marks_of

        plot_tracking(record, scenario, run_dir, marks_of(metrics, record.sim_time_us,
                                                          record.time_s))
    elif figures:
        write_figures(run_dir, metrics, run, record, scenario)
    return metrics, record


def write_figures(run_dir: Path, metrics: dict[str, Any], run: dict[str, Any],
                  record: RunRecord, scenario: Scenario) -> Path:
    """The figures and report.html: the run on one self-contained page
    (ground/report/run_page.py). Imported here, not with the metrics: matplotlib takes
    0.4 s of CPU, which a run without figures (``ivfm check``'s, unless asked) never needs."""
    from ground.report.figures import plot_run
    from ground.report.run_page import marks_of, path_figure, run_page

    marks = marks_of(metrics, record.sim_time_us, record.time_s)
    plot_run(record, scenario, run_dir, marks)
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
