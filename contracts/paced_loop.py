"""The paced loop both vehicle processes run: lockstep or real time, and in real time a
fixed-period schedule of wall-clock deadlines.

What the two loops share, and only that:

* ``PacedProcess``: the shell of a process's run: SIGTERM stops it, the configured
  loop (lockstep or real time, the real-time one under SCHED_FIFO) runs until stopped or
  interrupted, and shutting down happens whatever ended it.
* ``Deadlines``: the deadline in force, serving I/O while waiting for it, and what to
  do when a period overran. The autopilot must start its step *on* the deadline: it
  polls while far from it, sleeps, then spins the last stretch (``wait``), and drops the
  periods it lost (``skip_missed``). The simulator only has to stay in step with the wall
  clock: it reads what arrives until the deadline (``serve``), and catches up after a late
  period instead of dropping it, since each period is a period of sim time; far behind
  (a stall) it re-anchors, as a paused world resumes (``catch_up``).

The lockstep loops share the shell and the way their simulator link waits
(``lockstep_waits``): the autopilot answers samples as they come, the simulator sends
one and waits for its answer.
"""

from __future__ import annotations

import math
import signal
import socket
import struct
import time
from collections.abc import Callable

from contracts import timeline
from contracts.realtime import any_cpu, pin_this_thread, set_realtime_priority


def lockstep_waits(sock: socket.socket, timeout_s: float) -> None:
    """A lockstep link's socket: blocking, each receive and send waiting at most
    ``timeout_s`` (then BlockingIOError), the bound kept by the kernel (SO_RCVTIMEO,
    SO_SNDTIMEO). Why: a Python socket timeout polls before every receive and send, two
    system calls more a cycle on each side of a hand-over that needs one each."""
    sock.settimeout(None)
    whole = int(timeout_s)
    timeval = struct.pack("ll", whole, round((timeout_s - whole) * 1e6))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeval)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, timeval)


SPIN_S = 0.0005  # the last stretch before a precise deadline is busy-waited (default)
MAX_SPIN_S = 0.005
POLL_MIN_S = 0.0015  # below this, sleep (ns resolution) instead of epoll (ms resolution)


class Deadlines:
    """Deadlines every ``period_s`` on ``clock`` (``time.perf_counter``), from ``first_s``
    on; ``pause`` (``time.sleep``) sleeps. Both are injected by tests, so the logic is
    checked on a clock that nothing else on the machine can make late. ``spin_s``: the
    last stretch ``wait`` busy-waits (0: it sleeps to the deadline, as late as the
    kernel wakes it)."""

    def __init__(self, period_s: float, first_s: float,
                 clock: Callable[[], float] = time.perf_counter,
                 pause: Callable[[float], None] = time.sleep, spin_s: float = SPIN_S) -> None:
        self.period_s = period_s
        self.next_s = first_s
        self.clock = clock
        self.pause = pause
        self.spin_s = spin_s

    def remaining_s(self) -> float:
        return self.next_s - self.clock()

    def until_spin_s(self) -> float:
        """Time left for other work before ``wait`` must start spinning."""
        return self.next_s - self.spin_s - self.clock()

    def wait(self, poll: Callable[[float], None]) -> bool:
        """One turn of a precise wait. Far from the deadline: ``poll(timeout_s)`` once for
        I/O and return False (the caller does its housekeeping and calls again); near it:
        sleep, spin to the deadline and return True."""
        remaining = self.next_s - self.clock()
        if remaining > POLL_MIN_S:
            # epoll counts whole milliseconds and rounds up: ask for whole ones, early.
            poll(math.floor((remaining - self.spin_s) * 1000.0) / 1000.0)
            return False
        if remaining > self.spin_s:
            self.pause(remaining - self.spin_s)  # nanosecond sleep; I/O waits in the buffers
        while self.clock() < self.next_s:
            pass
        return True

    def serve(self, poll: Callable[[float], bool]) -> None:
        """A coarse wait: ``poll(remaining_s)`` until it reports that nothing came (False)
        or the deadline has passed. epoll may end it up to a millisecond late."""
        while True:
            remaining = self.next_s - self.clock()
            if remaining <= 0 or not poll(remaining):
                return

    def sleep(self) -> None:
        """Nothing to serve: sleep to the deadline."""
        self.pause(max(0.0, self.next_s - self.clock()))

    def advance(self) -> None:
        self.next_s += self.period_s

    def skip_missed(self) -> tuple[int, float]:
        """After the period's work: if the deadline in force has already passed, drop the
        periods lost and re-anchor on the same grid. Returns (periods dropped, how late
        [s]); (0, 0.0) when on time."""
        late = self.clock() - self.next_s
        if late <= 0:
            return 0, 0.0
        skipped = periods_lost(late, self.period_s)
        self.next_s += skipped * self.period_s
        return skipped, late

    def catch_up(self, passed_s: float, limit_s: float) -> float:
        """After ``advance``: a deadline ``passed_s`` that is more than ``limit_s`` behind
        (suspended?) re-anchors the schedule a period from now; less is caught up by
        running the next periods without waiting. Returns how far behind it re-anchored
        [s] (0 when it did not)."""
        now = self.clock()
        if now - passed_s > limit_s:
            self.next_s = now + self.period_s
            return now - passed_s
        return 0.0


def periods_lost(late_s: float, period_s: float) -> int:
    """The periods a loop loses when it is ``late_s`` past the deadline in force (the
    next one) once a period's work is done: every deadline that has passed, the one in
    force included; 0 when not late. The autopilot's deadline misses are counted so
    (``Deadlines.skip_missed``), and so are the reference sleeper's lost periods
    (ground/run/reference.py), so the two figures compare."""
    if late_s <= 0:
        return 0
    return int(late_s // period_s) + 1


class PacedProcess:
    """The run of a vehicle process: the configured loop until stopped. Subclasses give
    ``run_lockstep`` and ``run_realtime``, and may give ``start_up`` (before the loop),
    ``shut_down`` (always, after it) and ``report`` (after shutting down). ``process``
    names it in the run's timeline."""

    process = "process"

    def __init__(self, lockstep: bool, rt_priority: int,
                 log: Callable[[str], None], handover_cpu: int | None = None) -> None:
        self.lockstep = lockstep
        self.rt_priority = rt_priority
        self.log = log
        self.handover_cpu = handover_cpu  # lockstep: the loop's CPU (None: any)
        self._stop = False

    def stop(self, *_args: object) -> None:
        self._stop = True

    def run(self) -> int:
        signal.signal(signal.SIGTERM, self.stop)
        self.start_up()
        timeline.mark(self.process, "loop start")
        try:
            if self.lockstep:
                if self.handover_cpu is not None:
                    self.log(pin_this_thread(self.handover_cpu))
                self.run_lockstep()
            else:
                self.log(set_realtime_priority(self.rt_priority))
                self.run_realtime()
        except KeyboardInterrupt:
            pass
        finally:
            if self.lockstep and self.handover_cpu is not None:
                any_cpu()
            timeline.mark(self.process, "loop end")
            self.shut_down()
            timeline.mark(self.process, "shut down")
        self.report()
        return 0

    def start_up(self) -> None:
        pass

    def run_lockstep(self) -> None:
        raise NotImplementedError

    def run_realtime(self) -> None:
        raise NotImplementedError

    def shut_down(self) -> None:
        pass

    def report(self) -> None:
        pass
