"""The machine's own limit, measured beside ours: a reference sleeper.

A real-time run misses deadlines for two kinds of reasons: ours (a step that took too
long, a process that did not get going) and the machine's (a wake-up the kernel or the
host delivered late). The reference sleeper tells them apart. In the same minutes as
the run, it wakes on the autopilot's period, at the autopilot's SCHED_FIFO priority, on
the autopilot's CPUs, does no work, and counts the periods it loses exactly as the
autopilot counts its deadline misses (``contracts.paced_loop.periods_lost``). When the
autopilot misses and the reference loses periods in the same minutes, the machine would
have missed them with no code of ours; when the reference keeps time, the misses are
ours. docs/realtime.md ("The reference sleeper") says how to read the two figures.

What sleeps: ``cyclictest`` (Debian's rt-tests) when it is on PATH, a C program nothing
of ours is in; else the built-in sleeper (``python -m ground.run.reference``), the same
absolute sleeps on CLOCK_MONOTONIC from Python. Either is started as a process of its
own, so nothing in the caller (its threads, its GIL) delays its wake-ups.

Pure, and tested on exact numbers: ``lost_periods``, ``ReferenceTally`` (fixed memory),
``parse_cyclictest``, ``CyclictestClock`` and ``sleep_loop`` (the built-in sleeper's loop
on an injected clock). The shell: ``ReferenceSleeper``, which runs one and hands every wake-up to a
callback, and ``main``, the built-in sleeper's process.
"""

from __future__ import annotations

import argparse
import gc
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO, Any

from contracts.arguments import AUTOPILOT_RT_PRIORITY, cpu_list
from contracts.paced_loop import periods_lost
from contracts.realtime import Histogram, set_realtime_priority

CYCLICTEST = "cyclictest"
BUILT_IN = "built-in"
CHOICES = ("auto", CYCLICTEST, BUILT_IN)  # what to run ("auto": cyclictest when installed)
START_TIMEOUT_S = 10.0  # until the first wake-up is reported
FLUSH_EVERY = 25  # built-in sleeper: wake-ups per write to the pipe (0.1 s at 250 Hz)

# -- pure ---------------------------------------------------------------------------------


def lost_periods(latency_s: float, period_s: float) -> int:
    """Periods lost by a wake-up ``latency_s`` after its deadline, as the autopilot counts
    a step that starts that late: the next deadline is then ``latency_s - period_s``
    behind, and every deadline passed is lost (none while the wake-up is at most one
    period late; floor(latency / period) after that)."""
    return periods_lost(latency_s - period_s, period_s)


