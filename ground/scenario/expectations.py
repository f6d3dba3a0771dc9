"""Expectations: what must hold after a scenario flies (the ``[expect]`` table of a
scenario file), and their verdict on a run's metrics.

Every expectation becomes one ``Outcome``: its name, whether it held, the measured value
and the limit, and a message that says both. docs/checks.md describes the format. An
``[expect]`` table is checked when the scenario file is read, so a bad limit is refused
before anything flies.

    [expect]
    no_failsafe = true
    axes = { x = { rmse_max = 0.05, max_abs_max = 0.2 } }
    [expect.estimation]            # flying on the estimator
    position_rmse_m_max = 0.5
    [expect.path]                  # missions
    all_reached = true
    cross_track_max_m_max = 1.0
    [expect.timing]                # real-time runs
    deadline_misses_max = 0
    [[expect.event]]
    kind = "failsafe"
    mode = "HOLD"
    at_s = 12.0
    within_s = 1.5
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from contracts.modes import FlightMode
from contracts.toml_tables import array_of_tables, check_fields, number, subtable

AXIS_LIMITS = ("rmse_max", "max_abs_max")
# Section -> the metrics a limit may name ("<metric>_max" or "<metric>_min").
SECTION_METRICS: dict[str, tuple[str, ...]] = {
    "estimation": ("attitude_rmse_rad", "roll_rmse_rad", "pitch_rmse_rad", "yaw_rmse_rad",
                   "position_rmse_m", "altitude_rmse_m", "velocity_rmse_mps",
                   "euler_rate_rmse_rad_s"),
    "path": ("cross_track_rmse_m", "cross_track_max_m"),
    "timing": ("deadline_misses", "jitter_p50_ms", "jitter_p99_ms", "jitter_max_ms",
               "compute_p50_ms", "compute_p99_ms", "compute_max_ms", "sim_stalls",
               "sim_stall_steps", "sim_stall_longest_ms"),
    "control": ("effort_mean_sum_c2", "chattering_per_s", "saturated_fraction",
                "tilt_rate_rms_rad_s"),
}
# What ground/record/events.py reads from a log.
EVENT_KINDS = ("mode", "armed", "disarmed", "failsafe", "landed", "statustext")
_EVENT_KEYS = {"kind", "mode", "text", "at_s", "within_s", "after_s", "before_s", "by_s",
               "absent"}
_TOP = {"no_failsafe", "axes", "event", *SECTION_METRICS}


COMPLETED = "run completed without diverging"


@dataclass(frozen=True)
class Limit:
    """``section.metric`` (or ``axes.<axis>.<metric>``) must be at most / at least
    ``value``."""

    path: tuple[str, ...]
    bound: str  # "max" or "min"
    value: float

    @property
    def name(self) -> str:
        if self.path == ("path", "all_reached"):
            return "path: every item reached"
        return ".".join(self.path) + f" {'<=' if self.bound == 'max' else '>='} {self.value:g}"


@dataclass(frozen=True)
class EventExpectation:
    """An event of ``kind`` (with the mode or text, if given) in [after_s, before_s] of
    sim time; ``absent``: no such event in that window."""

    kind: str
    after_s: float = 0.0
    before_s: float = math.inf
    mode: str = ""
    text: str = ""
    absent: bool = False

    @property
    def name(self) -> str:
        what = self.kind + (f" {self.mode}" if self.mode else "") + \
            (f" {self.text!r}" if self.text else "")
        window = (f"by t = {self.before_s:g} s" if self.after_s == 0.0 else
                  f"after t = {self.after_s:g} s" if math.isinf(self.before_s) else
                  f"in [{self.after_s:g}, {self.before_s:g}] s")
        if self.after_s == 0.0 and math.isinf(self.before_s):
            window = "at any time"
        return f"{'no ' if self.absent else ''}event {what} {window}"

    def matches(self, event: dict[str, Any]) -> bool:
        return (event["kind"] == self.kind and
                (not self.mode or event.get("mode") == self.mode) and
                (not self.text or self.text.lower() in event.get("text", "").lower()))


@dataclass(frozen=True)
class Expectations:
    limits: tuple[Limit, ...] = ()
    events: tuple[EventExpectation, ...] = ()
    no_failsafe: bool = False
    sections: frozenset[str] = field(default_factory=frozenset)

    @property
    def needs_events(self) -> bool:
        """Events are read from the processes' log: an in-process run has none."""
        return bool(self.events) or self.no_failsafe

    def names(self) -> list[str]:
        """The outcomes' names, in ``evaluate``'s order (known before anything flies)."""
        return [COMPLETED, *(limit.name for limit in self.limits),
                *(["no failsafe"] if self.no_failsafe else []),
                *(e.name for e in self.events)]


