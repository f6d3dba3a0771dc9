"""Real time: a simulator that is late with its samples (a stall), noticed at the control
instants, counted in the loop timing and logged once it is over.

A control instant whose newest sample is older than the stall limit is not flown (the last
command holds); the episode's held steps and longest gap are logged when a sample comes
again. Nor is an instant whose newest sample the last step flew, when the next one was due.
"""

from __future__ import annotations

from collections.abc import Callable

from contracts.realtime import LoopTiming

STALL_PERIODS = 2.0  # no sample for this many periods is a simulator stall
# An instant that finds the sample the last step flew, the next one due, waits this share
# of the simulator's period for it before it holds the command: with the simulator's
# grid in phase with the control instants, the sample due arrives a few microseconds
# after the instant as often as before it (a rehearsal flight held 329 of 1529 instants,
# 12 s of flight taking 15.3 s).
SAME_SAMPLE_WAIT = 0.25


class StallWatch:
    """One stall episode at a time: when it began, the steps it held, its gap so far."""

    def __init__(self, timing: LoopTiming, log: Callable[[str], None]) -> None:
        self.timing = timing
        self.log = log
        self.started: float | None = None  # a stall going on: since (monotonic)
        self.held = 0  # control steps it has held the last command
        self.gap_s = 0.0  # its sample gap so far
        self.stepped_us: int | None = None  # the sample the last control step flew

    def flown(self, sample_us: int, sample_period_us: int, period_us: int) -> bool:
        """Whether the newest sample (``sample_us``) is the one the last step flew though
        the next is due (the simulator at the control rate or faster): a late step took
        the one this instant would have had, or the next is a little late. Flown again,
        the sample moved the setpoints a period on, ahead of the vehicle for good (a
        30 ms stop of the autopilot then sped an orbit up by 15 mm/s). A simulator slower
        than the control rate is flown at every instant, its samples again: the next one
        makes the setpoints' lead up."""
        return sample_us == self.stepped_us and sample_period_us <= period_us

    def flown_already(self, sample_us: int, sample_period_us: int, period_us: int) -> bool:
        """``flown``, after the wait for the sample due: the instant holds the last
        command, counted."""
        if not self.flown(sample_us, sample_period_us, period_us):
            return False
        self.timing.record_same_sample()
        return True

    def stalled(self, now: float, last_sample_s: float, period_s: float,
                sample_period_s: float) -> bool:
        """Whether the control instant ``now`` (monotonic) is in a stall: the newest sample,
        from ``last_sample_s``, is over STALL_PERIODS periods old (of the control or of the
        simulator, whichever is longer)."""
        gap_s = now - last_sample_s
        if gap_s <= STALL_PERIODS * max(period_s, sample_period_s):
            if self.started is not None:
                self.log(f"simulator late: no sample for at least "
                         f"{1e3 * self.gap_s:.0f} ms; {self.held} control "
                         f"step(s) held the last command")
                self.started, self.held = None, 0
            return False
        self.timing.record_stall(self.started is None, gap_s)
        if self.started is None:
            self.started = now
        self.held += 1
        self.gap_s = gap_s
        return True
