"""Every controller on every scenario and plant: tables beside the paper's, and figures."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from autopilot.models.ts_model import FuzzyModelSet  # noqa: E402
from contracts.airframe import airframe_from_spec  # noqa: E402
from contracts.airframe_file import AirframeSpec  # noqa: E402
from contracts.atomic_file import write_atomic
from contracts.frames import altitude_m  # noqa: E402
from ground.identify.paper_tables import PAPER_MSE_BY_SCENARIO  # noqa: E402
from ground.record.run_files import write_json  # noqa: E402
from ground.report.metrics import AXES, axis_error, compute_metrics  # noqa: E402
from ground.run.inprocess import run_inprocess  # noqa: E402
from ground.run.progress import ProgressLine
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402


def run_comparison(
    scenarios: list[str],
    controllers: list[str],
    plants: list[str],
    airframe_spec: AirframeSpec,
    models: FuzzyModelSet,
    parameters: dict[str, float],
    out_dir: Path,
) -> int:


    airframe = airframe_from_spec(airframe_spec)
    total = len(scenarios) * len(controllers) * len(plants)
    results: list[dict[str, Any]] = []
    records = {}
    done = 0
    start = time.perf_counter()
    for plant in plants:
        for name in scenarios:
            scenario = scenario_by_name(name).on_airframe(airframe_spec)
            for controller in controllers:
                line = ProgressLine(f"[{done + 1:>3}/{total}] {plant} {name} {controller}",
                                    scenario.duration_s)
                try:
                    record = run_inprocess(scenario, controller, plant, airframe, models,
                                           parameters=parameters, progress=line.update)
                finally:
                    line.done()
                metrics = compute_metrics(record, scenario, airframe_spec.argument)
                results.append(metrics)
                records[(plant, name, controller)] = record
                done += 1
                flag = " DIVERGED" if record.diverged else ""
                print(f"[{done:>3}/{total}] {plant:<10} {name:<15} {controller:<5} "
                      f"{record.wall_time_s:5.2f} s{flag}", file=sys.stderr)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "comparison.json", {"airframe": airframe_spec.argument, "runs": results})
    table = comparison_markdown(results, scenarios, controllers, plants)
    write_atomic(out_dir / "comparison.md", table)
    for plant in plants:
        for name in scenarios:
            plot_overlay(records, plant, name, controllers, out_dir)
    print(table)
    print(f"wrote {out_dir / 'comparison.md'}, comparison.json and figures "
          f"({time.perf_counter() - start:.1f} s)")
    return 1 if any(r["diverged"] for r in results) else 0


def _fmt(value: float | None, spec: str = ".4g") -> str:
    return "n/a" if value is None else format(value, spec)


def comparison_markdown(results: list[dict[str, Any]], scenarios: list[str],
                        controllers: list[str], plants: list[str]) -> str:
    by_key = {(r["plant"], r["scenario"], r["controller"]): r for r in results}
    lines = ["# Controller comparison", "",
             "RMSE [rad or m] / MSE per tracked axis after each scenario's transient; effort = "
             "mean sum c_i^2; chattering = total variation of the motor commands per second. "
             "The paper's \"MSE\" (metric not printed) is shown as IVFC / T1FC where it "
             "published one.", ""]
    for plant in plants:
        for name in scenarios:
            axes = scenario_by_name(name).axes
            lines.append(f"## {name} on the {plant} plant")
            lines.append("")
            header = "| controller | " + " | ".join(f"{a} rmse | {a} mse" for a in axes)
            lines.append(header + " | effort | chattering/s | diverged |")
            lines.append("|" + "---|" * (2 * len(axes) + 4))
            for controller in controllers:
                r = by_key[(plant, name, controller)]
                cells = []
                for a in axes:
                    m = r["axes"][a]
                    cells += [_fmt(m["rmse"]), _fmt(m["mse"])]
                c = r["control"]
                lines.append(f"| {controller} | " + " | ".join(cells)
                             + f" | {_fmt(c['effort_mean_sum_c2'])} | "
                             f"{_fmt(c['chattering_per_s'])} | {r['diverged']} |")
            paper = PAPER_MSE_BY_SCENARIO.get(name)
            if paper:
                cells = []
                for a in axes:
                    cells += ["", f"{paper[a][0]:g} / {paper[a][1]:g}" if a in paper else ""]
                lines.append("| paper IVFC / T1FC | " + " | ".join(cells) + " | | | |")
            if "ivfc" in controllers and "t1fc" in controllers:
                iv, t1 = by_key[(plant, name, "ivfc")], by_key[(plant, name, "t1fc")]
                verdicts = []
                for a in axes:
                    x, y = iv["axes"][a]["rmse"], t1["axes"][a]["rmse"]
                    if x is not None and y is not None:
                        margin = f" ({(y - x) / y * 100:+.1f} %)" if y > 0 else ""
                        verdicts.append(f"{a} {'yes' if x <= y else 'NO'}{margin}")
                lines.append("")
                lines.append("IVFC RMSE <= T1FC RMSE (margin relative to T1FC): "
                             + ", ".join(verdicts))
            lines.append("")
    return "\n".join(lines)


def plot_overlay(records: dict, plant: str, name: str, controllers: list[str],
                 out_dir: Path) -> Path:
    axes = scenario_by_name(name).axes
    fig, plots = plt.subplots(len(axes), 1, figsize=(10, 2.0 * len(axes)), sharex=True)
    for row, axis in enumerate(axes):
        ax = plots[row]
        first = records[(plant, name, controllers[0])]
        _, meas_index = AXES[axis]
        reference = first.measurement[:, meas_index] + axis_error(first, axis)
        shown = altitude_m if axis == "z" else (lambda v: v)
        ax.plot(first.time_s, shown(reference), "k--", lw=1.0, label="reference")
        for i, controller in enumerate(controllers):
            r = records[(plant, name, controller)]
            ax.plot(r.time_s, shown(r.measurement[:, meas_index]), f"C{i}", lw=1.0,
                    label=controller)
        ax.set_ylabel("altitude" if axis == "z" else axis)
    plots[0].legend(ncol=len(controllers) + 1, fontsize=8, loc="upper right")
    plots[-1].set_xlabel("t [s]")
    fig.suptitle(f"{name} on the {plant} plant")
    fig.tight_layout()
    path = out_dir / f"{name}_{plant}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