@dataclass(frozen=True)
class Outcome:
    """The verdict on one expectation."""

    name: str
    passed: bool
    measured: Any
    limit: Any
    message: str


def parse_expectations(data: Any, axes: tuple[str, ...], duration_s: float) -> Expectations:
    """The ``[expect]`` table, checked; ValueError says which field is wrong."""
    if data is None:
        return Expectations()
    if not isinstance(data, dict):
        raise ValueError("[expect] must be a table")
    check_fields(data, _TOP, "expect")
    limits: list[Limit] = []
    for axis, table in subtable(data, "axes", "expect.axes").items():
        where = f"expect.axes.{axis}"
        if axis not in axes:
            raise ValueError(f"{where}: the scenario is judged on {', '.join(axes)} only")
        if not isinstance(table, dict) or not table:
            raise ValueError(f"{where} must be a table of {' and/or '.join(AXIS_LIMITS)}")
        for key, value in table.items():
            if key not in AXIS_LIMITS:
                raise ValueError(f"{where}: unknown limit {key!r}; known: "
                                 f"{', '.join(AXIS_LIMITS)}")
            limits.append(Limit(("axes", axis, key.removesuffix("_max")), "max",
                                number(value, f"{where}.{key}")))
    sections = set()
    for section, known in SECTION_METRICS.items():
        table = subtable(data, section, f"expect.{section}")
        if table:
            sections.add(section)
        for key, value in table.items():
            where = f"expect.{section}.{key}"
            if section == "path" and key == "all_reached":
                if not isinstance(value, bool):
                    raise ValueError(f"{where} must be true or false")
                if value:
                    limits.append(Limit(("path", "all_reached"), "min", 1.0))
                continue
            metric, _, bound = key.rpartition("_")
            if bound not in ("max", "min") or metric not in known:
                raise ValueError(
                    f"{where}: unknown limit; known: "
                    f"{', '.join(f'{m}_max' for m in known)}"
                    + (", all_reached" if section == "path" else "") + " (or _min)")
            limits.append(Limit((section, metric), bound, number(value, where)))
    no_failsafe = data.get("no_failsafe", False)
    if not isinstance(no_failsafe, bool):
        raise ValueError("expect.no_failsafe must be true or false")
    events = tuple(_event(e, where, duration_s)
                   for where, e in array_of_tables(data, "event", "expect.event", _EVENT_KEYS))
    return Expectations(tuple(limits), events, no_failsafe, frozenset(sections))


def _event(data: dict[str, Any], where: str, duration_s: float) -> EventExpectation:
    kind = data.get("kind")
    if kind not in EVENT_KINDS:
        raise ValueError(f"{where}: kind must be one of {', '.join(EVENT_KINDS)}, got {kind!r}")
    mode = data.get("mode", "")
    modes = [m.name for m in FlightMode]
    if mode and mode not in modes:
        raise ValueError(f"{where}: mode must be one of {', '.join(modes)}, got {mode!r}")
    if mode and kind in ("statustext",):
        raise ValueError(f"{where}: a statustext event has a text, not a mode")
    text = data.get("text", "")
    if not isinstance(text, str) or (text and kind != "statustext"):
        raise ValueError(f"{where}: text (a string) is for statustext events")
    if kind == "statustext" and not text:
        raise ValueError(f"{where}: a statustext event needs the text to look for")
    times = {k: number(data[k], f"{where}.{k}", low=0.0)
             for k in ("at_s", "within_s", "after_s", "before_s", "by_s") if k in data}
    if "at_s" in times or "within_s" in times:
        if set(times) != {"at_s", "within_s"}:
            raise ValueError(f"{where}: at_s goes with within_s, and with no other time")
        after, before = times["at_s"], times["at_s"] + times["within_s"]
    elif "by_s" in times:
        if set(times) - {"by_s", "after_s"}:
            raise ValueError(f"{where}: by_s and before_s say the same thing; give one")
        after, before = times.get("after_s", 0.0), times["by_s"]
    else:
        after, before = times.get("after_s", 0.0), times.get("before_s", math.inf)
    if after > before:
        raise ValueError(f"{where}: the window ends ({before:g} s) before it starts "
                         f"({after:g} s)")
    if after > duration_s:
        raise ValueError(f"{where}: the window starts at {after:g} s, after the run ends "
                         f"({duration_s:g} s)")
    absent = data.get("absent", False)
    if not isinstance(absent, bool):
        raise ValueError(f"{where}.absent must be true or false")
    return EventExpectation(kind, after, before, mode, text, absent)