class ReferenceTally:
    """Wake-ups of the reference in fixed memory: their latencies (1 us bins), the
    periods lost and the wake-ups that lost any."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.latency = Histogram()
        self.lost = 0
        self.late_wakeups = 0

    def add(self, latency_s: float) -> None:
        latency_s = max(0.0, latency_s)  # a clock never wakes a sleep early; rounding may
        self.latency.add(latency_s)
        lost = lost_periods(latency_s, self.period_s)
        if lost:
            self.lost += lost
            self.late_wakeups += 1

    def summary(self) -> dict[str, float | int]:
        """Counts, and latencies in milliseconds (NaN with no wake-up)."""
        h = self.latency
        return {"wakeups": h.n, "lost_periods": self.lost, "late_wakeups": self.late_wakeups,
                "worst_ms": round(h.max_s * 1e3, 3) if h.n else float("nan"),
                "p99_ms": round(h.percentile(99) * 1e3, 3),
                "p50_ms": round(h.percentile(50) * 1e3, 3)}


def tally(samples: Iterable[tuple[float, float]], period_s: float,
          start_s: float = -float("inf"), end_s: float = float("inf")) -> ReferenceTally:
    """The wake-ups (time [s], latency [s]) from ``start_s`` to ``end_s`` on the same clock
    (time.monotonic): a run's loop, out of the reference's longer stretch."""
    out = ReferenceTally(period_s)
    for t_s, latency_s in samples:
        if start_s <= t_s <= end_s:
            out.add(latency_s)
    return out


_CYCLICTEST_VALUE = re.compile(r"^\s*(\d+):\s*(\d+):\s*(-?\d+)\s*$")
_CYCLICTEST_SUMMARY = re.compile(r"^T:\s*\d+\s+\(\s*\d+\)\s+P:\s*(\d+)\s+I:\s*(\d+)\s+"
                                 r"C:\s*(\d+)\s+Min:\s*(-?\d+)\s+Act:\s*(-?\d+)\s+"
                                 r"Avg:\s*(-?\d+)\s+Max:\s*(-?\d+)")


def parse_cyclictest(line: str) -> tuple[int, float] | None:
    """(wake-up number, latency [s]) in one line of ``cyclictest -v``
    ("thread:cycle:latency_us"), None for any other line (its header, its summary,
    warnings). cyclictest truncates to whole microseconds, so a wake-up under 1 us past a
    whole period counts as on time."""
    match = _CYCLICTEST_VALUE.match(line)
    return None if match is None else (int(match.group(2)), int(match.group(3)) * 1e-6)


class CyclictestClock:
    """When each of cyclictest's wake-ups was due, on time.monotonic. It prints them from a
    thread of normal priority every 10 ms, so on a busy machine they arrive late, in
    bursts; their own numbers place them on the grid instead. The n-th wake-up is due
    on the grid's deadline n plus the deadlines skipped before it (each wake-up more than
    a period late skips the ones it passed, as ``lost_periods`` counts); the grid's origin
    is the earliest any wake-up could have been (its arrival less its place on the grid
    and its latency), so one prompt arrival fixes it."""

    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self.origin_s = float("inf")
        self.skipped = 0
        self.last_index = -1  # the grid deadline of the last wake-up read

    def behind(self, now_s: float) -> float:
        """How many deadlines have passed since the last wake-up read (inf before any)."""
        return (now_s - self.origin_s) / self.interval_s - self.last_index

    def deadline(self, cycle: int, latency_s: float, arrival_s: float) -> float:
        """The deadline [s] of wake-up ``cycle`` (0 first), given in order."""
        self.last_index = cycle + self.skipped
        on_grid_s = self.last_index * self.interval_s
        self.origin_s = min(self.origin_s, arrival_s - on_grid_s - max(0.0, latency_s))
        self.skipped += lost_periods(latency_s, self.interval_s)
        return self.origin_s + on_grid_s


def parse_cyclictest_summary(line: str) -> dict[str, int] | None:
    """cyclictest's last line with ``-q`` ("T: 0 (pid) P:50 I:4000 C: ... Max: ..."): its
    priority, interval [us], wake-ups and latencies [us]; None for any other line."""
    match = _CYCLICTEST_SUMMARY.match(line.strip())
    if match is None:
        return None
    keys = ("priority", "interval_us", "cycles", "min_us", "act_us", "avg_us", "max_us")
    return dict(zip(keys, map(int, match.groups()), strict=True))


def cyclictest_command(period_s: float, priority: int) -> list[str]:
    """One measuring thread on the period (whole microseconds) at ``priority`` (0: the
    normal scheduler), printing each wake-up's latency as it comes (``-v -u``) and a
    summary at the end (``-q``). ``--default-system``: cyclictest must not tune the
    machine it measures (by default it holds /dev/cpu_dma_latency at 0, keeping every
    CPU out of its idle states for as long as it runs)."""
    argv = [CYCLICTEST, "-t", "1", "-d", "0", "-i", str(round(period_s * 1e6)),
            "--default-system", "-q", "-v", "-u"]
    if priority > 0:
        argv[1:1] = ["-p", str(priority)]
    return argv


def sleep_loop(period_s: float, emit: Callable[[float, float], None],
               running: Callable[[], bool], clock: Callable[[], float] = time.monotonic,
               pause: Callable[[float], None] = time.sleep) -> None:
    """Sleep to each deadline of a ``period_s`` grid and ``emit(deadline_s, latency_s)``;
    a late wake-up drops the deadlines already passed and stays on the grid, as
    cyclictest and the autopilot do. ``time.sleep`` is an absolute clock_nanosleep on
    CLOCK_MONOTONIC (Python 3.11 on), as cyclictest's."""
    next_s = clock() + period_s
    while running():
        wait_s = next_s - clock()
        if wait_s > 0:
            pause(wait_s)
        now = clock()
        emit(next_s, now - next_s)
        next_s += period_s
        next_s += periods_lost(now - next_s, period_s) * period_s


