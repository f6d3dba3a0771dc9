"""A run's timeline: the marks every process of ``ivfm run`` left (``contracts/timeline.py``)
gathered into ``timeline.json`` in the run folder, with the durations of the phases.

Start-up and teardown are everything but the loop; the loop is the autopilot's first
control step to its last, so its real-time factor is the lockstep speed after warm-up.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from contracts import timeline
from ground.record.run_files import METRICS_FILE, write_json

GROUND = "ground"
RAW_FILE = ".timeline.jsonl"  # the marks as the processes append them
TIMELINE_FILE = "timeline.json"
COMMAND_START = (GROUND, "command start")
LOOP = (("autopilot", "first control step"), ("autopilot", "last control step"))
REPORT_DONE = (GROUND, "report done")
# (name, from mark, to mark): the phases of a run, in order.
PHASES = (
    ("command start-up", COMMAND_START, (GROUND, "run start")),
    ("processes start-up", (GROUND, "run start"), (GROUND, "ready to fly")),
    ("waiting to fly", (GROUND, "ready to fly"), ("sitl", "released")),
    ("released to first step", ("sitl", "released"), LOOP[0]),
    ("loop", *LOOP),
    ("teardown", LOOP[1], (GROUND, "run end")),
    ("report", (GROUND, "run end"), REPORT_DONE),
    ("total", COMMAND_START, REPORT_DONE),
)


def raw_path(run_dir: Path) -> Path:
    return Path(run_dir) / RAW_FILE


def mark(run_dir: Path, event: str, t_s: float | None = None) -> None:
    """A mark of the ground station itself."""
    timeline.mark(GROUND, event, t_s, raw_path(run_dir))


def read_marks(run_dir: Path) -> list[dict[str, Any]]:
    """The raw marks, in time order (a torn last line is left out)."""
    marks = []
    try:
        lines = raw_path(run_dir).read_text().splitlines()
    except FileNotFoundError:
        return []
    for line in lines:
        try:
            marks.append(json.loads(line))
        except ValueError:
            continue
    return sorted(marks, key=lambda m: m["t"])


def summarize(marks: list[dict[str, Any]], sim_loop_s: float) -> dict[str, Any]:
    """Events relative to the command start (each with the time since its process's
    previous mark), phase durations, and the loop's real-time factor for ``sim_loop_s``
    of sim time between the first and the last control step."""
    first = {(m["process"], m["event"]): m["t"] for m in reversed(marks)}
    origin = first.get(COMMAND_START, marks[0]["t"] if marks else 0.0)
    events, previous = [], {}
    for m in marks:
        event = {"t_s": round(m["t"] - origin, 6), "process": m["process"], "event": m["event"]}
        if m["process"] in previous:
            event["after_previous_s"] = round(m["t"] - previous[m["process"]], 6)
        previous[m["process"]] = m["t"]
        events.append(event)
    phases = {name: round(first[end] - first[start], 6) for name, start, end in PHASES
              if start in first and end in first}
    # The origin on time.monotonic (one clock for every process of the machine): lines up
    # the runs of one command, such as a check's flights one after the other.
    out: dict[str, Any] = {"origin_monotonic_s": origin, "events": events, "phases_s": phases}
    if "loop" in phases:
        out["loop_real_time_factor"] = (sim_loop_s / phases["loop"] if phases["loop"] > 0
                                        else math.inf)
        if "total" in phases:
            phases["outside the loop"] = round(phases["total"] - phases["loop"], 6)
    return out


def write(run_dir: Path, sim_loop_s: float) -> dict[str, Any]:
    """timeline.json from the raw marks; returns it."""
    summary = {"sim_loop_s": sim_loop_s, **summarize(read_marks(run_dir), sim_loop_s)}
    write_json(Path(run_dir) / TIMELINE_FILE, summary)
    return summary


def figures(run_dir: Path) -> dict[str, float]:
    """The timeline's figures for metrics.json: the loop's real-time factor and, once the
    report is done, the whole command's wall time ({} without a timeline)."""
    try:
        summary = json.loads((Path(run_dir) / TIMELINE_FILE).read_text())
    except (FileNotFoundError, ValueError):
        return {}
    phases = summary.get("phases_s", {})
    out = {}
    if "loop_real_time_factor" in summary:
        out["loop_real_time_factor"] = summary["loop_real_time_factor"]
        out["loop_wall_time_s"] = phases["loop"]
    if "total" in phases:
        out["command_wall_time_s"] = phases["total"]
    return out


def finish(run_dir: Path, metrics: dict[str, Any]) -> dict[str, Any]:
    """At the end of ``ivfm run``: mark the report done, write the final timeline.json
    and put its figures into metrics.json; returns the metrics."""
    run_dir = Path(run_dir)
    mark(run_dir, REPORT_DONE[1])
    previous = json.loads((run_dir / TIMELINE_FILE).read_text())
    write(run_dir, previous["sim_loop_s"])
    raw_path(run_dir).unlink(missing_ok=True)
    metrics = {**metrics, **figures(run_dir)}
    write_json(run_dir / METRICS_FILE, metrics)
    return metrics
