"""``ivfm check``: scenario files flown and judged by their ``[expect]`` tables."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from contracts.arguments import number
from contracts.atomic_file import write_atomic
from ground.check.checker import (
    CheckOptions,
    Progress,
    collect,
    flights_at_once,
    read_baseline,
    run_check,
)
from ground.check.results import junit_xml, markdown_summary, results_table
from ground.cli.common import add_rt_cpus, fresh_folder

DESCRIPTION = ("Fly each scenario through the processes and check its expectations "
               "(docs/checks.md). Exit status 0 when all hold, 1 when any fails, 2 on bad "
               "input.")


def add_arguments(check: argparse.ArgumentParser) -> None:
    check.add_argument("paths", nargs="*", metavar="PATH",
                       help="scenario files, folders of them, or shipped names (default: "
                            "every shipped scenario)")
    check.add_argument("--out", type=Path, default=None,
                       help="folder for the run folders and check.json (default: a new "
                            "folder under runs/)")
    check.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML here")
    check.add_argument("--summary", type=Path, metavar="FILE",
                       help="append a Markdown summary here (default: $GITHUB_STEP_SUMMARY "
                            "when set)")
    check.add_argument("--baseline", type=Path, metavar="DIR",
                       help="an earlier check's folder (or its check.json): fail on drift")
    check.add_argument("--tolerance", type=number(0.0, 10.0), default=0.05,
                       help="relative change a baseline allows (default 0.05)")
    check.add_argument("-j", "--jobs", type=number(1, 64, integer=True), default=None,
                       help="scenarios in progress at once, 1-64; in lockstep one flies "
                            "per CPU this process may use while the others start or "
                            "report (default: in lockstep two per CPU, in real time 1)")
    check.add_argument("--realtime", action="store_true",
                       help="pace to the wall clock (default: lockstep)")
    add_rt_cpus(check)
    check.add_argument("--cold", action="store_true",
                       help="start every run's processes anew (default: forked by one process "
                            "loader, which loads their imports and compiled code once)")
    check.add_argument("--keep", action="store_true",
                       help="keep the run folders of passed scenarios too")


def default_jobs(realtime: bool, scenarios: int) -> int:
    """Lockstep: two runs in progress per flight (``flights_at_once``: one flight per
    usable CPU), so that while one flies the next starts its processes, and waits, or the
    last writes its report. The paper's seven took 3.4-4.3 s so on 2 CPUs, against
    4.0-5.2 s with two flying and nothing waiting (alternated; docs/checks.md). One CPU, or real
    time: one, so that a run's pacing has the machine to itself."""
    if realtime or len(os.sched_getaffinity(0)) < 2:
        return 1
    return max(1, min(2 * flights_at_once(scenarios), scenarios, 64))


def handle(args: argparse.Namespace) -> int:
    scenarios = collect(args.paths)
    baseline = read_baseline(args.baseline) if args.baseline is not None else None
    out = args.out or fresh_folder("check")
    summary = args.summary or (Path(os.environ["GITHUB_STEP_SUMMARY"])
                               if os.environ.get("GITHUB_STEP_SUMMARY") else None)
    mode = "real time" if args.realtime else "lockstep"
    args.jobs = args.jobs or default_jobs(args.realtime, len(scenarios))
    flying = "" if args.realtime else f", {flights_at_once(args.jobs)} flying"
    print(f"ivfm check: {len(scenarios)} scenario(s), {mode}, {args.jobs} at a time"
          f"{flying}; run folders in {out}", file=sys.stderr)
    start = time.perf_counter()
    results = run_check(scenarios, CheckOptions(out, realtime=args.realtime, jobs=args.jobs,
                                                baseline=baseline, tolerance=args.tolerance,
                                                keep_passed=args.keep, forked=not args.cold,
                                                rt_cpus=args.rt_cpus),
                        Progress(len(scenarios)))
    wall_s = time.perf_counter() - start
    print(results_table(results))
    failed = [r for r in results if not r.passed]
    print(f"{len(results) - len(failed)} of {len(results)} passed in {wall_s:.1f} s"
          + (f"; failed run folders kept in {out}" if failed else ""))
    if args.junit is not None:
        args.junit.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(args.junit, junit_xml(results))
        print(f"wrote {args.junit}")
    if summary is not None:
        with open(summary, "a") as f:
            f.write(markdown_summary(results, wall_s))
        print(f"appended the summary to {summary}")
    return 1 if failed else 0