def cpus_text(cpus: frozenset[int] | None) -> str:
    return "any CPU" if cpus is None else "CPU " + ",".join(map(str, sorted(cpus)))


# -- the shell ----------------------------------------------------------------------------


class ReferenceSleeper:
    """The reference as a process beside a run: ``start`` (returns once it has woken up),
    every wake-up to ``on_sample(t_s, latency_s)`` (t_s on time.monotonic), ``stop``.
    ``prefer``: "auto" (cyclictest when on PATH, else the built-in sleeper), "cyclictest"
    (that or an error) or "built-in". ``source``, ``scheduling`` and ``note`` say what ran,
    at which priority, and why not cyclictest."""

    def __init__(self, period_s: float, on_sample: Callable[[float, float], None],
                 priority: int = AUTOPILOT_RT_PRIORITY, cpus: frozenset[int] | None = None,
                 prefer: str = "auto") -> None:
        if prefer not in CHOICES:
            raise ValueError(f"reference must be one of {', '.join(CHOICES)}, got {prefer!r}")
        self.period_s = period_s
        self.on_sample = on_sample
        self.priority = priority
        self.cpus = cpus
        self.prefer = prefer
        self.source = ""
        self.scheduling = ""
        self.note = ""  # why the built-in sleeper ran (cyclictest not installed, refused)
        self.summary_line: dict[str, int] | None = None  # cyclictest's own, at the end
        self.proc: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        self._err: IO[bytes] | None = None
        self._woke = threading.Event()
        self._clock = CyclictestClock(round(period_s * 1e6) * 1e-6)  # its whole microseconds

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def describe(self) -> str:
        """One line for a report: what slept, how and where."""
        interval = f"every {self.period_s * 1e3:g} ms"
        note = f"; {self.note}" if self.note else ""
        return f"{self.source}, {self.scheduling}, {cpus_text(self.cpus)}, {interval}{note}"

    def start(self, timeout_s: float = START_TIMEOUT_S) -> None:
        """Run cyclictest or the built-in sleeper until its first wake-up is reported;
        RuntimeError when neither runs."""
        if self.prefer != BUILT_IN:
            if shutil.which(CYCLICTEST) is None:
                if self.prefer == CYCLICTEST:
                    raise RuntimeError("cyclictest is not installed (Debian: apt-get "
                                       "install rt-tests)")
                self.note = "cyclictest not installed"
            else:
                why = self._run(cyclictest_command(self.period_s, self.priority),
                                CYCLICTEST, timeout_s)
                if why is None:
                    self.scheduling = (f"SCHED_FIFO priority {self.priority}"
                                       if self.priority > 0 else "normal scheduling")
                    return
                if self.prefer == CYCLICTEST:
                    raise RuntimeError(f"cyclictest did not run: {why}")
                self.note = f"cyclictest did not run ({why})"
        command = [sys.executable, "-m", "ground.run.reference", "--period-s",
                   repr(self.period_s), "--priority", str(self.priority)]
        # This very module, whether this process found it installed or on its sys.path.
        root = str(Path(__file__).resolve().parents[2])
        path = os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))
        why = self._run(command, BUILT_IN, timeout_s, {**os.environ, "PYTHONPATH": path})
        if why is not None:
            raise RuntimeError(f"the built-in reference sleeper did not run: {why}")

    def _run(self, argv: list[str], source: str, timeout_s: float,
             env: dict[str, str] | None = None) -> str | None:
        """Start ``argv`` and wait for its first wake-up; None when it came, else why not
        (the process is gone then)."""
        self.source = source
        self._woke.clear()
        self._clock = CyclictestClock(self._clock.interval_s)
        self._err = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop or here)
        cpus = self.cpus
        # The affinity of the whole process before it runs, so that every thread of it
        # (cyclictest's measuring thread) inherits it, as the autopilot's do (--rt-cpus).
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=self._err, stdin=subprocess.DEVNULL,
            text=True, bufsize=1, start_new_session=True, env=env,
            preexec_fn=None if cpus is None else lambda: os.sched_setaffinity(0, cpus))
        self._reader = threading.Thread(target=self._read, args=(self.proc.stdout, source),
                                        name=f"reference-{source}", daemon=True)
        self._reader.start()
        end = time.monotonic() + timeout_s
        while not self._woke.wait(0.02):
            if self.proc.poll() is not None or time.monotonic() > end:
                why = self._stderr_tail() or (f"exit status {self.proc.returncode}"
                                              if self.proc.returncode is not None else
                                              f"no wake-up in {timeout_s:g} s")
                self._end()
                return why
        return None

    def _read(self, stream: IO[str], source: str) -> None:
        for line in stream:
            if source == CYCLICTEST:
                sample = parse_cyclictest(line)
                if sample is None:
                    self.summary_line = parse_cyclictest_summary(line) or self.summary_line
                    continue
                cycle, latency_s = sample
                t_s = self._clock.deadline(cycle, latency_s, time.monotonic())
            else:
                if line.startswith("#"):
                    self.scheduling = line[1:].strip()
                    continue
                deadline, latency_us = line.split()
                t_s, latency_s = float(deadline), float(latency_us) * 1e-6
            self._woke.set()
            self.on_sample(t_s, latency_s)

    def _stderr_tail(self) -> str:
        if self._err is None:
            return ""
        self._err.seek(0)
        lines = [ln.strip() for ln in self._err.read().decode(errors="replace").splitlines()
                 if ln.strip() and "cpu_dma_latency" not in ln]
        return lines[-1] if lines else ""

    def stop(self, timeout_s: float = 5.0) -> None:
        """End it and read what it printed. cyclictest prints its wake-ups late on a busy
        machine and drops those not yet printed when it ends: first wait (up to
        ``timeout_s``) for those due by now. SIGTERM then makes it print its summary."""
        if self.source == CYCLICTEST and self.proc is not None:
            end_s = time.monotonic() + timeout_s
            now_s = time.monotonic()
            while (self._clock.behind(now_s) > 2.0 and self.proc.poll() is None
                   and time.monotonic() < end_s):
                time.sleep(0.005)
        self._end(timeout_s)

    def _end(self, timeout_s: float = 5.0) -> None:
        proc = self.proc
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            if self._reader is not None:
                self._reader.join(timeout_s)
            if proc.stdout is not None:
                proc.stdout.close()
        if self._err is not None:
            self._err.close()
            self._err = None
        self.proc = None

    def __enter__(self) -> ReferenceSleeper:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()


