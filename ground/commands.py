"""What each ``ivfm`` subcommand does (the argument parsing is in cli.py)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from autopilot.control.factory import load_models
from autopilot.control.parameters import PARAMETERS, validate_parameters
from autopilot.identification.ts_model import FuzzyModelSet
from contracts.airframe import airframe_by_name
from ground.scenarios import SCENARIOS, scenario_by_name


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (temp file + rename) so no half-written file is left."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2, allow_nan=False)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run_command(args: argparse.Namespace) -> int:
    from ground.figures import plot_run
    from ground.inprocess import run_inprocess
    from ground.metrics import compute_metrics
    from ground.processes import run_processes

    scenario = scenario_by_name(args.scenario)
    airframe = airframe_by_name(args.airframe)
    parameters = validate_parameters(dict(args.param))
    models = load_models(args.model) if args.controller in ("ivfc", "t1fc") else None
    how = ("in process" if args.inprocess else
           "simulator + autopilot, real time" if args.realtime else
           "simulator + autopilot, lockstep")
    print(f"ivfm: {scenario.name} with {args.controller} on the {args.plant} plant "
          f"({scenario.duration_s:g} s sim, {how})", file=sys.stderr)
    timing: dict = {}
    if args.inprocess:
        record = run_inprocess(scenario, args.controller, args.plant, airframe, models,
                               period_s=1.0 / args.rate_hz, parameters=parameters)
    else:
        overrides = {k: v for k, v in parameters.items() if k in dict(args.param)}
        record, timing = run_processes(
            scenario, args.controller, args.plant, args.airframe, args.out, args.model,
            overrides, realtime=args.realtime, rate_hz=args.rate_hz,
            state_source=args.state_source)
    metrics = compute_metrics(record, scenario, args.airframe)
    metrics["mode"] = "inprocess" if args.inprocess else (
        "realtime" if args.realtime else "lockstep")
    metrics["parameters"] = parameters
    if timing:
        metrics["timing"] = timing
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "metrics.json", metrics)
    if not args.no_figures:
        plot_run(record, scenario, args.out)
    print(format_metrics(metrics))
    print(f"wrote {args.out / 'metrics.json'}" + ("" if args.no_figures else " and figures"))
    return 1 if record.diverged else 0


def format_metrics(metrics: dict[str, Any]) -> str:
    lines = [f"{metrics['scenario']} | {metrics['controller']} | {metrics['plant']} plant | "
             f"{metrics['sim_time_s']:.1f} s sim in {metrics['wall_time_s']:.2f} s wall "
             f"({metrics['real_time_factor']:.0f}x real time)"
             + (" | DIVERGED" if metrics["diverged"] else "")]
    lines.append(f"  errors after {metrics['transient_s']:g} s:")
    for axis, m in metrics["axes"].items():
        lines.append(f"    {axis:>5}: rmse {m['rmse']:.5f}  mse {m['mse']:.3e}  "
                     f"max {m['max_abs']:.4f}")
    c = metrics["control"]
    lines.append(f"  effort {c['effort_mean_sum_c2']:.4f}  chattering "
                 f"{c['chattering_per_s']:.3f}/s  saturated {100 * c['saturated_fraction']:.1f} %")
    return "\n".join(lines)


def compare_command(args: argparse.Namespace) -> int:
    from ground.compare import run_comparison

    for name in args.scenarios:
        scenario_by_name(name)
    airframe_by_name(args.airframe)
    parameters = validate_parameters(dict(args.param))
    models = load_models(args.model)
    return run_comparison(args.scenarios, args.controllers, args.plants, args.airframe, models,
                          parameters, args.out)


def identify_command(args: argparse.Namespace) -> int:
    from autopilot.identification.dataset import read_dataset, write_dataset
    from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
    from autopilot.identification.model_file import save_model
    from ground.excitation import excitation_dataset
    from ground.paper_tables import TABLE_2_VALIDATION_RMSE

    airframe = airframe_by_name(args.airframe)
    n_clusters = DEFAULT_N_CLUSTERS if args.clusters is None else args.clusters
    if n_clusters < 2:
        raise ValueError(f"--clusters must be at least 2, got {n_clusters}")
    start = time.perf_counter()
    if args.data is not None:
        dataset = read_dataset(args.data)
        print(f"ivfm: identifying from {args.data} ({dataset.n_rows} samples)", file=sys.stderr)
    else:
        print(f"ivfm: flying the excitation ({args.samples} samples, seed {args.seed})",
              file=sys.stderr)
        dataset = excitation_dataset(airframe, n_samples=args.samples, seed=args.seed)
    models = identify_dataset(dataset, n_clusters=n_clusters, seed=args.seed,
                              metadata={"airframe": args.airframe})
    elapsed = time.perf_counter() - start
    print(format_table_2(models, TABLE_2_VALIDATION_RMSE))
    print(f"identification took {elapsed:.2f} s")
    if args.write_data is not None:
        write_dataset(args.write_data, dataset)
        print(f"wrote {args.write_data}")
    if args.out is not None:
        save_model(args.out, models)
        print(f"wrote {args.out}")
    return 0


def format_table_2(models: FuzzyModelSet, paper: dict[str, tuple[float, float]]) -> str:
    lines = ["Validation RMSE of the identified models (paper's Table 2 beside ours)",
             f"{'function':<10}{'paper T1FM':>12}{'paper IVFM':>12}{'our T1FM':>12}"
             f"{'our IVFM':>12}  IVFM better?"]
    for name, ch in models.channels.items():
        p_t1, p_iv = paper[name]
        better = ch.rmse_valid_ivfm < ch.rmse_valid_t1fm
        verdict = "yes" if better else ("equal" if ch.rmse_valid_ivfm == ch.rmse_valid_t1fm
                                        else "no")
        lines.append(f"f_{name:<8}{p_t1:>12.4f}{p_iv:>12.4f}{ch.rmse_valid_t1fm:>12.4f}"
                     f"{ch.rmse_valid_ivfm:>12.4f}  {verdict}")
        lines.extend(f"    note: {note}" for note in ch.notes)
    return "\n".join(lines)


def scenarios_command(args: argparse.Namespace) -> int:
    for s in SCENARIOS.values():
        print(f"{s.name:<16} {s.description} (judged on {', '.join(s.axes)} after "
              f"{s.transient_s:g} s)")
    return 0


def params_command(args: argparse.Namespace) -> int:
    for p in PARAMETERS:
        print(f"{p.name:<16} {p.default:>10g}  [{p.minimum:g}, {p.maximum:g}] {p.unit:<8}"
              f" {p.description}")
    return 0


def sitl_command(args: argparse.Namespace) -> int:
    from sitl.__main__ import run

    return run(args)


def autopilot_command(args: argparse.Namespace) -> int:
    from autopilot.__main__ import run

    return run(args)
