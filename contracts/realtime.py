"""What the two vehicle processes need to keep a real-time loop: scheduling priority, and
loop statistics in fixed memory (the same cost per period after an hour as after a second).

Periods and compute times go into histograms of 1 us bins (up to 50 ms, then one
overflow bin) with running counts, sums and maxima; percentiles are read off the
cumulative histogram only when a summary is asked for. Nothing grows with run time.
Percentiles are the upper edge of their bin: at most 1 us above the exact value.
"""

from __future__ import annotations

import collections
import contextlib
import os
import resource
from pathlib import Path

import numpy as np

BIN_S = 1e-6
BINS = 50_000  # 50 ms of 1 us bins; longer values land in the overflow bin


class ProcessUsage:
    """What a process has cost the machine since it was made: CPU seconds (user and
    system, every thread) and context switches (voluntary: it waited; involuntary: it
    was preempted), for a run's final status and the benchmarks' cycle budget."""

    def __init__(self) -> None:
        self.restart()

    def restart(self) -> None:
        """Count from now (a loop's first step: start-up is not the loop's cost)."""
        self._start = resource.getrusage(resource.RUSAGE_SELF)

    def since_start(self) -> dict[str, float | int]:
        now, start = resource.getrusage(resource.RUSAGE_SELF), self._start
        return {"cpu_s": round(now.ru_utime + now.ru_stime - start.ru_utime - start.ru_stime, 6),
                "user_s": round(now.ru_utime - start.ru_utime, 6),
                "voluntary_switches": now.ru_nvcsw - start.ru_nvcsw,
                "involuntary_switches": now.ru_nivcsw - start.ru_nivcsw}


class Histogram:
    """Counts of non-negative durations in 1 us bins, with count, sum and maximum."""

    def __init__(self) -> None:
        self.counts = np.zeros(BINS + 1, dtype=np.int64)
        self.n = 0
        self.total_s = 0.0
        self.max_s = 0.0

    def add(self, value_s: float) -> None:
        index = int(value_s / BIN_S)
        self.counts[index if index < BINS else BINS] += 1
        self.n += 1
        self.total_s += value_s
        if value_s > self.max_s:
            self.max_s = value_s

    def percentile(self, q: float) -> float:
        """The q-th percentile (0-100) [s]: the upper edge of the bin it falls in, or the
        maximum if that is smaller (and for values past the last bin)."""
        if self.n == 0:
            return float("nan")
        rank = max(1, int(np.ceil(q / 100.0 * self.n)))
        index = int(np.searchsorted(np.cumsum(self.counts), rank))
        if index >= BINS:
            return self.max_s
        return min((index + 1) * BIN_S, self.max_s)