def summary(sleeper: ReferenceSleeper, counted: ReferenceTally) -> dict[str, Any]:
    """What a report shows of the reference: what ran, and its counts."""
    return {"source": sleeper.source, "scheduling": sleeper.scheduling,
            "cpus": cpus_text(sleeper.cpus), "period_ms": sleeper.period_s * 1e3,
            "note": sleeper.note, **counted.summary()}


# -- the built-in sleeper's process ---------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    """``python -m ground.run.reference --period-s S --priority P``: sleep on the grid
    until SIGTERM, one line per wake-up on stdout ("deadline_s latency_us"), after a first
    line "# <scheduling>"."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--period-s", type=float, required=True)
    parser.add_argument("--priority", type=int, default=AUTOPILOT_RT_PRIORITY)
    parser.add_argument("--cpus", type=cpu_list, help="pin to these CPUs (default: as "
                        "started)")
    args = parser.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    if args.cpus is not None:
        os.sched_setaffinity(0, args.cpus)
    out = sys.stdout
    out.write(f"# {set_realtime_priority(args.priority)}\n")
    out.flush()
    gc.disable()  # the loop makes no cycles: nothing for the collector, no pause from it
    count = 0

    def emit(deadline_s: float, latency_s: float) -> None:
        nonlocal count
        out.write(f"{deadline_s:.6f} {latency_s * 1e6:.1f}\n")
        count += 1
        if count % FLUSH_EVERY == 1:  # the first at once: the caller waits for it
            out.flush()

    try:
        sleep_loop(args.period_s, emit, lambda: not stop.is_set())
        out.flush()
    except BrokenPipeError:  # the reader is gone: so is the point
        # Python flushes stdout again at exit: point it where that cannot fail.
        os.dup2(os.open(os.devnull, os.O_WRONLY), out.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
