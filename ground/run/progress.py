"""Progress of long work on one live line: the one mechanism every long command draws
its progress with (``LiveLine``), and the flight's line (sim time, real-time factor,
time left: ``ProgressLine``).

On a terminal the line is redrawn in place (at most ten times a second); anywhere else
(CI logs, files, pipes) only what is logged as a result is printed, so logs hold
results, not progress. The
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


class LiveLine:
    """A line redrawn in place on a terminal (``draw``, at most every ``REDRAW_S`` unless
    forced) and lines that stay (``log``: on a terminal above the live line, elsewhere
    the only output)."""

    def __init__(self, stream: TextIO | None = None, clock: Any = time.perf_counter) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.live = is_terminal(self.stream)
        self.clock = clock
        self.last_draw = -1.0
        self.shown = False

    def draw(self, line: str, force: bool = True) -> None:
        if not self.live:
            return
        now = self.clock()
        if not force and now - self.last_draw < REDRAW_S:
            return
        self.last_draw = now
        self.shown = True
        self.stream.write(f"\r\033[K{line}")
        self.stream.flush()

    def log(self, line: str) -> None:
        self.stream.write(("\r\033[K" if self.shown else "") + line + "\n")
        self.shown = False
        self.stream.flush()

    def clear(self) -> None:
        if self.shown:
            self.stream.write("\r\033[K")
            self.stream.flush()
            self.shown = False


class ProgressLine:
    """``loading()`` while the numerical core loads, ``update(sim_s)`` as sim time
    advances, ``done()`` at the end (clears the line). ``what`` names the work
    ("attitude-sine", "[3/56] ..."); ``total_s``: the sim time it runs to."""

    def __init__(self, what: str, total_s: float, stream: TextIO | None = None,
                 clock: Any = time.perf_counter) -> None:
        self.what = what
        self.total_s = total_s
        self.line = LiveLine(stream, clock)
        self.clock = clock
        self.started_wall: float | None = None  # wall time at the first sim second
        self.started_sim = 0.0

    def loading(self, text: str = "loading the compiled numerical core (compiling it on "
                                  "the first run: up to a minute)") -> None:
        self.line.draw(f"{self.what}: {text}...")

    def update(self, sim_s: float) -> None:
        now = self.clock()
        if self.started_wall is None:
            self.started_wall, self.started_sim = now, sim_s
        if self.line.live:
            self.line.draw(self.text(sim_s, now), force=False)

    def text(self, sim_s: float, now: float) -> str:
        elapsed = now - (self.started_wall if self.started_wall is not None else now)
        flown = sim_s - self.started_sim
        line = f"{self.what}: {sim_s:6.1f} of {self.total_s:g} s sim"
        if elapsed > 0.2 and flown > 0:
            factor = flown / elapsed
            left = max(self.total_s - sim_s, 0.0) / factor
            line += f", {factor:5.1f}x real time, {left:4.0f} s left"
        return line

    def done(self) -> None:
        self.line.clear()