class LoopTiming:
    """Jitter (|period - nominal|), compute time and deadline misses of a periodic loop."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.jitter = Histogram()
        self.compute = Histogram()
        self.period_total_s = 0.0
        self.misses = 0
        # The last few misses (step index, how late [s]): where to look, in fixed memory.
        self.recent_misses: collections.deque[tuple[int, float]] = collections.deque(maxlen=8)
        # Simulator stalls: control instants with no sample for over two periods (the last
        # command held); episodes, steps held and the longest episode's sample gap.
        self.stalls = 0
        self.stall_steps = 0
        self.longest_stall_s = 0.0
        # Control instants whose newest sample the last step had flown (the last command
        # held): after a late step, or a sample a little late.
        self.same_sample = 0

    def record_same_sample(self) -> None:
        """One control instant with no sample since the last step."""
        self.same_sample += 1

    def record_stall(self, new_episode: bool, gap_s: float) -> None:
        """One control instant without a fresh sample; ``gap_s`` since the last one."""
        self.stalls += new_episode
        self.stall_steps += 1
        self.longest_stall_s = max(self.longest_stall_s, gap_s)

    def record_miss(self, periods: int, late_s: float) -> None:
        self.misses += periods
        self.recent_misses.append((self.compute.n, late_s))

    def record_period(self, period_s: float) -> None:
        self.period_total_s += period_s
        self.jitter.add(abs(period_s - self.period_s))

    def record_compute(self, compute_s: float) -> None:
        self.compute.add(compute_s)

    def summary(self) -> dict[str, float | int]:
        """Statistics so far, in milliseconds (computed now: call it when asked, not per
        period)."""
        stalls = {"sim_stalls": self.stalls, "sim_stall_steps": self.stall_steps,
                  "sim_stall_longest_ms": self.longest_stall_s * 1e3,
                  "same_sample_held": self.same_sample}
        if self.jitter.n < 1:
            return {"steps": self.compute.n, "deadline_misses": self.misses, **stalls}
        j, c = self.jitter, self.compute
        return {
            "steps": c.n,
            "nominal_period_ms": self.period_s * 1e3,
            "period_mean_ms": self.period_total_s / j.n * 1e3,
            "jitter_p50_ms": j.percentile(50) * 1e3,
            "jitter_p99_ms": j.percentile(99) * 1e3,
            "jitter_max_ms": j.max_s * 1e3,
            "compute_p50_ms": c.percentile(50) * 1e3,
            "compute_p99_ms": c.percentile(99) * 1e3,
            "compute_max_ms": c.max_s * 1e3,
            "deadline_misses": self.misses,
            "recent_misses": [{"step": step, "late_ms": round(late * 1e3, 3)}
                              for step, late in self.recent_misses],
            **stalls,
        }


def set_realtime_priority(priority: int) -> str:
    """Ask for SCHED_FIFO at ``priority`` (1-99) for the calling thread, as PX4 does for its
    tasks on Linux; 0 leaves the scheduler alone. Returns what was done, for the log: a
    process without the right (CAP_SYS_NICE) keeps the normal scheduler and says so."""
    if priority <= 0:
        return "normal scheduling (real-time priority not asked for)"
    if not 1 <= priority <= 99:
        raise ValueError(f"real-time priority must be in [1, 99] (0: off), got {priority}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        return f"normal scheduling: SCHED_FIFO {priority} refused ({exc})"
    return f"SCHED_FIFO priority {priority}"


def _cpus_text(cpus: frozenset[int] | set[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus))


def pin_this_thread(cpu: int) -> str:
    """Lockstep: the calling thread (the loop) on ``cpu`` only; the process's other
    threads (Zenoh's) stay where they were. The simulator and the autopilot alternate, so
    with both loops on one CPU a hand-over is a switch on that CPU instead of waking a
    sleeping thread on another (docs/mavlink.md, "The cycle budget")."""
    try:
        os.sched_setaffinity(0, {cpu})  # 0: the calling thread
    except OSError as exc:
        return f"loop on any CPU: CPU {cpu} refused ({exc})"
    return f"loop on CPU {cpu}"


def any_cpu() -> None:
    """Every thread of this process back on every CPU, once its loop is done: a caller
    that goes on (a test running the loop in process) is placed as before."""
    with contextlib.suppress(OSError):
        pin_to_cpus(frozenset(range(os.cpu_count() or 1)))


def keep_off_cpu(cpu: int) -> str:
    """Lockstep: every thread of this process (Zenoh's, those to come inherit it) on every
    CPU but ``cpu``, the two loops' (a loop then pins itself there: ``pin_this_thread``),
    so nothing else of the run wakes up on the hand-over's CPU."""
    others = frozenset(range(os.cpu_count() or 1)) - {cpu}
    if not others:
        return "one CPU: nothing kept off it"
    try:
        pin_to_cpus(others)
    except OSError as exc:
        return f"threads on any CPU: {exc}"
    return f"threads kept off CPU {cpu}"


def pin_to_cpus(cpus: frozenset[int]) -> str:
    """Keep every thread of this process on ``cpus`` (threads started later, such as
    Zenoh's, inherit it). With ``shield_cpus`` the real-time loops get CPUs nothing else
    runs on: on a virtual machine whose every CPU is busy, the host takes milliseconds at
    a time from its CPUs whatever the guest's priorities (docs/realtime.md)."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            os.sched_setaffinity(int(tid), cpus)
    return f"pinned to CPU {_cpus_text(cpus)}"


_PF_KTHREAD = 0x00200000  # /proc/PID/stat flags: a kernel thread


def _user_threads() -> list[int]:
    """Thread ids of every user-space process on the machine, kernel threads left out."""
    tids = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            flags = int(stat[stat.rindex(")") + 2:].split()[6])
            if flags & _PF_KTHREAD:
                continue
            tids += [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        except (OSError, ValueError):
            continue  # gone, or not ours to read
    return tids


def shield_cpus(reserved: frozenset[int] | None) -> tuple[int, int]:
    """Move every user-space thread on the machine off the ``reserved`` CPUs, so that the
    real-time processes pinned there (``--rt-cpus``) have them to themselves, as
    ``cset shield`` does; what those threads start later inherits it. Threads already
    confined to reserved CPUs (pinned on purpose) are left there. ``None`` lifts the
    shield: every thread may use every CPU again. Returns (threads moved, refused)."""
    every = frozenset(range(os.cpu_count() or 1))
    if reserved is not None and not every - reserved:
        raise ValueError(f"reserving CPU {_cpus_text(reserved)} would leave no CPU for "
                         "the rest of the machine")
    moved = refused = 0
    for tid in _user_threads():
        try:
            now = frozenset(os.sched_getaffinity(tid))
            if reserved is None:
                new = every
            elif now <= reserved:
                continue
            else:
                new = now - reserved
            if new != now:
                os.sched_setaffinity(tid, new)
                moved += 1
        except ProcessLookupError:
            continue
        except OSError:
            refused += 1
    return moved, refused