# -- verdicts -------------------------------------------------------------------------------

def evaluate(expectations: Expectations, metrics: dict[str, Any]) -> list[Outcome]:
    """One outcome per expectation, and first one for the run itself (not diverged)."""
    diverged = bool(metrics.get("diverged"))
    outcomes = [Outcome(COMPLETED, not diverged, diverged, False,
                        "the run diverged or lost control records" if diverged else
                        "the run completed")]
    for limit in expectations.limits:
        outcomes.append(_limit_outcome(limit, metrics))
    events = metrics.get("events")
    if expectations.needs_events and events is None:
        missing = "this run has no event record (an in-process run): events need the processes"
        if expectations.no_failsafe:
            outcomes.append(Outcome("no failsafe", False, None, 0, missing))
        outcomes += [Outcome(e.name, False, None, None, missing) for e in expectations.events]
        return outcomes
    if expectations.no_failsafe:
        failsafes = [e for e in events if e["kind"] == "failsafe"]
        first = (f"; first at t = {failsafes[0]['t_s']:.2f} s in {failsafes[0].get('mode')}"
                 if failsafes else "")
        outcomes.append(Outcome("no failsafe", not failsafes, len(failsafes), 0,
                                f"{len(failsafes)} failsafe(s), expected 0{first}"))
    for expected in expectations.events:
        outcomes.append(_event_outcome(expected, events))
    return outcomes


def _lookup(metrics: dict[str, Any], path: tuple[str, ...]) -> Any:
    value: Any = metrics
    for part in path:
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def _limit_outcome(limit: Limit, metrics: dict[str, Any]) -> Outcome:
    measured = _lookup(metrics, limit.path)
    name = limit.name
    if limit.path == ("path", "all_reached"):
        reached = bool(measured)
        arrivals = _lookup(metrics, ("path", "arrival_s")) or []
        missed = [i for i, a in zip(_lookup(metrics, ("path", "items")) or [], arrivals,
                                    strict=False) if a is None]
        return Outcome(limit.name, reached, measured, True,
                       "every item reached" if reached else
                       f"mission items not reached: {missed or 'no path metrics'}")
    if isinstance(measured, bool) or not isinstance(measured, (int, float)) or \
            not math.isfinite(measured):
        section = limit.path[0]
        why = {"estimation": "the run did not fly on the estimator",
               "path": "the run flew no mission (or it reached too few items)",
               "timing": "timing is measured in real-time runs only"}.get(section, "")
        return Outcome(name, False, measured, limit.value,
                       f"{'.'.join(limit.path)} was not measured"
                       + (f" ({why})" if measured is None and why else
                          f" ({measured!r})" if measured is not None else ""))
    passed = measured <= limit.value if limit.bound == "max" else measured >= limit.value
    relation = ("<=" if passed else ">") if limit.bound == "max" else (">=" if passed else "<")
    return Outcome(name, passed, measured, limit.value,
                   f"{'.'.join(limit.path)} = {measured:.6g} {relation} limit {limit.value:g}")


def _event_outcome(expected: EventExpectation, events: list[dict[str, Any]]) -> Outcome:
    in_window = [e for e in events if expected.matches(e)
                 and expected.after_s <= e["t_s"] <= expected.before_s]
    if expected.absent:
        first = in_window[0] if in_window else None
        return Outcome(expected.name, first is None, None if first is None else first["t_s"],
                       None, "none happened" if first is None else
                       f"happened at t = {first['t_s']:.3f} s")
    if in_window:
        return Outcome(expected.name, True, in_window[0]["t_s"], expected.before_s,
                       f"at t = {in_window[0]['t_s']:.3f} s")
    elsewhere = [e for e in events if expected.matches(e)]
    times = ", ".join(f"{e['t_s']:.3f}" for e in elsewhere[:3])
    said = (f"it happened at t = {times} s, outside the window" if elsewhere
            else "it did not happen")
    kinds = [e for e in events if e["kind"] == expected.kind][:3]
    seen = "" if elsewhere or not kinds else \
        "; seen instead: " + ", ".join(f"{e.get('mode') or e.get('text')} at "
                                        f"{e['t_s']:.2f} s" for e in kinds)
    return Outcome(expected.name, False, elsewhere[0]["t_s"] if elsewhere else None,
                   expected.before_s, f"expected {expected.name}: {said}{seen}")
