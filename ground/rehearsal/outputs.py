"""What ``ivfm rehearse`` writes and prints: ``rehearsal.json``, ``rehearsal.md``, the
self-contained ``rehearsal.html``, JUnit XML and the terminal's summary, all from one
``Rehearsal`` (ground/rehearsal/rehearse.py). Pure: a rehearsal in, text out."""

from __future__ import annotations

import base64
import html
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from contracts.atomic_file import write_atomic
from ground.check.results import junit_document, junit_suite, markdown_cell
from ground.record.run_files import write_json
from ground.rehearsal.results import Rehearsal
from ground.scenario.expectations import Outcome

PARAMS_FILE = "parameters.params"


def write_outputs(r: Rehearsal, out_dir: Path) -> None:
    write_json(out_dir / "rehearsal.json", rehearsal_json(r))
    write_atomic(out_dir / "rehearsal.md", markdown(r))
    write_atomic(out_dir / "rehearsal.html", html_page(r, out_dir))
    write_atomic(out_dir / "rehearsal.xml", junit(r))


def _outcome_json(o: Outcome) -> dict[str, Any]:
    return {"name": o.name, "passed": bool(o.passed), "measured": _plain(o.measured),
            "limit": _plain(o.limit), "message": o.message}


def _plain(value: Any) -> Any:
    """A JSON value: numpy scalars as Python's, non-finite numbers as null."""
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def rehearsal_json(r: Rehearsal) -> dict[str, Any]:
    return {"verdict": r.verdict, "passed": bool(r.passed), "airframe": r.airframe,
            "profile": r.profile.source,
            "rate_hz": r.rate_hz, "sensors": r.sensors, "model": r.model,
            "parameters_set": r.given,
            "wall_time_s": r.wall_time_s, "not_flown": r.not_flown,
            "static": [_outcome_json(o) for o in r.static],
            "flights": [{"name": f.name, "passed": bool(f.result.passed), "error": f.result.error,
                         "realtime": f.flight.realtime, "wall_time_s": f.result.wall_time_s,
                         "run_dir": str(f.result.run_dir),
                         "outcomes": [_outcome_json(o) for o in f.result.outcomes],
                         **({"deadline_misses": f.deadline_misses,
                             "steps_held": f.steps_held,
                             "reference": {k: _plain(v) for k, v in f.reference.items()},
                             "machine": f.machine_note()} if f.reference else {})}
                        for f in r.flights]}


TIMING_COLUMNS = ("flight", "autopilot deadline misses",
                  "autopilot steps held (simulator stalls)", "reference lost periods",
                  "reference worst wake-up", "reference p99", "over")


def timing_rows(r: Rehearsal) -> list[tuple[str, ...]]:
    """Each real-time flight flown beside the reference, by TIMING_COLUMNS. A stall that
    holds the simulator too is counted by the autopilot as held steps, not as misses
    (docs/realtime.md), so both are shown."""
    rows = []
    for f in r.flights:
        ref = f.reference
        if not ref:
            continue
        ours = tuple("not measured" if n is None else str(n)
                     for n in (f.deadline_misses, f.steps_held))
        if "error" in ref:
            rows.append((f.name, *ours, "not run", "", "", ref["error"]))
            continue
        rows.append((f.name, *ours, str(ref["lost_periods"]), f"{ref['worst_ms']:.2f} ms",
                     f"{ref['p99_ms']:.3f} ms",
                     f"{ref['window']}, {ref['window_s']:.1f} s, {ref['wakeups']} wake-ups"))
    return rows


def reference_line(r: Rehearsal) -> str:
    """What the reference was, once for the report (the same for every flight)."""
    ref = next((f.reference for f in r.flights if f.reference and "error" not in f.reference),
               None)
    if ref is None:
        return ""
    note = f"; {ref['note']}" if ref["note"] else ""
    return (f"The reference sleeper ({ref['source']}, {ref['scheduling']}, {ref['cpus']}, "
            f"every {ref['period_ms']:g} ms{note}) slept beside each real-time flight, woken "
            f"on the autopilot's period at its priority and doing no work; a lost period is "
            f"counted as the autopilot counts a deadline miss. Periods it lost are the "
            f"machine's, with none of our code running in it (docs/realtime.md).")


def _flight_count(r: Rehearsal) -> str:
    return f"{sum(f.result.passed for f in r.flights)} of {len(r.profile.flights)} flights"


