"""The flake hunt: the whole process tier, as CI runs it, several times back to back,
alone or beside CPU-bound neighbours, keeping everything a failure leaves behind.

    python tests/stress/tier_runs.py --runs 6                    # quiet
    python tests/stress/tier_runs.py --runs 4 --neighbours 1     # beside a CPU-bound loop
    python tests/stress/tier_runs.py --runs 2 --out runs/flakes -k mavsdk

Each run is the two commands of ``.ci/run``'s process tier (four at a time, then the
tests marked ``alone`` one at a time). A neighbour is
``ivfm run attitude-sine --inprocess`` in a loop, at ``--nice`` (default 0: it competes
as any other work would). For each run the script keeps, under ``--out``:

* ``run-N/<tier>.txt``: pytest's whole output (the failures' tracebacks and captured
  output, which name the processes' logs);
* ``run-N/<tier>.xml``: JUnit, with every test's duration;
* ``run-N/tmp-<tier>/``: every test's temporary folder (process logs, MCAP files, run
  folders): pytest's "failed" retention drops the folder of a test whose fixture failed,
  and those are flakes too. A whole run is some hundred megabytes.

At the end it prints a table: per run, per tier, passed, failed, wall time and the
failed tests by name, and the load average during the run. Exits 1 if any test failed.
Asserts nothing else; the machine is the one it runs on.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TIERS = {  # name -> pytest arguments, as .ci/run runs them
    "parallel": ["-m", "process and not alone", "-n", "4", "--dist", "worksteal"],
    "alone": ["-m", "process and alone"],
}
NEIGHBOUR = ("while true; do {nice}{python} -m ground.cli run attitude-sine --inprocess "
             "--out {out} >/dev/null 2>&1; done")


@dataclass
class TierResult:
    run: int
    tier: str
    wall_s: float
    passed: int = 0
    failed: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    load: tuple[float, float] = (0.0, 0.0)  # 1-min load average at start and end


def junit_counts(path: Path) -> tuple[int, list[str], list[str]]:
    """(passed, failed, errored) test names from a JUnit file."""
    if not path.exists():
        return 0, [], [f"no JUnit written ({path.name})"]
    passed, failed, errors = 0, [], []
    for case in ET.parse(path).getroot().iter("testcase"):
        name = f"{case.get('classname')}::{case.get('name')}"
        if case.find("failure") is not None:
            failed.append(name)
        elif case.find("error") is not None:
            errors.append(name)
        elif case.find("skipped") is None:
            passed += 1
    return passed, failed, errors


def run_tier(run: int, tier: str, folder: Path, extra: list[str]) -> TierResult:
    folder.mkdir(parents=True, exist_ok=True)
    xml = folder / f"{tier}.xml"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *TIERS[tier],
           f"--junitxml={xml}", f"--basetemp={folder / f'tmp-{tier}'}",
           "-o", "tmp_path_retention_policy=all", "-o", "tmp_path_retention_count=1",
           *extra]
    load0 = os.getloadavg()[0]
    started = time.monotonic()
    with open(folder / f"{tier}.txt", "w") as out:
        subprocess.run(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, check=False)
    result = TierResult(run, tier, time.monotonic() - started)
    result.passed, result.failed, result.errors = junit_counts(xml)
    result.load = (load0, os.getloadavg()[0])
    return result


def start_neighbours(count: int, nice: int, out: Path) -> list[subprocess.Popen]:
    prefix = f"nice -n {nice} " if nice else ""
    return [subprocess.Popen(["bash", "-c", NEIGHBOUR.format(
        nice=prefix, python=sys.executable, out=out / f"neighbour-{i}")],
        cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL) for i in range(count)]


def stop_neighbours(procs: list[subprocess.Popen]) -> None:
    for proc in procs:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        proc.wait()


def table(results: list[TierResult]) -> str:
    lines = ["| run | tier | passed | failed | wall s | load (start, end) | failed tests |",
             "|---|---|---|---|---|---|---|"]
    for r in results:
        bad = r.failed + r.errors
        lines.append(f"| {r.run} | {r.tier} | {r.passed} | {len(bad)} | {r.wall_s:.0f} | "
                     f"{r.load[0]:.1f}, {r.load[1]:.1f} | {'<br>'.join(bad) or '-'} |")
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=6)
    p.add_argument("--neighbours", type=int, default=0, help="CPU-bound loops beside it")
    p.add_argument("--nice", type=int, default=0, help="the neighbours' niceness")
    p.add_argument("--tiers", default="parallel,alone",
                   help="which of: parallel, alone (comma-separated)")
    p.add_argument("--out", type=Path, default=Path("runs/tier-runs"))
    p.add_argument("-k", default=None, help="only the tests matching (pytest -k)")
    args = p.parse_args()
    tiers = [t for t in args.tiers.split(",") if t]
    unknown = set(tiers) - set(TIERS)
    if unknown:
        p.error(f"unknown tier(s) {sorted(unknown)}: choose from {sorted(TIERS)}")
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    extra = ["-k", args.k] if args.k else []
    neighbours = start_neighbours(args.neighbours, args.nice, out)
    results: list[TierResult] = []
    try:
        for run in range(1, args.runs + 1):
            for tier in tiers:
                r = run_tier(run, tier, out / f"run-{run}", extra)
                results.append(r)
                bad = r.failed + r.errors
                print(f"run {run} {tier}: {r.passed} passed, {len(bad)} failed in "
                      f"{r.wall_s:.0f} s (load {r.load[0]:.1f} -> {r.load[1]:.1f})"
                      + "".join(f"\n    FAILED {name}" for name in bad), flush=True)
    finally:
        stop_neighbours(neighbours)
    summary = table(results)
    (out / "summary.md").write_text(summary + "\n")
    print(summary)
    failures = sum(len(r.failed) + len(r.errors) for r in results)
    print(f"{failures} failure(s) in {args.runs} run(s), "
          f"{args.neighbours} neighbour(s) at nice {args.nice}; kept under {out}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
