"""Is this machine's speed steady? A fixed piece of pure-Python work, timed over and over.

    python tests/benchmarks/bench_machine.py              # 12 s, on whatever CPU
    python tests/benchmarks/bench_machine.py --seconds 30 --cpu 1

Why: on the 2-CPU virtual machine this project is measured on, the same code ran 1.5x
slower or faster from one run to the next, and within one run. This times the same work
(a Python loop, in this thread's CPU time, so the machine's other load does not count)
every few milliseconds and prints how its cost moves, with the steal time the kernel
counted meanwhile (/proc/stat). A spread with no steal and nothing else running is the
host slowing the virtual CPU where the guest cannot see it: then only figures taken in
alternated pairs (``bench_lockstep.py --before``) tell a change from the machine.
Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

USER_HZ = os.sysconf("SC_CLK_TCK")


def work(n: int = 200_000) -> int:
    total = 0
    for i in range(n):
        total += i * i
    return total


def steal_s() -> float:
    """The machine's steal time so far (all CPUs), from /proc/stat."""
    with open("/proc/stat") as stat:
        fields = stat.readline().split()
    return int(fields[8]) / USER_HZ if len(fields) > 8 else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--cpu", type=int, help="pin this process to one CPU")
    args = parser.parse_args()
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    work()  # warm
    steal_before, start = steal_s(), time.monotonic()
    costs_ms: list[tuple[float, float]] = []
    while time.monotonic() - start < args.seconds:
        t0 = time.thread_time()
        work()
        costs_ms.append((time.monotonic() - start, 1e3 * (time.thread_time() - t0)))
    stolen_s = steal_s() - steal_before
    values = sorted(c for _, c in costs_ms)
    print(f"{len(values)} runs of the same work over {args.seconds:g} s, thread CPU per run: "
          f"min {values[0]:.2f} ms, median {statistics.median(values):.2f} ms, "
          f"p95 {values[int(0.95 * (len(values) - 1))]:.2f} ms, max {values[-1]:.2f} ms "
          f"(max / min {values[-1] / values[0]:.2f}); steal meanwhile {stolen_s:.2f} s")
    print("per second: median cost [ms]")
    for second in range(int(args.seconds)):
        window = [c for t, c in costs_ms if second <= t < second + 1]
        if window:
            print(f"  {second:3d} s  {statistics.median(window):6.2f}  "
                  + "#" * round(20 * statistics.median(window) / values[-1]))


if __name__ == "__main__":
    main()