def markdown(r: Rehearsal) -> str:
    static_ok = sum(o.passed for o in r.static)
    lines = [f"# Rehearsal of {r.airframe_name}: **{r.verdict}**", "",
             f"Profile `{r.profile.name}`; {static_ok} of {len(r.static)} static checks and "
             f"{_flight_count(r)} passed in {r.wall_time_s:.0f} s; control at "
             f"{r.rate_hz:g} Hz; model {r.model or 'none'}; {_given(r)}.", ""]
    failed = r.failed_checks()
    if failed:
        lines += ["## What failed, and what to change", "",
                  "| check | what it measured | what to change |", "|---|---|---|"]
        lines += [f"| {markdown_cell(group)}: {markdown_cell(o.name)} | "
                  f"{markdown_cell(o.message)} | {markdown_cell(advice)} |"
                  for group, o, advice in failed]
        lines.append("")
    if r.not_flown:
        lines += [f"Flights: {r.not_flown}.", ""]
    if r.flights:
        lines += ["## Flights", "", "| flight | result | expectations held | how | wall time |",
                  "|---|---|---|---|---|"]
        lines += [f"| {f.name} | {'pass' if f.result.passed else '**FAIL**'} | "
                  f"{sum(o.passed for o in f.result.outcomes)} of {len(f.result.outcomes)} | "
                  f"{'real time' if f.flight.realtime else 'lockstep'} | "
                  f"{f.result.wall_time_s:.1f} s |" for f in r.flights]
        lines.append("")
    timing = timing_rows(r)
    if timing:
        lines += ["## Deadlines beside the machine's own", "", reference_line(r), "",
                  "| " + " | ".join(TIMING_COLUMNS) + " |",
                  "|" + "---|" * len(TIMING_COLUMNS)]
        lines += ["| " + " | ".join(markdown_cell(c) for c in row) + " |" for row in timing]
        lines.append("")
    lines += ["## Static checks", "", "| check | result | measured |", "|---|---|---|"]
    lines += [f"| {markdown_cell(o.name)} | {'pass' if o.passed else '**FAIL**'} | "
              f"{markdown_cell(o.message)} |" for o in r.static]
    for f in r.flights:
        res = f.result
        lines += ["", f"## Flight {f.name}: {'pass' if res.passed else '**FAIL**'}", "",
                  f"{res.scenario.description}; "
                  f"{'real time' if f.flight.realtime else 'lockstep'}, flown in "
                  f"{res.wall_time_s:.1f} s; run folder `{res.run_dir}`.", ""]
        if res.error:
            lines += [f"The flight failed: {res.error.splitlines()[0]}", ""]
        lines += ["| expectation | result | measured |", "|---|---|---|"]
        lines += [f"| {markdown_cell(o.name)} | {'pass' if o.passed else '**FAIL**'} | "
                  f"{markdown_cell(o.message)} |" for o in res.outcomes]
    lines += ["", f"The parameters flown: `{PARAMS_FILE}` (QGroundControl's format)."]
    return "\n".join(lines) + "\n"


def _given(r: Rehearsal) -> str:
    if not r.given:
        return "default parameters"
    return "parameters set: " + ", ".join(f"{k} = {v:g}" for k, v in sorted(r.given.items()))


