"""Marks of a run's phases on one clock, for every process of the run (docs/scenarios.md).

When ``IVFM_TIMELINE`` names a file, ``mark`` appends one JSON line to it,
``{"process": ..., "event": ..., "t": time.monotonic()}``. CLOCK_MONOTONIC is one clock
for the whole machine on Linux, so the marks of the ground station, the logger, the
simulator and the autopilot line up. Marks say where start-up and teardown time goes;
they are never read by the control path. Without the variable a mark costs one lookup.

This module imports only the standard library, so a process can mark its start before
its heavy imports.
"""

from __future__ import annotations

import json
import os
import time

ENV = "IVFM_TIMELINE"


def mark(process: str, event: str, t_s: float | None = None,
         path: str | os.PathLike[str] | None = None) -> None:
    """Append the mark (now, or at ``t_s`` on time.monotonic) to the timeline file of
    ``path`` or of the environment; nothing when there is none."""
    target = path if path is not None else os.environ.get(ENV)
    if not target:
        return
    line = json.dumps({"process": process, "event": event,
                       "t": time.monotonic() if t_s is None else t_s}) + "\n"
    # One write on an O_APPEND file: lines of several processes never interleave.
    fd = os.open(target, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line.encode())
    finally:
        os.close(fd)


def process_start_s() -> float:
    """When this process started, on time.monotonic (from /proc/self/stat, 10 ms steps):
    the interpreter's own start-up, before any line of ours ran, counts too."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        started_since_boot_s = int(fields[19]) / os.sysconf("SC_CLK_TCK")
        since_start_s = time.clock_gettime(time.CLOCK_BOOTTIME) - started_since_boot_s
    except (OSError, ValueError, IndexError):
        return time.monotonic()
    return time.monotonic() - since_start_s
