"""Command-line numbers, checked where they are parsed: every numeric option of ``ivfm``,
``python -m sitl`` and ``python -m autopilot`` takes its type from here, so a value out
of range, NaN, an infinity or a word is refused by argparse with the option's name and
its range ("argument --rate-hz: must be a number in (0, 10000] Hz, got '-5'"), exit
status 2, before anything runs or is written.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from typing import NamedTuple


class NumberRange(NamedTuple):
    """What a ``number`` option accepts, kept on its parser so a test can check that any
    value it took lies inside."""

    low: float
    high: float
    low_open: bool
    integer: bool

    def holds(self, value: float) -> bool:
        inside = (self.low < value if self.low_open else self.low <= value) and value <= self.high
        return inside and (not self.integer or isinstance(value, int))


def number(low: float, high: float, unit: str = "", *, integer: bool = False,
           low_open: bool = False, allow_inf: bool = False) -> Callable[[str], float]:
    """An argparse type: a number in [low, high] (``low_open``: (low, high]); whole with
    ``integer``; ``allow_inf``: "inf" too (when ``high`` is infinite, e.g. a duration)."""
    left = "(" if low_open else "["
    right = "]" if math.isfinite(high) else ")"
    what = "a whole number" if integer else "a number"
    def shown(v: float) -> str:
        return str(int(v)) if integer and math.isfinite(v) else f"{v:g}"

    span = f"{left}{shown(low)}, {shown(high)}{right}{' ' + unit if unit else ''}"

    def parse(text: str) -> float:
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            value = None
        ok = value is not None and (math.isfinite(value) or (allow_inf and value == math.inf))
        ok = ok and (low < value if low_open else low <= value) and value <= high
        if not ok:
            raise argparse.ArgumentTypeError(f"must be {what} in {span}, got {text!r}")
        return value

    parse.__name__ = "number"  # argparse names the type in some messages
    parse.range = NumberRange(low, high, low_open, integer)  # type: ignore[attr-defined]
    return parse


# The ranges every process shares. The control loop and the simulator check theirs again
# (a configuration may come from code); both read them from here.
CONTROL_RATE_RANGE_HZ = (1.0, 1000.0)
SIM_RATE_RANGE_HZ = (1.0, 2000.0)


def _rate(low: float, high: float) -> Callable[[str], float]:
    """A rate in [low, high] Hz whose period is a whole number of microseconds (sim time
    counts microseconds)."""
    in_range = number(low, high, "Hz")

    def parse(text: str) -> float:
        value = in_range(text)
        if abs(1e6 / value - round(1e6 / value)) > 1e-6:
            raise argparse.ArgumentTypeError(f"{text} Hz does not give a whole microsecond "
                                             "period (100, 250, 400, 1000 Hz do)")
        return value

    parse.range = in_range.range  # type: ignore[attr-defined]
    return parse


RATE_HZ = _rate(*CONTROL_RATE_RANGE_HZ)  # the control rate
SIM_RATE_HZ = _rate(*SIM_RATE_RANGE_HZ)
PORT = number(0, 65535, integer=True)
SEED = number(0, 2**32 - 1, integer=True)
VEHICLE_ID = number(1, 255, integer=True)  # a MAVLink system id
RT_PRIORITY = number(0, 99, integer=True)
# The SCHED_FIFO priorities the vehicle processes ask for by default (as PX4 on Linux
# runs its tasks); the reference sleeper runs at the autopilot's (ground/run/reference.py).
AUTOPILOT_RT_PRIORITY = 50
SIMULATOR_RT_PRIORITY = 40
DURATION_S = number(0.0, math.inf, "s", low_open=True, allow_inf=True)
TIMEOUT_S = number(0.0, 3600.0, "s", low_open=True)
ALTITUDE_M = number(0.0, 10_000.0, "m")


def cpu_list(text: str) -> frozenset[int]:
    """CPUs as Linux lists them: "0", "0,2" or "0-1", each one this machine has."""
    cpus: set[int] = set()
    have = os.cpu_count() or 1
    for part in text.split(","):
        low, _, high = part.strip().partition("-")
        try:
            first, last = int(low), int(high or low)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a CPU list (examples: 0, 0,2, 0-1)") from None
        if not 0 <= first <= last < have:
            raise argparse.ArgumentTypeError(
                f"CPU {part.strip()!r} is not on this machine (CPUs 0-{have - 1})")
        cpus.update(range(first, last + 1))
    return frozenset(cpus)


def cpu_number(text: str) -> int:
    """argparse type: one CPU of this machine."""
    cpus = cpu_list(text)
    if len(cpus) != 1:
        raise argparse.ArgumentTypeError(f"expected one CPU, got {text!r}")
    return next(iter(cpus))


def add_vehicle_process_arguments(parser: argparse.ArgumentParser) -> None:
    """The options the simulator and the autopilot share beyond Zenoh's."""
    parser.add_argument("--perturbations", action="store_true",
                        help="take perturbation requests over Zenoh (scenario runs pass it); "
                             "without it they are refused, so that nobody blows wind at or "
                             "kicks a vehicle that did not ask for it")
    parser.add_argument("--rt-cpus", type=cpu_list, metavar="LIST",
                        help="keep the process on these CPUs (0, 0-1, 0,2): with 'ivfm "
                             "shield' on the same list, CPUs nothing else runs on "
                             "(docs/realtime.md)")
    parser.add_argument("--handover-cpu", type=cpu_number, metavar="CPU",
                        help="lockstep: run the loop on this CPU (its Zenoh threads stay "
                             "free); give the simulator and the autopilot the same one and "
                             "each hand-over between them stays on it (scenario runs do: "
                             "docs/mavlink.md)")


def address(text: str) -> tuple[str, int] | None:
    """HOST:PORT (HOST default 127.0.0.1), or "none"."""
    if text.lower() == "none":
        return None
    host, _, port = text.rpartition(":")
    try:
        number_ = int(port)
    except ValueError:
        number_ = -1
    if not 1 <= number_ <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT (port 1-65535) or none, got "
                                         f"{text!r}")
    return host or "127.0.0.1", number_
