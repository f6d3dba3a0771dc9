"""Progress of long work on one live line: sim time, real-time factor, time left.

On a terminal the line is redrawn in place (at most ten times a second); anywhere else
(CI logs, files, pipes) nothing is printed, so logs hold results, not progress. The
first step of a flight loads the numerical core (numba), or compiles it on a fresh
install: until that step is done the line says so, and its time is not counted in the
real-time factor.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

REDRAW_S = 0.1


def is_terminal(stream: Any) -> bool:
    return bool(getattr(stream, "isatty", None)) and stream.isatty()


class ProgressLine:
    """``loading()`` while the numerical core loads, ``update(sim_s)`` as sim time
    advances, ``done()`` at the end (clears the line). ``what`` names the work
    ("attitude-sine", "[3/56] ..."); ``total_s``: the sim time it runs to."""

    def __init__(self, what: str, total_s: float, stream: TextIO | None = None,
                 clock: Any = time.perf_counter) -> None:
        self.what = what
        self.total_s = total_s
        self.stream = stream if stream is not None else sys.stderr
        self.live = is_terminal(self.stream)
        self.clock = clock
        self.started_wall: float | None = None  # wall time at the first sim second
        self.started_sim = 0.0
        self.last_draw = -1.0

    def loading(self, text: str = "loading the compiled numerical core (compiling it on "
                                  "the first run: up to a minute)") -> None:
        self._draw(f"{self.what}: {text}...")

    def update(self, sim_s: float) -> None:
        now = self.clock()
        if self.started_wall is None:
            self.started_wall, self.started_sim = now, sim_s
        if not self.live or now - self.last_draw < REDRAW_S:
            return
        self._draw(self.text(sim_s, now))

    def text(self, sim_s: float, now: float) -> str:
        elapsed = now - (self.started_wall if self.started_wall is not None else now)
        flown = sim_s - self.started_sim
        line = f"{self.what}: {sim_s:6.1f} of {self.total_s:g} s sim"
        if elapsed > 0.2 and flown > 0:
            factor = flown / elapsed
            left = max(self.total_s - sim_s, 0.0) / factor
            line += f", {factor:5.1f}x real time, {left:4.0f} s left"
        return line

    def _draw(self, line: str) -> None:
        if not self.live:
            return
        self.last_draw = self.clock()
        self.stream.write(f"\r\033[K{line}")
        self.stream.flush()

    def done(self) -> None:
        if self.live and self.last_draw >= 0:
            self.stream.write("\r\033[K")
            self.stream.flush()
