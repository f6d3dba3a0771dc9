"""The paced loop both processes share: deadlines, waiting for them, late periods."""

from __future__ import annotations

import signal
import time

import pytest

from contracts.paced_loop import Deadlines, PacedProcess


def test_precise_wait_polls_in_whole_milliseconds_then_ends_on_the_deadline():
    pace = Deadlines(0.01, time.perf_counter() + 0.0057)
    timeouts: list[float] = []
    while not pace.wait(lambda timeout_s: (timeouts.append(timeout_s), time.sleep(timeout_s))):
        pass
    assert time.perf_counter() >= pace.next_s
    assert timeouts and all(round(t * 1000) == pytest.approx(t * 1000) for t in timeouts)
    assert pace.remaining_s() > -0.005  # ended on the deadline, not long after (loaded CI)


def test_late_periods_are_dropped_on_the_grid_and_counted():
    pace = Deadlines(0.01, time.perf_counter() - 0.025)  # 25 ms late
    first = pace.next_s
    skipped, late = pace.skip_missed()
    assert skipped == 3 and late == pytest.approx(0.025, abs=0.005)
    assert pace.next_s == pytest.approx(first + 0.03)
    assert pace.skip_missed() == (0, 0.0)


def test_catching_up_re_anchors_only_when_far_behind():
    pace = Deadlines(0.01, time.perf_counter() - 0.5)
    pace.catch_up(pace.next_s, 1.0)  # half a second behind: catch up, keep the schedule
    assert pace.remaining_s() < -0.4
    passed = time.perf_counter() - 2.0
    pace.catch_up(passed, 1.0)
    assert pace.remaining_s() == pytest.approx(0.01, abs=0.005)


def test_coarse_serve_stops_when_nothing_comes_or_the_deadline_passes():
    pace = Deadlines(0.01, time.perf_counter() + 0.5)
    calls: list[float] = []
    pace.serve(lambda remaining_s: calls.append(remaining_s) or len(calls) < 3)
    assert len(calls) == 3
    pace = Deadlines(0.01, time.perf_counter() - 0.001)
    pace.serve(lambda remaining_s: pytest.fail("polled after the deadline"))


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
