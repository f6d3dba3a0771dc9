"""The lockstep path through the processes beside the in-process path, measured in the same
run (the machine's speed moves up to 3x between days: the ratio is the figure).

    python tests/benchmarks/bench_lockstep.py             # 3 rounds of 60 s attitude-sine
    python tests/benchmarks/bench_lockstep.py --rounds 5 --duration 30
    python tests/benchmarks/bench_lockstep.py --before /path/to/older/checkout

``--before``: each round flies this checkout, then the older one (its own processes,
from a Python that imports it), so that every pair shares the machine's minutes: this
machine's speed swings by 2x within an hour, and only pairs tell a change from it.

Each round flies the scenario in process, then through the logger, simulator and
autopilot (lockstep, every record logged). The processes' loop is the autopilot's
first to last control step (timeline.json); CPU and context switches come from each
process's final status (getrusage: every thread of the process). Prints figures;
asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# The checkout flown: this one, or (IVFM_BENCH_ROOT, set by --before) an older one.
ROOT = Path(os.environ.get("IVFM_BENCH_ROOT") or Path(__file__).resolve().parents[2])
sys.path.insert(0, str(ROOT))

from autopilot.control.factory import load_models  # noqa: E402
from contracts.airframe import PAPER  # noqa: E402
from ground.run.inprocess import run_inprocess  # noqa: E402
from ground.run.processes import RunSettings, run_processes  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402

PROCESSES = ("sitl", "autopilot", "logger")


def _thread_counters() -> dict[tuple[str, str], tuple[int, ...]]:
    """(process, thread name) -> (voluntary switches, involuntary switches, ns on a CPU,
    ns waiting for one) of this process's children's threads (the last two from
    /proc's schedstat; a process's threads of one name summed)."""
    out: dict[tuple[str, str], tuple[int, ...]] = {}
    me = os.getpid()
    children = Path(f"/proc/{me}/task/{me}/children").read_text().split()
    for pid in children:
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            name = ("logger" if b"log" in cmdline else cmdline[2].decode()
                    if len(cmdline) > 2 else "?")
            for task in Path(f"/proc/{pid}/task").iterdir():
                status = dict(line.split(":\t", 1) for line in
                              (task / "status").read_text().splitlines() if ":\t" in line)
                on_cpu_ns, waiting_ns, _ = (task / "schedstat").read_text().split()
                key = (name, status["Name"].strip())
                counts = (int(status["voluntary_ctxt_switches"]),
                          int(status["nonvoluntary_ctxt_switches"]), int(on_cpu_ns),
                          int(waiting_ns))
                out[key] = tuple(a + b for a, b in zip(out.get(key, (0,) * 4), counts,
                                                       strict=True))
        except (OSError, KeyError, IndexError, ValueError):
            continue  # a process or thread that has just ended
    return out


class SwitchWindow:
    """Context switches and CPU per thread over a window of the flight (from 1.5 s to
    3.5 s after the start, inside the loop of a 30-60 s flight at up to ~50x)."""

    def __init__(self) -> None:
        self.before: dict = {}
        self.after: dict = {}
        self.thread = threading.Thread(target=self._sample, daemon=True)
        self.thread.start()

    def _sample(self) -> None:
        time.sleep(1.5)
        self.before, t0 = _thread_counters(), time.monotonic()
        time.sleep(2.0)
        self.after, self.window_s = _thread_counters(), time.monotonic() - t0

    def per_cycle(self, rtf: float) -> list[tuple]:
        """(process, thread, voluntary and involuntary switches, us on a CPU, us waiting
        for one) per cycle, of the threads that switched or ran at all."""
        self.thread.join()
        cycles = self.window_s * rtf * 100
        rows = []
        for key, after in self.after.items():
            before = self.before.get(key, after)
            v, n, on_ns, wait_ns = (a - b for a, b in zip(after, before, strict=True))
            if v + n > 0.05 * cycles or on_ns > 1000 * cycles:
                rows.append((*key, v / cycles, n / cycles, on_ns / cycles / 1e3,
                             wait_ns / cycles / 1e3))
        return sorted(rows)


def round_trip(scenario, settings: RunSettings, models) -> dict:
    """One in-process flight and one through the processes: their figures."""
    inprocess = run_inprocess(scenario, "ivfc", "paper", PAPER, models)
    with tempfile.TemporaryDirectory() as tmp:
        window = SwitchWindow()
        accounting = run_processes(scenario, settings, Path(tmp), quiet=True)
        timeline = json.loads((Path(tmp) / "timeline.json").read_text())
    steps = round(scenario.duration_s * settings.rate_hz)
    rtf = timeline["loop_real_time_factor"]
    return {"inprocess_rtf": scenario.duration_s / inprocess.wall_time_s,
            "processes_rtf": rtf, "threads": window.per_cycle(rtf),
            "usage": accounting["usage"], "steps": steps,
            "lost": sum(accounting["lost"].values())}


def round_before(checkout: Path, duration_s: float) -> dict:
    """One round of the older checkout, flown by a Python that imports it."""
    env = {**os.environ, "IVFM_BENCH_ROOT": str(checkout), "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, __file__, "--rounds", "1", "--duration",
                           str(duration_s), "--json"], env=env, cwd=checkout,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--duration", type=float, default=60.0, help="sim seconds")
    parser.add_argument("--before", type=Path, metavar="CHECKOUT",
                        help="an older checkout, flown after this one in every round")
    parser.add_argument("--json", action="store_true", help="one round's figures as JSON")
    args = parser.parse_args()
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"),
                                   duration_s=args.duration)
    settings = RunSettings("ivfc", "paper", "paper")
    models = load_models(None)
    if args.json:
        print(json.dumps(round_trip(scenario, settings, models)))
        return
    if args.before is not None:
        round_before(args.before, 2.0)  # its numba cache loaded (or compiled) first
        round_trip(dataclasses.replace(scenario, duration_s=2.0), settings, models)
        pairs = []
        for k in range(args.rounds):
            new, old = round_trip(scenario, settings, models), round_before(args.before,
                                                                          args.duration)
            pairs.append(new["processes_rtf"] / old["processes_rtf"])
            cpu = " / ".join(
                f"{1e6 * old['usage'][n]['cpu_s'] / old['steps']:.0f} -> "
                f"{1e6 * new['usage'][n]['cpu_s'] / new['steps']:.0f}"
                for n in PROCESSES if n in old["usage"] and n in new["usage"])
            print(f"round {k + 1}: before {old['processes_rtf']:.1f}x (in process "
                  f"{old['inprocess_rtf']:.0f}x), now {new['processes_rtf']:.1f}x (in process "
                  f"{new['inprocess_rtf']:.0f}x): {pairs[-1]:.2f}x; CPU per cycle "
                  f"{'/'.join(PROCESSES)} {cpu} us", flush=True)
        print(f"now against before, median of {len(pairs)} pairs: "
              f"{statistics.median(pairs):.2f}x the lockstep speed")
        return
    rows = []
    for k in range(args.rounds):
        row = round_trip(scenario, settings, models)
        rows.append(row)
        print(f"round {k + 1}: in process {row['inprocess_rtf']:.1f}x, processes "
              f"{row['processes_rtf']:.1f}x real time "
              f"({100 * row['processes_rtf'] / row['inprocess_rtf']:.0f} %); "
              f"records lost {row['lost']}", flush=True)
    ratio = [r["processes_rtf"] / r["inprocess_rtf"] for r in rows]
    best = rows[ratio.index(statistics.median(ratio))] if len(rows) % 2 else rows[0]
    print(f"lockstep attitude-sine, {args.duration:g} s sim, logger on: median "
          f"{100 * statistics.median(ratio):.0f} % of the in-process real-time factor "
          f"(processes {statistics.median(r['processes_rtf'] for r in rows):.1f}x, in "
          f"process {statistics.median(r['inprocess_rtf'] for r in rows):.1f}x)")
    print("per process, the median round's run (CPU: every thread; switches per 10 ms "
          "cycle):")
    for name in PROCESSES:
        u = best["usage"].get(name)
        if not u:
            continue
        print(f"  {name:9s} CPU {1e3 * u['cpu_s'] / args.duration:6.1f} ms per sim second "
              f"({1e6 * u['cpu_s'] / best['steps']:5.0f} us per cycle, user "
              f"{1e6 * u['user_s'] / best['steps']:5.0f}); switches per cycle "
              f"{u['voluntary_switches'] / best['steps']:.2f} voluntary, "
              f"{u['involuntary_switches'] / best['steps']:.2f} involuntary")
    print("per thread over 2 s of the median round's loop, per cycle: switches (voluntary, "
          "involuntary), us on a CPU, us runnable waiting for one (threads with more than "
          "0.05 switches or 1 us):")
    for process, thread, voluntary, involuntary, on_us, waiting_us in best["threads"]:
        print(f"  {process:9s} {thread:16s} {voluntary:5.2f} {involuntary:5.2f} "
              f"{on_us:6.1f} {waiting_us:6.1f}")


if __name__ == "__main__":
    main()
