"""What a real-time period costs each process against a lockstep one, for the same flight.

    python tests/benchmarks/bench_realtime_cost.py              # 30 s of attitude-sine
    python tests/benchmarks/bench_realtime_cost.py --duration 60
    python tests/benchmarks/bench_realtime_cost.py --rate-hz 1000 --spin-us 0

The scenario (on the rigid body) flies twice through fresh processes, in lockstep and
in real time. While they run, /proc is read every 0.2 s for each child of this process:
its CPU (user and system, every thread) and its main thread's context switches. The
figures: each process's CPU per real-time period in flight (from 5 s after the simulator
started to 2 s before the end: start-up and shut-down left out), and the last reading
before it exits per period, start-up included, in both modes. Prints figures; asserts
nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from ground.run.processes import RunSettings, run_processes  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402

NAMES = {"ground.cli": "logger", "sitl": "simulator", "autopilot": "autopilot"}


def _reading(pid: str) -> tuple[str, float, int, int] | None:
    """(process, CPU s, voluntary, involuntary switches) of a child of ours, else None."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        if int(fields[1]) != os.getpid():
            return None
        with open(f"/proc/{pid}/cmdline") as f:
            argv = f.read().split("\0")
        with open(f"/proc/{pid}/status") as f:
            status = dict(line.split(":\t", 1) for line in f.read().splitlines()
                          if ":\t" in line)
    except (OSError, ValueError, IndexError):
        return None
    name = next((NAMES[a] for a in argv[1:4] if a in NAMES), "?")
    cpu_s = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return (name, cpu_s, int(status["voluntary_ctxt_switches"]),
            int(status["nonvoluntary_ctxt_switches"]))


def fly(realtime: bool, duration_s: float, rate_hz: float = 100.0,
        spin_us: float | None = None, window_s: tuple[float, float] | None = None
        ) -> tuple[dict[str, tuple[float, int, int]], dict[str, float]]:
    """The flight's last readings per process (CPU s, voluntary, involuntary switches),
    and each process's CPU seconds within ``window_s`` (from, to; seconds after the
    simulator's first reading) when given."""
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=duration_s)
    settings = RunSettings("ivfc", "rigid-body", scenario.airframe.argument,
                           realtime=realtime, rate_hz=rate_hz, spin_us=spin_us)
    last: dict[str, tuple[str, float, int, int]] = {}
    series: dict[str, list[tuple[float, float]]] = {}
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            now = time.monotonic()
            for pid in os.listdir("/proc"):
                if pid.isdigit() and (reading := _reading(pid)) is not None:
                    last[pid] = reading
                    series.setdefault(reading[0], []).append((now, reading[1]))
            time.sleep(0.2)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    with tempfile.TemporaryDirectory() as tmp:
        run_processes(scenario, settings, Path(tmp) / "run", quiet=True)
    done.set()
    watcher.join()
    in_window = {}
    if window_s is not None and series.get("simulator"):
        origin = series["simulator"][0][0]
        for name, points in series.items():
            inside = [(t, cpu) for t, cpu in points
                      if window_s[0] <= t - origin <= window_s[1]]
            if len(inside) >= 2:
                (t0, c0), (t1, c1) = inside[0], inside[-1]
                in_window[name] = (c1 - c0) / (t1 - t0)  # CPU seconds per wall second
    return ({name: (cpu_s, vol, invol) for name, cpu_s, vol, invol in last.values()},
            in_window)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="sim seconds")
    parser.add_argument("--rate-hz", type=float, default=100.0, help="both loops' rate")
    parser.add_argument("--spin-us", type=float, default=None,
                        help="the autopilot's busy-wait before each step (default: its own)")
    args = parser.parse_args()
    periods = round(args.duration * args.rate_hz)
    window = (5.0, args.duration - 2.0)  # in flight, start-up and shut-down left out
    lockstep, _ = fly(False, args.duration, args.rate_hz, args.spin_us)
    realtime, flying = fly(True, args.duration, args.rate_hz, args.spin_us, window)
    runs = {"lockstep": lockstep, "real time": realtime}
    print(f"attitude-sine on the rigid body, {args.duration:g} s ({periods} periods at "
          f"{args.rate_hz:g} Hz); CPU-s (start-up included), main thread's voluntary / "
          f"involuntary switches")
    for mode, run in runs.items():
        print(f"  {mode:9s} " + "; ".join(f"{name} {cpu:.2f} s, {vol} / {invol}"
                                          for name, (cpu, vol, invol) in sorted(run.items())))
    for name in sorted(set(lockstep) & set(realtime) - {"?"}):
        lockstep_ms, realtime_ms = (1e3 * runs[mode][name][0] / periods
                                    for mode in ("lockstep", "real time"))
        flying_ms = 1e3 * flying.get(name, math.nan) / args.rate_hz
        print(f"  {name}: in flight {flying_ms:.3f} ms of CPU per real-time period (/proc, "
              f"{window[0]:g}-{window[1]:g} s); start-up included, {realtime_ms:.3f} ms per "
              f"real-time period and {lockstep_ms:.3f} ms per lockstep one")


if __name__ == "__main__":
    main()
