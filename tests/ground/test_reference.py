"""The reference sleeper (ground/run/reference.py): its lost periods counted as the
autopilot counts deadline misses, on synthetic latencies and an injected clock (exact
numbers); cyclictest's output parsed from a capture of the real program; and, in the
process tier, the built-in sleeper and cyclictest themselves counting a stall made with
SIGSTOP."""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from contracts.paced_loop import Deadlines
from ground.run.reference import (
    BUILT_IN,
    CYCLICTEST,
    CyclictestClock,
    ReferenceSleeper,
    ReferenceTally,
    cyclictest_command,
    lost_periods,
    parse_cyclictest,
    parse_cyclictest_summary,
    sleep_loop,
    summary,
    tally,
)

PERIOD_S = 0.004
# `cyclictest -p 50 -t 1 -d 0 -i 4000 --default-system -q -v -u` (rt-tests 2.4, Debian
# bookworm, kernel 6.18 on this 2-CPU VM, pinned to CPU 0 with taskset), stopped with
# SIGSTOP for 50 ms after 1 s and for 10 ms 0.3 s later, ended with SIGTERM after 2 s.
CAPTURE = Path(__file__).parents[1] / "data" / "cyclictest" / "cyclictest-2.4-stalled.txt"


@pytest.mark.parametrize("latency_ms, lost", [
    (0.0, 0), (0.03, 0), (3.999, 0), (4.0, 0),  # up to one period late: the next is kept
    (4.001, 1), (7.999, 1), (8.001, 2), (46.3, 11), (52.138, 13), (100.5, 25)])
def test_a_wake_up_loses_the_deadlines_that_passed_as_the_autopilot_counts(latency_ms, lost):
    """The autopilot's loop, late by the same amount after the step it woke for
    (Deadlines.skip_missed, on an injected clock), drops the same number of periods."""
    latency_s = latency_ms * 1e-3
    assert lost_periods(latency_s, PERIOD_S) == lost
    now = [10.0 + latency_s]  # woke for the deadline at 10 s, this late
    pace = Deadlines(PERIOD_S, 10.0, clock=lambda: now[0])
    pace.advance()  # the step done: the next deadline is in force
    assert pace.skip_missed()[0] == lost


def test_the_tally_counts_lost_periods_late_wake_ups_and_percentiles():
    counted = ReferenceTally(PERIOD_S)
    for _ in range(98):
        counted.add(50e-6)
    counted.add(5e-3)   # one period lost
    counted.add(50e-3)  # twelve
    assert counted.summary() == {"wakeups": 100, "lost_periods": 13, "late_wakeups": 2,
                                 "worst_ms": 50.0, "p99_ms": 5.001, "p50_ms": 0.051}
    empty = ReferenceTally(PERIOD_S).summary()
    assert empty["wakeups"] == 0 and empty["lost_periods"] == 0
    assert math.isnan(empty["worst_ms"]) and math.isnan(empty["p99_ms"])


def test_a_window_keeps_only_the_wake_ups_inside_it():
    samples = [(1.0, 9e-3), (2.0, 1e-4), (3.0, 13e-3), (4.0, 50e-3)]
    inside = tally(samples, PERIOD_S, 1.5, 3.0).summary()
    assert (inside["wakeups"], inside["lost_periods"], inside["worst_ms"]) == (2, 3, 13.0)
    assert tally(samples, PERIOD_S).summary()["lost_periods"] == 2 + 3 + 12


class SteppedClock:
    """time.monotonic and time.sleep for the loop: a sleep ends on time, plus the delay
    given for that wake-up (a stall)."""

    def __init__(self, delays_s: dict[int, float]) -> None:
        self.now_s = 100.0
        self.delays_s = delays_s
        self.sleeps = 0

    def clock(self) -> float:
        return self.now_s

    def pause(self, seconds: float) -> None:
        self.now_s += seconds + self.delays_s.get(self.sleeps, 0.0)
        self.sleeps += 1


def test_the_built_in_loop_sleeps_on_the_grid_and_drops_what_a_stall_passed():
    """Wake-up 3 comes 10.5 ms late: it is reported so, the two deadlines it passed are
    dropped, and the next wake-up is on the same 4 ms grid again."""
    stepped = SteppedClock({3: 0.0105})
    woke: list[tuple[float, float]] = []
    sleep_loop(PERIOD_S, lambda d, late: woke.append((d, late)), lambda: len(woke) < 7,
               stepped.clock, stepped.pause)
    deadlines_ms = [round((d - 100.0) * 1e3, 6) for d, _ in woke]
    assert deadlines_ms == [4.0, 8.0, 12.0, 16.0, 28.0, 32.0, 36.0]  # 20 and 24 dropped
    assert [round(late * 1e3, 6) for _, late in woke] == [0, 0, 0, 10.5, 0, 0, 0]
    counted = ReferenceTally(PERIOD_S)
    for _, late in woke:
        counted.add(late)
    assert counted.summary()["lost_periods"] == 2  # the deadlines it dropped


