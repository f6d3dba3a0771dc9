"""Roll against pitch: the IVFC's and T1FC's attitude-sine errors on models identified
with several excitation seeds (the paper airframe, c = 5, 5 % noise, in process).

The airframe and the reference are symmetric in roll and pitch, so over seeds neither
axis should be worse. With an independent random multisine per axis, theta was worse in
6 of 8 seeds, by 1.7x in the median: each seed gave roll and pitch different spectra.
Prints per seed the validation RMSE of f_phi and f_theta and the tracking RMSE of phi and
theta, then the median theta/phi ratio and how often theta is worse.

    python tests/benchmarks/bench_roll_pitch_gap.py --seeds 8

It uses only ``excitation_dataset`` and ``identify_dataset``, so it also runs on an
earlier commit: ``git worktree add /tmp/old COMMIT``, copy this file to
``/tmp/old/tests/benchmarks/`` and run it from there (it imports the tree it is in).
Asserts nothing: the figures are for docs/reproducing.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).parents[2]
sys.path.insert(0, str(ROOT))

from autopilot.identification.identify import identify_dataset  # noqa: E402
from contracts.airframe import PAPER  # noqa: E402
from ground.identify.excitation import excitation_dataset  # noqa: E402
from ground.report.metrics import compute_metrics  # noqa: E402
from ground.run.inprocess import run_inprocess  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=8, help="excitation seeds 0..N-1")
    parser.add_argument("--scenario", default="attitude-sine")
    args = parser.parse_args()
    scenario = scenario_by_name(args.scenario)
    ratios: dict[str, list[float]] = {"ivfc": [], "t1fc": []}
    print(f"{'seed':>4} {'fit f_phi':>10} {'f_theta':>8} {'IVFC phi':>10} {'theta':>9} "
          f"{'T1FC phi':>10} {'theta':>9}")
    for seed in range(args.seeds):
        models = identify_dataset(excitation_dataset(PAPER, seed=seed), n_clusters=5,
                                  seed=seed)
        row = [models.channels["phi"].rmse_valid_ivfm, models.channels["theta"].rmse_valid_ivfm]
        for controller in ("ivfc", "t1fc"):
            record = run_inprocess(scenario, controller, scenario.plant, PAPER, models)
            axes = compute_metrics(record, scenario, "paper")["axes"]
            row += [axes["phi"]["rmse"], axes["theta"]["rmse"]]
            ratios[controller].append(axes["theta"]["rmse"] / axes["phi"]["rmse"])
        print(f"{seed:>4} {row[0]:>10.4f} {row[1]:>8.4f} {row[2]:>10.5f} {row[3]:>9.5f} "
              f"{row[4]:>10.5f} {row[5]:>9.5f}")
    for controller, r in ratios.items():
        worse = sum(x > 1.0 for x in r)
        print(f"{controller.upper()}: median theta/phi {statistics.median(r):.2f}, "
              f"theta worse in {worse} of {len(r)} seeds")


if __name__ == "__main__":
    main()
