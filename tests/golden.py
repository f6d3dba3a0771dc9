"""Golden per-axis tracking errors of every paper scenario, controller and plant.

The in-process runs are deterministic (fixed-step RK4, no noise unless a scenario asks for
it, seeded where it does), so each run's per-axis RMSE and max |error| is a fixed number
on a given machine. tests/ground/test_scenarios.py compares fresh runs with the numbers stored in
tests/golden_metrics.json at a relative tolerance of GOLDEN_REL.

After a change that is meant to move the numbers, regenerate the file and review its diff:

    cd /work/main && .venv/bin/python -m tests.golden --update

Without --update the command recomputes and reports the differences only.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

GOLDEN_PATH = Path(__file__).with_name("golden_metrics.json")
UPDATE_COMMAND = ".venv/bin/python -m tests.golden --update"
PLANTS = ("paper", "rigid-body")
# Per-axis quantities of ground.report.metrics.compute_metrics that are pinned.
QUANTITIES = ("rmse", "max_abs")
# Runs are bit-for-bit reproducible on one machine (test_runs_are_bit_for_bit_reproducible);
# 1 % leaves room for another CPU's or library's last-bit float differences growing
# through a 20 s closed loop, while a 10 % regression of any axis still fails.
GOLDEN_REL = 0.01
# Errors this small are the rounding of a controller that knows the plant exactly (SMC's
# psi): the same code gave rmse 2.36e-5 / max 2.76e-4 rad on one machine and 2.55e-5 /
# 2.98e-4 on an AMD EPYC with AVX-512. Absolute floors per quantity cover that spread
# (a single sample, the max, spreads more); anything larger is held to GOLDEN_REL.
GOLDEN_ABS = {"rmse": 5e-6, "max_abs": 5e-5}


def run_key(plant: str, scenario: str, controller: str) -> str:
    return f"{plant}/{scenario}/{controller}"


def compute_all_metrics(models: Any = None) -> dict[tuple[str, str, str], dict[str, Any]]:
    """compute_metrics of every (plant, paper scenario, controller), run in process."""
    from autopilot.control.factory import CONTROLLERS, load_models
    from contracts.airframe import PAPER
    from ground.report.metrics import compute_metrics
    from ground.run.inprocess import run_inprocess
    from ground.scenario.scenario_file import PAPER_SCENARIOS, shipped_scenarios

    if models is None:
        models = load_models(None)
    out = {}
    for plant in PLANTS:
        for name in PAPER_SCENARIOS:
            scenario = shipped_scenarios()[name]
            for controller in CONTROLLERS:
                record = run_inprocess(scenario, controller, plant, PAPER, models)
                out[(plant, name, controller)] = compute_metrics(record, scenario, "paper")
    return out


def golden_values(all_metrics: dict[tuple[str, str, str], dict[str, Any]]) -> dict[str, Any]:
    """{run_key: {axis: {quantity: value}}} of the pinned quantities."""
    return {
        run_key(*key): {
            axis: {q: values[q] for q in QUANTITIES} for axis, values in m["axes"].items()
        }
        for key, m in all_metrics.items()
    }


def load_golden(path: Path = GOLDEN_PATH) -> dict[str, Any]:
    return json.loads(path.read_text())["runs"]


def write_golden(runs: dict[str, Any], path: Path = GOLDEN_PATH) -> None:
    import numba
    import numpy

    document = {
        "header": {
            "produced_by": f"cd /work/main && {UPDATE_COMMAND}",
            "what": "per-axis rmse and max_abs (ground.report.metrics.compute_metrics) of every "
                    "(plant, ground.scenario.scenario_file.PAPER_SCENARIOS, CONTROLLERS) run in "
                    "process (ground.run.inprocess.run_inprocess, PAPER airframe, shipped fuzzy "
                    "models); "
                    "run keys are plant/scenario/controller",
            "checked_by": f"tests/ground/test_scenarios.py, pytest.approx(rel={GOLDEN_REL:g}, "
                          f"abs={GOLDEN_ABS})",
            "versions": {"python": sys.version.split()[0], "numpy": numpy.__version__,
                         "numba": numba.__version__},
        },
        "runs": runs,
    }
    path.write_text(json.dumps(document, indent=1, sort_keys=True) + "\n")


def differences(golden: dict[str, Any], fresh: dict[str, Any]) -> list[str]:
    """One line per missing, extra or out-of-tolerance value; empty when all agree."""
    import pytest

    lines = []
    for key in sorted(set(fresh) - set(golden)):
        lines.append(f"{key}: computed but has no golden value")
    for key in sorted(set(golden) - set(fresh)):
        lines.append(f"{key}: golden value for a run that is no longer computed")
    for key in sorted(set(golden) & set(fresh)):
        plant, scenario, controller = key.split("/")
        g_axes, f_axes = golden[key], fresh[key]
        if set(g_axes) != set(f_axes):
            lines.append(f"{key}: axes {sorted(f_axes)} computed, golden has {sorted(g_axes)}")
            continue
        for axis in sorted(f_axes):
            for q in QUANTITIES:
                want, got = g_axes[axis].get(q), f_axes[axis][q]
                if want is None or got is None:
                    if want is not got:
                        lines.append(f"{key} {axis} {q}: golden {want}, got {got}")
                    continue
                if got != pytest.approx(want, rel=GOLDEN_REL, abs=GOLDEN_ABS[q]):
                    change = f" ({(got - want) / abs(want):+.1%})" if want else ""
                    lines.append(f"plant={plant} scenario={scenario} controller={controller} "
                                 f"axis={axis} {q}: golden {want:.6g}, got {got:.6g}{change}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.golden", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--update", action="store_true",
                        help=f"rewrite {GOLDEN_PATH.name} with freshly computed values")
    args = parser.parse_args(argv)
    fresh = golden_values(compute_all_metrics())
    if args.update:
        write_golden(fresh)
        print(f"wrote {GOLDEN_PATH} ({len(fresh)} runs)")
        return 0
    if not GOLDEN_PATH.exists():
        print(f"{GOLDEN_PATH} missing; run {UPDATE_COMMAND}")
        return 1
    diff = differences(load_golden(), fresh)
    print("\n".join(diff) if diff else f"all {len(fresh)} runs match {GOLDEN_PATH.name}")
    return 1 if diff else 0


if __name__ == "__main__":
    raise SystemExit(main())