def test_cyclictest_output_captured_here_is_read_line_by_line():
    lines = CAPTURE.read_text().splitlines()
    samples = [v for v in map(parse_cyclictest, lines) if v is not None]
    assert len(samples) == 476  # the header, the summary and nothing else left out
    assert [cycle for cycle, _ in samples] == list(range(476))
    latencies = [latency for _, latency in samples]
    assert [parse_cyclictest(line) for line in lines[:3]] == [None, None, None]
    assert parse_cyclictest("       0:     249:   52138") == (249, pytest.approx(0.052138))
    counted = ReferenceTally(PERIOD_S)
    for latency_s in latencies:
        counted.add(latency_s)
    # 52.138 ms late: 13 deadlines passed; 15.723 ms: 3. Nothing else over 76 us.
    assert counted.summary() == {"wakeups": 476, "lost_periods": 16, "late_wakeups": 2,
                                 "worst_ms": 52.138, "p99_ms": 0.064, "p50_ms": 0.031}
    # Its own summary: the priority and interval asked for, and the same worst wake-up
    # (two wake-ups came after its last print, before SIGTERM ended it).
    assert parse_cyclictest_summary(lines[-1]) == {
        "priority": 50, "interval_us": 4000, "cycles": 478, "min_us": 17, "act_us": 31,
        "avg_us": 172, "max_us": 52138}
    assert parse_cyclictest_summary(lines[3]) is None


def test_cyclictests_wake_ups_are_placed_on_its_grid_however_late_they_are_read():
    """Its lines arrive late and in bursts (a normal-priority thread prints them every
    10 ms); their numbers place them: the grid's origin from the promptest arrival, the
    deadlines a late wake-up passed skipped, as cyclictest skips them."""
    clock = CyclictestClock(0.004)
    # Wake-ups 0-2 read together 30 ms after the first was due (at 100 s): each placed as
    # early as it could have been. Wake-up 3, 0.2 ms late, read 1 us after it woke: the
    # origin is right to that 1 us from then on.
    got = [clock.deadline(0, 50e-6, 100.030), clock.deadline(1, 40e-6, 100.030),
           clock.deadline(2, 60e-6, 100.030), clock.deadline(3, 200e-6, 100.012201)]
    assert got == pytest.approx([100.02995, 100.02996, 100.02994, 100.012001], abs=1e-9)
    assert clock.origin_s == pytest.approx(100.000001, abs=1e-9)
    # Wake-up 4 (due at 100.016) comes 9.5 ms late: the deadlines at 100.020 and 100.024
    # passed, so wake-up 5 is the one due at 100.028.
    assert clock.deadline(4, 9.5e-3, 100.0256) == pytest.approx(100.016001, abs=1e-9)
    assert clock.deadline(5, 30e-6, 100.040) == pytest.approx(100.028001, abs=1e-9)
    assert clock.skipped == 2


def test_cyclictest_is_asked_for_the_autopilots_period_and_priority_untuned():
    argv = cyclictest_command(0.004, 50)
    assert argv[:3] == ["cyclictest", "-p", "50"]
    assert argv[argv.index("-i") + 1] == "4000" and argv[argv.index("-t") + 1] == "1"
    assert "--default-system" in argv  # it must not hold the CPUs out of idle
    assert {"-q", "-v", "-u"} <= set(argv)
    assert "-p" not in cyclictest_command(0.01, 0)  # 0: the normal scheduler, as asked
    assert cyclictest_command(1 / 300, 50)[cyclictest_command(1 / 300, 50).index("-i") + 1] \
        == "3333"


