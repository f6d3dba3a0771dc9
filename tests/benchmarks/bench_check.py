"""Benchmark of the regression path: ``ivfm run`` through the processes and ``ivfm check``
of the paper's seven scenarios, beside the in-process path measured in the same run (the
machine's speed moves up to 3x between days: compare the ratios).

    python tests/benchmarks/bench_check.py             # best of 3 single runs; the check
                                                       # one at a time and at its default -j
    python tests/benchmarks/bench_check.py --runs 5 --jobs 1   # not the default -j

Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PAPER = ("attitude-sine", "attitude-hold", "position-sine", "attitude-jr-10",
         "attitude-jr-15", "attitude-jr-20", "position-kick")


def ivfm(*args: str) -> float:
    """Wall time of one ivfm command [s]."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ground.cli", *args], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


# The same seven flown in process by one fresh Python (what ivfm check would be without
# the processes): planned, flown, their metrics computed and judged, no figures.
IN_PROCESS_SEVEN = """
import sys
from pathlib import Path
from ground.run.flights import fly_inprocess, plan_flight
from ground.scenario.expectations import evaluate
from ground.scenario.scenario_file import scenario_by_name
out = Path(sys.argv[1])
for name in sys.argv[2:]:
    scenario = scenario_by_name(name)
    (out / name).mkdir(parents=True, exist_ok=True)
    metrics = fly_inprocess(plan_flight(scenario), out / name, figures=False)
    evaluate(scenario.expect, metrics)
"""


def loop_wall_s(metrics: dict) -> float:
    """The loop's wall time: from the run's loop figure, else the log's first to last
    control record."""
    return metrics.get("loop_wall_time_s") or metrics["wall_time_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=None,
                        help="ivfm check -j (default: the command's own)")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-check-"))
    ivfm("run", "position-kick", "--out", str(tmp / "warm"), "--no-figures")  # caches warm

    rows = []
    for k in range(args.runs):
        whole = ivfm("run", "position-kick", "--out", str(tmp / f"pk{k}"), "--no-figures")
        m = json.loads((tmp / f"pk{k}" / "metrics.json").read_text())
        with_figures = ivfm("run", "position-kick", "--out", str(tmp / f"fig{k}"))
        ivfm("run", "position-kick", "--inprocess", "--out", str(tmp / f"in{k}"),
             "--no-figures")
        inproc = json.loads((tmp / f"in{k}" / "metrics.json").read_text())
        rows.append((whole, loop_wall_s(m), m["sim_time_s"] / loop_wall_s(m),
                     inproc["real_time_factor"], with_figures))
    best = min(rows)
    print("ivfm run position-kick (logger + simulator + autopilot, lockstep), best of "
          f"{args.runs}:")
    print(f"  whole command {best[0]:.2f} s with --no-figures, "
          f"{min(r[4] for r in rows):.2f} s with the figures; loop {best[1]:.2f} s "
          f"({best[2]:.1f}x real time); start-up and teardown {best[0] - best[1]:.2f} s")
    print(f"  in-process path in the same run: {best[3]:.1f}x real time; loop at "
          f"{100 * best[2] / best[3]:.0f} % of it")
    phases = json.loads((tmp / f"pk{rows.index(best)}" / "timeline.json").read_text())
    print("  phases of that run [s]: " + ", ".join(
        f"{name} {t:.3f}" for name, t in phases["phases_s"].items()))

    def check(jobs: list[str], name: str) -> tuple[float, float]:
        """Wall time of ``ivfm check`` of the seven and the sum of their loop times."""
        out = tmp / name
        wall = ivfm("check", *PAPER, "--out", str(out), "--junit", str(tmp / "junit.xml"),
                    "--keep", *jobs)
        results = json.loads((out / "check.json").read_text())["scenarios"]
        return wall, sum(loop_wall_s(r["metrics"]) for r in results.values())

    # One at a time first: its loops are the flights' own time (runs side by side slow
    # each other's loops, so their sum is no measure of the flights).
    wall_1, loops_1 = check(["-j", "1"], "check-1")
    wall, loops = (wall_1, loops_1) if args.jobs == 1 else check(
        [] if args.jobs is None else ["-j", str(args.jobs)], "check")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", IN_PROCESS_SEVEN, str(tmp / "inprocess"), *PAPER],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    in_process_s = time.perf_counter() - start
    print(f"ivfm check of the paper's seven scenarios, JUnit written; the seven one at a "
          f"time: {wall_1:.2f} s wall, sum of their loop times {loops_1:.2f} s")
    print(f"  -j {args.jobs or 'default'}: {wall:.2f} s wall (its runs' loops sum to "
          f"{loops:.2f} s): {wall / loops_1:.2f}x the loops one at a time; the same seven "
          f"flown in process by one fresh Python {in_process_s:.2f} s: "
          f"{wall / in_process_s:.2f}x")

if __name__ == "__main__":
    main()