_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:70em;padding:0 1.5em;color:#222}
.verdict{font-size:2.4em;font-weight:700;padding:.4em .8em;border-radius:.3em;color:#fff;
display:inline-block}
.go{background:#1a7f37}.nogo{background:#c62828}
table{border-collapse:collapse;margin:.5em 0 1.5em;width:100%}
td,th{border:1px solid #ccc;padding:.3em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}.pass{color:#1a7f37;font-weight:600}.fail{color:#c62828;font-weight:700}
tr.failed{background:#fdecea}img{max-width:100%;border:1px solid #ddd}
details{margin:.3em 0 1em}
"""


def html_page(r: Rehearsal, out_dir: Path) -> str:
    """One self-contained page: the verdict first, then each failed check with what it
    measured, the limit and what to change, then every check and each flight's figure
    (inline PNG, no network)."""
    e = html.escape
    mark = lambda ok: '<span class="pass">pass</span>' if ok else \
        '<span class="fail">FAIL</span>'  # noqa: E731
    static_ok = sum(o.passed for o in r.static)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>Rehearsal of "
             f"{e(r.airframe_name)}: {r.verdict}</title><style>{_STYLE}</style></head><body>",
             f"<h1>Rehearsal of {e(r.airframe_name)}</h1>",
             f"<div class='verdict {'go' if r.passed else 'nogo'}' id='verdict'>"
             f"{r.verdict}</div>",
             f"<p>Profile <code>{e(r.profile.name)}</code>: {static_ok} of {len(r.static)} "
             f"static checks and {_flight_count(r)} passed in {r.wall_time_s:.0f} s; control "
             f"at {r.rate_hz:g} Hz; model {e(r.model or 'none')}; {e(_given(r))}.</p>"]
    failed = r.failed_checks()
    if failed:
        parts.append("<h2>What failed, and what to change</h2><table id='failed'><tr>"
                     "<th>check</th><th>measured</th><th>limit</th><th>what to change</th></tr>")
        parts += [f"<tr class='failed'><td>{e(group)}: {e(o.name)}</td><td>{e(o.message)}</td>"
                  f"<td>{e(_limit_text(o.limit))}</td><td>{e(advice)}</td></tr>"
                  for group, o, advice in failed]
        parts.append("</table>")
    if r.not_flown:
        parts.append(f"<p class='fail'>Flights: {e(r.not_flown)}.</p>")
    if r.flights:
        parts.append("<h2>Flights</h2><table id='flights'><tr><th>flight</th><th>result</th>"
                     "<th>expectations held</th><th>how</th><th>wall time</th></tr>")
        parts += [f"<tr{'' if f.result.passed else ' class=failed'}><td><a href='#flight-"
                  f"{e(f.name)}'>{e(f.name)}</a></td><td>{mark(f.result.passed)}</td><td>"
                  f"{sum(o.passed for o in f.result.outcomes)} of {len(f.result.outcomes)}</td>"
                  f"<td>{'real time' if f.flight.realtime else 'lockstep'}</td>"
                  f"<td>{f.result.wall_time_s:.1f} s</td></tr>" for f in r.flights]
        parts.append("</table>")
    timing = timing_rows(r)
    if timing:
        parts.append(f"<h2>Deadlines beside the machine's own</h2><p>{e(reference_line(r))}"
                     "</p><table id='reference'><tr>"
                     + "".join(f"<th>{e(c)}</th>" for c in TIMING_COLUMNS) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>"
                  for row in timing]
        parts.append("</table>")
    parts.append("<h2>Static checks</h2><table><tr><th>check</th><th>result</th>"
                 "<th>measured</th></tr>")
    parts += [f"<tr{'' if o.passed else ' class=failed'}><td>{e(o.name)}</td>"
              f"<td>{mark(o.passed)}</td><td>{e(o.message)}</td></tr>" for o in r.static]
    parts.append("</table>")
    for f in r.flights:
        res = f.result
        parts.append(f"<h2 id='flight-{e(f.name)}'>Flight {e(f.name)}: {mark(res.passed)}</h2>"
                     f"<p>{e(res.scenario.description)}; "
                     f"{'real time' if f.flight.realtime else 'lockstep'}, flown in "
                     f"{res.wall_time_s:.1f} s.</p>")
        if res.error:
            parts.append(f"<p class='fail'>The flight failed: {e(res.error)}</p>")
        parts.append("<table><tr><th>expectation</th><th>result</th><th>measured</th></tr>")
        parts += [f"<tr{'' if o.passed else ' class=failed'}><td>{e(o.name)}</td>"
                  f"<td>{mark(o.passed)}</td><td>{e(o.message)}</td></tr>"
                  for o in res.outcomes]
        parts.append("</table>")
        figure = res.run_dir / "tracking.png"
        if figure.is_file():
            data = base64.b64encode(figure.read_bytes()).decode()
            parts.append(f"<details open><summary>tracking</summary><img alt='tracking of "
                         f"{e(f.name)}' src='data:image/png;base64,{data}'></details>")
    parts.append(f"<p>The parameters flown: <code>{PARAMS_FILE}</code> (QGroundControl's "
                 f"format); each flight's run folder: <code>ivfm report "
                 f"{e(str(out_dir / 'flights'))}/NAME</code>.</p></body></html>")
    return "\n".join(parts) + "\n"


def _limit_text(limit: Any) -> str:
    if limit is None:
        return ""
    if isinstance(limit, list):
        return f"[{', '.join(f'{v:g}' for v in limit)}]"
    return f"{limit:g}" if isinstance(limit, float) else str(limit)


def junit(r: Rehearsal) -> str:
    """JUnit XML: a testsuite for the static checks and one per flight."""
    root = ET.Element("testsuites", name=f"ivfm rehearse {r.airframe_name}")
    suites = [("static", r.static, None, 0.0)]
    suites += [(f.name, f.result.outcomes, f.result.error, f.result.wall_time_s)
               for f in r.flights]
    if r.not_flown:
        suites += [(fl.scenario.stem, [], r.not_flown, 0.0) for fl in r.profile.flights]
    for name, outcomes, error, wall_s in suites:
        junit_suite(root, name, f"ivfm.rehearse.{name}", outcomes, error, wall_s)
    return junit_document(root, r.wall_time_s)


def summary_lines(r: Rehearsal) -> list[str]:
    """What the terminal shows at the end: the verdict and each failed check."""
    lines = [f"rehearsal of {r.airframe_name}: {r.verdict} ({sum(o.passed for o in r.static)}"
             f" of {len(r.static)} static checks, {_flight_count(r)} passed, "
             f"{r.wall_time_s:.0f} s)"]
    for group, o, advice in r.failed_checks():
        lines.append(f"  x {group}: {o.message}")
        if advice:
            lines.append(f"      change: {advice}")
    if r.not_flown:
        lines.append(f"  x flights: {r.not_flown}")
    return lines