def test_asking_for_cyclictest_where_it_is_not_installed_says_so(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    sleeper = ReferenceSleeper(PERIOD_S, lambda *_: None, prefer=CYCLICTEST)
    with pytest.raises(RuntimeError, match="apt-get install rt-tests"):
        sleeper.start()
    with pytest.raises(ValueError, match="auto, cyclictest, built-in"):
        ReferenceSleeper(PERIOD_S, lambda *_: None, prefer="chrt")


# -- the process tier ---------------------------------------------------------------------

def _run_with_a_stall(prefer: str, stall_s: float = 0.05):
    """The reference on CPU 0 for about 1.5 s, stopped (SIGSTOP) for ``stall_s`` midway;
    its report, the tally of the wake-ups due between its start and its stop, and how
    long that was [s]."""
    samples: list[tuple[float, float]] = []
    sleeper = ReferenceSleeper(PERIOD_S, lambda t_s, late_s: samples.append((t_s, late_s)),
                               cpus=frozenset({0}), prefer=prefer)
    sleeper.start()
    try:
        start_s = time.monotonic()
        time.sleep(0.7)
        os.kill(sleeper.pid, signal.SIGSTOP)
        time.sleep(stall_s)
        os.kill(sleeper.pid, signal.SIGCONT)
        time.sleep(0.7)
        stop_s = time.monotonic()
    finally:
        sleeper.stop()
    return (summary(sleeper, tally(samples, PERIOD_S)),
            tally(samples, PERIOD_S, start_s, stop_s).summary(), stop_s - start_s)


@pytest.mark.process
@pytest.mark.alone  # a stall counted: the machine's own would add to it
@pytest.mark.parametrize("prefer", [BUILT_IN, pytest.param(CYCLICTEST, marks=pytest.mark.skipif(
    shutil.which("cyclictest") is None, reason="cyclictest is not installed (Debian: "
    "apt-get install rt-tests; .ci/run installs it where it may)"))])
def test_a_50_ms_stall_of_the_sleeper_is_counted(prefer):
    """Stopped for at least 50 ms, the sleeper wakes at least 46 ms late (the stall less
    the period it was sleeping into) and loses at least 11 periods: of the 12 or 13
    deadlines a 50 ms stall spans, the one it wakes for is served late and the rest are
    lost, as the autopilot would lose them. Every deadline between its start and its stop
    is a wake-up or a lost period, whatever the load on the machine (to the few periods
    at the ends that the wake-ups' times place either side: cyclictest's are placed from
    its printed numbers)."""
    got, inside, window_s = _run_with_a_stall(prefer)
    assert got["source"] == prefer and got["cpus"] == "CPU 0"
    assert got["scheduling"].startswith(("SCHED_FIFO priority 50", "normal scheduling"))
    assert got["worst_ms"] >= 46.0
    assert got["lost_periods"] >= 11 and got["late_wakeups"] >= 1
    assert got["p50_ms"] < PERIOD_S * 1e3  # most wake-ups on time: a sane sleeper
    due = window_s / PERIOD_S
    assert inside["wakeups"] <= due + 2, (inside, due)
    assert inside["wakeups"] + inside["lost_periods"] >= due - 3, (inside, due)


@pytest.mark.process
def test_without_cyclictest_the_built_in_sleeper_runs_and_says_why(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))  # no cyclictest on it (CI installs from pip)
    woke: list[float] = []
    with ReferenceSleeper(PERIOD_S, lambda _t, late: woke.append(late)) as sleeper:
        time.sleep(0.3)
    assert sleeper.source == BUILT_IN and sleeper.note == "cyclictest not installed"
    assert sleeper.describe().startswith("built-in, ")
    assert len(woke) >= 0.2 / PERIOD_S


@pytest.mark.process
@pytest.mark.skipif(shutil.which("setpriv") is None or os.geteuid() != 0,
                    reason="needs root and setpriv (util-linux) to take CAP_SYS_NICE away")
def test_without_the_right_to_sched_fifo_it_sleeps_at_normal_priority_and_says_so():
    """As the autopilot does without CAP_SYS_NICE: cyclictest refuses to run, and the
    built-in sleeper runs at normal priority, both said."""
    script = ("import time\n"
              "from ground.run.reference import ReferenceSleeper\n"
              "woke = []\n"
              "with ReferenceSleeper(0.004, lambda t, late: woke.append(late)) as s:\n"
              "    time.sleep(0.3)\n"
              "print(s.describe())\nprint(len(woke))\n")
    done = subprocess.run(["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice",
                           sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).parents[2])
    assert done.returncode == 0, done.stderr
    described, woke = done.stdout.splitlines()
    assert described.startswith("built-in, normal scheduling: SCHED_FIFO 50 refused")
    if shutil.which("cyclictest"):
        assert "; cyclictest did not run (" in described
    assert int(woke) >= 0.2 / PERIOD_S
