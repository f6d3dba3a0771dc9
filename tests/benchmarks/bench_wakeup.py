"""What a busy machine costs a real-time thread's wake-ups, without any of our code.

A SCHED_FIFO thread (priority 50, as the autopilot's loop) sleeps to a 4 ms grid for
--seconds and measures how late each wake-up is, beside CPU-bound neighbours
(``while True: pass``) in several layouts: none; one; as many as there are CPUs; the same
niced to 19; under SCHED_IDLE; and with the sleeper's CPU kept for it (the neighbours on
the other CPUs, as ``ivfm shield`` arranges). It also counts the CPUs' steal time
(/proc/stat: time the host ran something else while a guest CPU wanted to run).

    python tests/benchmarks/bench_wakeup.py --seconds 30

Prints one row per layout; asserts nothing. Needs CAP_SYS_NICE for SCHED_FIFO.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

PERIOD_S = 0.004
BUSY = "while True: pass"


def steal_ticks() -> int:
    with open("/proc/stat") as f:
        return int(f.readline().split()[8])


def sleeper(seconds: float, cpu: int | None) -> tuple[list[float], int]:
    """Lateness of each wake-up [s] and the steal ticks over the run."""
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    steal = steal_ticks()
    late, due = [], time.perf_counter() + PERIOD_S
    end = due + seconds
    while due < end:
        wait = due - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        late.append(time.perf_counter() - due)
        due += PERIOD_S
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.sched_setaffinity(0, range(os.cpu_count() or 1))
    return late, steal_ticks() - steal


def neighbours(count: int, prefix: list[str], cpus: set[int] | None) -> list[subprocess.Popen]:
    procs = [subprocess.Popen([*prefix, sys.executable, "-c", BUSY]) for _ in range(count)]
    if cpus is not None:
        for proc in procs:
            os.sched_setaffinity(proc.pid, cpus)
    return procs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    n = os.cpu_count() or 1
    others = set(range(1, n))
    layouts = [("alone", 0, [], None, None),
               ("1 neighbour", 1, [], None, None),
               (f"{n} neighbours", n, [], None, None),
               (f"{n} neighbours, nice 19", n, ["nice", "-n", "19"], None, None),
               (f"{n} neighbours, SCHED_IDLE", n, ["chrt", "-i", "0"], None, None),
               (f"{n} neighbours on CPU {sorted(others)}, sleeper alone on CPU 0", n, [],
                others, 0)]
    print(f"{'layout':52s} {'p99 ms':>7s} {'max ms':>7s} {'>1 ms':>6s} {'>4 ms':>6s} "
          f"{'steal ticks':>11s}")
    for name, count, prefix, cpus, sleeper_cpu in layouts:
        if cpus is not None and not cpus:
            continue  # one CPU: nothing to keep
        procs = neighbours(count, prefix, cpus)
        try:
            time.sleep(0.5)
            late, steal = sleeper(args.seconds, sleeper_cpu)
        finally:
            for proc in procs:
                proc.kill()
                proc.wait()
        late.sort()
        print(f"{name:52s} {late[int(0.99 * len(late))] * 1e3:7.3f} {late[-1] * 1e3:7.2f} "
              f"{sum(x > 1e-3 for x in late):6d} {sum(x > 4e-3 for x in late):6d} {steal:11d}",
              flush=True)


if __name__ == "__main__":
    main()
