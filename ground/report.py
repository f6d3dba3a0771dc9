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

from contracts.telemetry import CHANNEL_INTERNALS, CONTROL, vehicle_key
from ground.inprocess import RunRecord
from ground.logger import iter_messages
from ground.scenarios import Scenario, load_scenario

RUN_FILE = "run.json"
SCENARIO_FILE = "scenario.toml"


def control_records(log: Path, vehicle: int) -> dict[str, np.ndarray]:
    """The autopilot's control records of one vehicle as arrays (one row per step), plus
    ``log_time_ns``; checks that no sequence number is missing."""
    key = vehicle_key(vehicle, "autopilot", "control")
    rows: list[dict[str, Any]] = []
    log_times = []
    for topic, message, data in iter_messages(log, key):
        if topic != key:
            continue
        rows.append(CONTROL.decode(data))
        log_times.append(message.log_time)
    if not rows:
        raise ValueError(f"no control records of vehicle {vehicle} ({key}) in {log}")
    rows.sort(key=lambda r: int(r["seq"]))
    seq = np.array([int(r["seq"]) for r in rows])
    out = {name: np.array([r[name] for r in rows]) for name in rows[0]
           if not name.startswith("theta_f_")}
    for name in ("theta_f_phi", "theta_f_theta", "theta_f_psi"):
        out[name] = np.array([r[name] for r in rows])
    out["log_time_ns"] = np.array(sorted(log_times))
    out["missing"] = np.setdiff1d(np.arange(seq[0], seq[-1] + 1), seq)
    return out


def record_from_log(log: Path, vehicle: int, scenario: Scenario, controller: str, plant: str,
                    rate_hz: float) -> RunRecord:
    r = control_records(log, vehicle)
    n = len(r["seq"])
    measurement = r["measurement"]
    internals = np.stack([r[f"ch_{name}"] for name in CHANNEL_INTERNALS], axis=2)
    wall = (r["log_time_ns"][-1] - r["log_time_ns"][0]) / 1e9 if n > 1 else math.nan
    diverged = bool(n < round(scenario.duration_s * rate_hz) or len(r["missing"]) or
                    not np.all(np.isfinite(measurement)) or
                    np.max(np.abs(measurement[:, 0:3])) > 1e3)
    return RunRecord(
        scenario=scenario.name, controller=controller, plant=plant, period_s=1.0 / rate_hz,
        time_s=r["reference_time_s"], measurement=measurement, reference=r["reference"],
        kick=r["kick_rad"], motor_commands=r["motor_commands"], channel_telemetry=internals,
        theta_g=r["theta_g"], theta_f=[r["theta_f_phi"], r["theta_f_theta"], r["theta_f_psi"]],
        wall_time_s=wall or math.nan, diverged=diverged)


def perturbation_events(log: Path, vehicle: int) -> list[dict[str, Any]]:
    """Every perturbation the vehicle's processes applied, with the sim time it took effect."""
    events = []
    for process in ("sitl", "autopilot"):
        key = vehicle_key(vehicle, process, "perturbation")
        for topic, _message, data in iter_messages(log, key):
            if topic == key:
                events.append({"process": process, **json.loads(data)})
    return sorted(events, key=lambda e: (e["sim_time_us"], e["process"], e["seq"]))


def report(run_dir: Path, figures: bool = True) -> tuple[dict[str, Any], RunRecord]:
    """metrics.json (and figures) of a run folder, from its log."""
    from ground.commands import write_json
    from ground.figures import plot_run
    from ground.metrics import compute_metrics

    run_dir = Path(run_dir)
    try:
        run = json.loads((run_dir / RUN_FILE).read_text())
    except FileNotFoundError:
        raise ValueError(f"{run_dir} has no {RUN_FILE}: is it a folder ivfm run wrote?") from None
    except ValueError as exc:
        raise ValueError(f"{run_dir / RUN_FILE} is not JSON: {exc}") from None
    scenario = load_scenario(run_dir / SCENARIO_FILE)
    record = record_from_log(run_dir, run["vehicle"], scenario, run["controller"], run["plant"],
                             run["rate_hz"])
    metrics = compute_metrics(record, scenario, run["airframe"])
    metrics["mode"] = run["mode"]
    metrics["parameters"] = run.get("parameters", {})
    metrics["perturbations_applied"] = [
        {k: e[k] for k in ("process", "sim_time_us", "event", "id", "kind")}
        for e in perturbation_events(run_dir, run["vehicle"])]
    for extra in ("telemetry", "timing"):
        if run.get(extra):
            metrics[extra] = run[extra]
    write_json(run_dir / "metrics.json", metrics)
    if figures:
        plot_run(record, scenario, run_dir)
    return metrics, record
