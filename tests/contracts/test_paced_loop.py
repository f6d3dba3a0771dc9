"""The paced loop both processes share: deadlines, waiting for them, late periods."""

from __future__ import annotations

import signal
import time

import pytest

from contracts.paced_loop import Deadlines, PacedProcess


class Clock:
    """A clock only the test moves: each reading costs a microsecond (a spin ends), a
    sleep or a poll takes what it asks plus ``oversleep_s`` (a late wake-up)."""

    def __init__(self, now_s: float = 100.0, oversleep_s: float = 0.0) -> None:
        self.now_s = now_s
        self.oversleep_s = oversleep_s
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        self.now_s += 1e-6
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now_s += seconds + self.oversleep_s

    def poll(self, timeout_s: float) -> None:
        """Waiting for I/O that does not come."""
        self.now_s += timeout_s + self.oversleep_s


def deadlines(clock: Clock, first_in_s: float, period_s: float = 0.01) -> Deadlines:
    return Deadlines(period_s, clock.now_s + first_in_s, clock, clock.sleep)


@pytest.mark.parametrize("oversleep_s, slept", [(0.0, [0.0002]), (0.0002, [])])
def test_precise_wait_polls_in_whole_milliseconds_sleeps_then_spins_to_the_deadline(
        oversleep_s, slept):
    """5.7 ms ahead: one poll of 5 ms (whole ms, ending before the last 0.5 ms), then a
    sleep of what is left above the last 0.5 ms (none if the poll woke late), then a spin
    that ends on the deadline."""
    clock = Clock(oversleep_s=oversleep_s)
    pace = deadlines(clock, 0.0057)
    polls: list[float] = []
    while not pace.wait(lambda timeout_s: (polls.append(timeout_s), clock.poll(timeout_s))):
        pass
    assert polls == [pytest.approx(0.005)]
    assert clock.sleeps == [pytest.approx(s, abs=1e-5) for s in slept]
    assert pace.next_s <= clock.now_s < pace.next_s + 1e-5  # spun to the deadline, not past


def test_without_a_spin_the_wait_polls_then_sleeps_to_the_deadline_itself():
    """--spin-us 0: the poll leaves no stretch to spin, and the sleep ends on the deadline
    (here, a kernel that wakes on time); nothing is busy-waited but the clock's tick."""
    clock = Clock()
    pace = Deadlines(0.01, clock.now_s + 0.0057, clock, clock.sleep, spin_s=0.0)
    polls: list[float] = []
    while not pace.wait(lambda timeout_s: (polls.append(timeout_s), clock.poll(timeout_s))):
        pass
    assert polls == [pytest.approx(0.005)]
    assert clock.sleeps == [pytest.approx(0.0007, abs=1e-5)]
    assert pace.next_s <= clock.now_s < pace.next_s + 1e-5
    assert pace.until_spin_s() == pytest.approx(pace.remaining_s(), abs=1e-5)


def test_a_wait_woken_past_the_deadline_returns_at_once():
    clock = Clock()
    pace = deadlines(clock, -0.003)
    assert pace.wait(lambda timeout_s: pytest.fail("polled past the deadline"))
    assert clock.sleeps == []


def test_late_periods_are_dropped_on_the_grid_and_counted():
    clock = Clock()
    pace = deadlines(clock, -0.025)  # 25 ms late
    first = pace.next_s
    skipped, late = pace.skip_missed()
    assert skipped == 3 and late == pytest.approx(0.025, abs=1e-5)
    assert pace.next_s == pytest.approx(first + 0.03)
    assert pace.skip_missed() == (0, 0.0)


def test_catching_up_re_anchors_only_when_far_behind():
    clock = Clock()
    pace = deadlines(clock, -0.5)
    assert pace.catch_up(pace.next_s, 1.0) == 0.0  # half a second behind: keep the grid
    assert pace.remaining_s() == pytest.approx(-0.5, abs=1e-5)
    behind = pace.catch_up(clock.now_s - 2.0, 1.0)
    assert behind == pytest.approx(2.0, abs=1e-5)
    assert pace.remaining_s() == pytest.approx(0.01, abs=1e-5)


def test_coarse_serve_stops_when_nothing_comes_or_the_deadline_passes():
    clock = Clock()
    pace = deadlines(clock, 0.5)
    calls: list[float] = []
    pace.serve(lambda remaining_s: calls.append(remaining_s) or len(calls) < 3)
    assert len(calls) == 3
    pace = deadlines(clock, -0.001)
    pace.serve(lambda remaining_s: pytest.fail("polled after the deadline"))


def test_sleeping_to_the_deadline_on_the_real_clock_ends_at_or_after_it():
    """The defaults are the wall clock: a sleep to a deadline never ends early."""
    pace = Deadlines(0.01, time.perf_counter() + 0.002)
    pace.sleep()
    assert time.perf_counter() >= pace.next_s


class _Counting(PacedProcess):
    def __init__(self, lockstep: bool) -> None:
        super().__init__(lockstep, 0, lambda text: None)
        self.calls: list[str] = []

    def start_up(self) -> None:
        self.calls.append("start")

    def run_lockstep(self) -> None:
        self.calls.append("lockstep")
        raise KeyboardInterrupt

    def run_realtime(self) -> None:
        self.calls.append("realtime")

    def shut_down(self) -> None:
        self.calls.append("shut down")

    def report(self) -> None:
        self.calls.append("report")


@pytest.mark.parametrize("lockstep", [True, False])
def test_the_shell_runs_its_loop_and_always_shuts_down(lockstep):
    previous = signal.getsignal(signal.SIGTERM)
    try:
        process = _Counting(lockstep)
        assert process.run() == 0
    finally:
        signal.signal(signal.SIGTERM, previous)
    loop = "lockstep" if lockstep else "realtime"
    assert process.calls == ["start", loop, "shut down", "report"]
