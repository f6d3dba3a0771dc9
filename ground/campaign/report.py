"""A campaign's report from its rows: report.json, report.md and figures.

Per scenario, controller and axis: mean, median and p95 RMSE with 95 % bootstrap
intervals; per scenario and axis, each controller against the first one listed, draw by
draw (win rate, the paired difference and ratio, with intervals); figures of the
distributions, their CDFs, and RMSE against each drawn factor. An identification
campaign compares IVFM with T1FM per channel and cluster count the same way.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic_file import write_atomic
from ground.campaign.stats import paired, summary, verdict
from ground.report.figures import plt

AXES = ("phi", "theta", "psi", "z", "x", "y")
CHANNELS = ("phi", "theta", "psi")
NOT_FACTORS = {"id", "kind", "draw", "error", "worker_pid", "wall_s", "scenario", "controller",
               "diverged", "effort", "chattering_per_s", "replay", "identification_seed"}


def _value(row: dict[str, Any], key: str) -> float:
    value = row.get(key)
    return float(value) if isinstance(value, int | float) and not row.get("error") else np.nan


def flight_report(rows: list[dict[str, Any]], controllers: tuple[str, ...]) -> dict[str, Any]:
    scenarios = sorted({r["scenario"] for r in rows if "scenario" in r})
    out: dict[str, Any] = {"runs": len(rows), "failed": [
        {"id": r["id"], "error": r["error"]} for r in rows if r.get("error")],
        "scenarios": {}}
    for scenario in scenarios:
        mine = [r for r in rows if r.get("scenario") == scenario]
        axes = [a for a in AXES if any(f"{a}_rmse" in r for r in mine)]
        draws = sorted({r["draw"] for r in mine})
        table = {c: {r["draw"]: r for r in mine if r.get("controller") == c}
                 for c in controllers}
        section: dict[str, Any] = {"draws": len(draws), "axes": axes, "controllers": {},
                                   "paired": {}}
        for c in controllers:
            section["controllers"][c] = {
                "failed": sum(1 for r in table[c].values() if r.get("error")),
                **{axis: summary([_value(r, f"{axis}_rmse") for r in table[c].values()])
                   for axis in axes}}
        first = controllers[0]
        for other in controllers[1:]:
            section["paired"][f"{first} vs {other}"] = {}
            for axis in axes:
                a = [_value(table[first].get(d, {}), f"{axis}_rmse") for d in draws]
                b = [_value(table[other].get(d, {}), f"{axis}_rmse") for d in draws]
                comparison = paired(np.array(a), np.array(b))
                comparison["verdict"] = verdict(comparison).replace(
                    "a better", f"{first} better").replace("b better", f"{other} better")
                section["paired"][f"{first} vs {other}"][axis] = comparison
        out["scenarios"][scenario] = section
    return out


def identification_report(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"runs": len(rows), "failed": [
        {"id": r["id"], "error": r["error"]} for r in rows if r.get("error")], "clusters": {}}
    for clusters in sorted({int(r["clusters"]) for r in rows if "clusters" in r}):
        mine = [r for r in rows if r.get("clusters") == clusters]
        section: dict[str, Any] = {"draws": len(mine)}
        for ch in CHANNELS:
            ivfm = np.array([_value(r, f"{ch}_ivfm_rmse") for r in mine])
            t1fm = np.array([_value(r, f"{ch}_t1fm_rmse") for r in mine])
            comparison = paired(ivfm, t1fm)
            comparison["verdict"] = verdict(comparison).replace(
                "a better", "IVFM better").replace("b better", "T1FM better")
            section[ch] = {"ivfm": summary(ivfm), "t1fm": summary(t1fm),
                           "paired": comparison}
        out["clusters"][str(clusters)] = section
    return out


def _ci(values: list[float] | None, fmt: str = ".3g") -> str:
    if not values or values[0] is None or not np.isfinite(values[0]):
        return "-"
    return f"[{values[0]:{fmt}}, {values[1]:{fmt}}]"


def _num(value: float | None, fmt: str = ".3g") -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:{fmt}}"


def markdown(name: str, kind: str, report: dict[str, Any]) -> str:
    lines = [f"# Campaign {name}", "",
             f"{report['runs']} runs, {len(report['failed'])} failed. Intervals: 95 % "
             "(bootstrap; win rates: Wilson).", ""]
    if kind == "identification":
        lines.append("Validation RMSE of the identified models, IVFM against T1FM on the same "
                     "data (lower is better).")
        for clusters, section in report["clusters"].items():
            lines += ["", f"## c = {clusters} clusters ({section['draws']} identifications)",
                      "", "| channel | IVFM median [95 % CI] | T1FM median [95 % CI] | IVFM wins "
                      "| median IVFM/T1FM [95 % CI] | verdict |", "|---|---|---|---|---|---|"]
            for ch in CHANNELS:
                s = section[ch]
                p = s["paired"]
                lines.append(
                    f"| f_{ch} | {_num(s['ivfm']['median'])} {_ci(s['ivfm']['median_ci'])} | "
                    f"{_num(s['t1fm']['median'])} {_ci(s['t1fm']['median_ci'])} | "
                    f"{p['wins']}/{p['n']} {_ci(p['win_rate_ci'], '.2f')} | "
                    f"{_num(p['median_ratio'])} {_ci(p['median_ratio_ci'])} | {p['verdict']} |")
    else:
        for scenario, section in report["scenarios"].items():
            lines += ["", f"## {scenario} ({section['draws']} draws)", "",
                      "| controller | axis | mean RMSE [95 % CI] | median [95 % CI] | "
                      "p95 [95 % CI] |", "|---|---|---|---|---|"]
            for c, stats_c in section["controllers"].items():
                for axis in section["axes"]:
                    s = stats_c[axis]
                    lines.append(f"| {c} | {axis} | {_num(s['mean'])} {_ci(s['mean_ci'])} | "
                                 f"{_num(s['median'])} {_ci(s['median_ci'])} | "
                                 f"{_num(s['p95'])} {_ci(s['p95_ci'])} |")
            for pair, by_axis in section["paired"].items():
                first = pair.split(" vs ")[0]
                lines += ["", f"Paired, {pair} (same draw): how often {first} has the lower "
                          "RMSE, and the difference.", "",
                          "| axis | wins [95 % CI] | median difference [95 % CI] | "
                          "median ratio [95 % CI] | verdict |", "|---|---|---|---|---|"]
                for axis, p in by_axis.items():
                    lines.append(
                        f"| {axis} | {p['wins']}/{p['n']} {_ci(p['win_rate_ci'], '.2f')} | "
                        f"{_num(p['median_difference'])} {_ci(p['median_difference_ci'])} | "
                        f"{_num(p['median_ratio'])} {_ci(p['median_ratio_ci'])} | "
                        f"{p['verdict']} |")
    if report["failed"]:
        lines += ["", "## Failed runs", ""]
        lines += [f"* {f['id']}: {f['error']}" for f in report["failed"][:50]]
        if len(report["failed"]) > 50:
            lines.append(f"* ... and {len(report['failed']) - 50} more (results.csv)")
    return "\n".join(lines) + "\n"


def flight_figures(rows: list[dict[str, Any]], controllers: tuple[str, ...],
                   out_dir: Path) -> list[Path]:
    """Per scenario: RMSE distributions (box plots), their CDFs, and RMSE against each
    drawn factor."""
    paths = []
    for scenario in sorted({r["scenario"] for r in rows if "scenario" in r}):
        mine = [r for r in rows if r.get("scenario") == scenario and not r.get("error")]
        axes = [a for a in AXES if any(f"{a}_rmse" in r for r in mine)]
        if not mine or not axes:
            continue
        fig, plots = plt.subplots(2, len(axes), figsize=(3.2 * len(axes), 6.0), squeeze=False)
        for col, axis in enumerate(axes):
            data = [[r[f"{axis}_rmse"] for r in mine if r["controller"] == c]
                    for c in controllers]
            plots[0, col].boxplot(data, showfliers=True)
            plots[0, col].set_xticks(range(1, len(controllers) + 1), controllers)
            every = np.concatenate([np.asarray(v, dtype=float) for v in data if v])
            spread = every.max() / every.min() if every.size and every.min() > 0 else 1.0
            scale = "log" if spread > 10 else "linear"  # decades apart, or close together
            plots[0, col].set_yscale(scale)
            plots[0, col].set_title(f"{axis} RMSE", fontsize=9)
            for c, values in zip(controllers, data, strict=True):
                if values:
                    v = np.sort(values)
                    plots[1, col].step(v, np.arange(1, v.size + 1) / v.size, where="post",
                                       label=c)
            plots[1, col].set_xscale(scale)
            plots[1, col].tick_params(axis="x", labelsize=7)
            plots[1, col].set_xlabel(f"{axis} RMSE")
        plots[1, 0].set_ylabel("fraction of draws")
        plots[1, 0].legend(fontsize=8)
        paths.append(_save(fig, f"{scenario}: RMSE over {len({r['draw'] for r in mine})} draws",
                           out_dir / f"{scenario}-rmse.png"))
        factors = [k for k in mine[0] if k not in NOT_FACTORS and not k.endswith(
            ("_rmse", "_max_abs", "_direction_rad", "_fraction"))
            and isinstance(mine[0][k], int | float)]
        factors = [f for f in factors if np.ptp([r.get(f, 0.0) for r in mine]) > 0][:4]
        if not factors:
            continue
        fig, plots = plt.subplots(len(axes), len(factors),
                                  figsize=(3.2 * len(factors), 2.4 * len(axes)),
                                  squeeze=False)
        for row, axis in enumerate(axes):
            for col, factor in enumerate(factors):
                for c in controllers:
                    chosen = [r for r in mine if r["controller"] == c]
                    plots[row, col].scatter([r[factor] for r in chosen],
                                            [r[f"{axis}_rmse"] for r in chosen], s=6, label=c)
                plots[row, col].tick_params(labelsize=7)
                if row == len(axes) - 1:
                    plots[row, col].set_xlabel(factor)
            plots[row, 0].set_ylabel(f"{axis} RMSE")
        plots[0, 0].legend(fontsize=7)
        paths.append(_save(fig, f"{scenario}: RMSE against what was drawn",
                           out_dir / f"{scenario}-factors.png"))
    return paths


def _save(fig: Any, title: str, path: Path) -> Path:
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_report(out_dir: Path, name: str, kind: str, controllers: tuple[str, ...],
                 rows: list[dict[str, Any]]) -> dict[str, Any]:
    """report.json, report.md and the figures in ``out_dir``."""
    report = (identification_report(rows) if kind == "identification"
              else flight_report(rows, controllers))
    write_atomic(out_dir / "report.json", json.dumps(report, indent=1))
    write_atomic(out_dir / "report.md", markdown(name, kind, report))
    if kind != "identification":
        flight_figures(rows, controllers, out_dir)
    return report
