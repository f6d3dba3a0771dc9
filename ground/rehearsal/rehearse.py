"""``ivfm rehearse``: the checks a person runs before a first flight of their airframe,
and one go / no-go.

Checks that need no flight (ground/rehearsal/readiness.py: the airframe file, the parameters) come
first; then the profile's flights, each a scenario flown through the processes (lockstep,
or real time where timing is the point) with the rehearsed airframe, model, rate and
sensors, and judged by its own ``[expect]`` table, as ``ivfm check`` judges. Outputs in
the rehearsal folder: ``rehearsal.md``, a self-contained ``rehearsal.html``, JUnit XML,
the parameter set flown as a QGroundControl ``.params`` file, ``rehearsal.json``, and one
run folder per flight. docs/rehearsal.md is the guide.
"""

from __future__ import annotations

import base64
import html
import math
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from autopilot.control.factory import load_models, model_airframe_metadata, shipped_model_name
from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
from autopilot.models.model_file import save_model
from autopilot.parameters import airframe_parameters, validate_parameters
from contracts.airframe import airframe_from_spec
from contracts.airframe_file import AirframeSpec, check_controllable, read_airframe
from contracts.atomic_file import write_atomic
from ground.check.checker import CheckOptions, ScenarioResult, check_one
from ground.check.results import junit_document, junit_suite, markdown_cell
from ground.identify.excitation import excitation_dataset
from ground.record.run_files import write_json
from ground.rehearsal.readiness import ADVICE, Flight, Profile, airframe_checks, parameter_checks
from ground.run.children import WarmProcesses
from ground.run.flights import Overrides
from ground.scenario.expectations import Outcome
from ground.scenario.scenario_file import load_scenario

PARAMS_FILE = "parameters.params"
# What to change when one expectation fails, whatever the flight (else the flight's advice).
EXPECTATION_ADVICE = {
    "control.tilt_rate_rms_rad_s": "roll and pitch swing in a limit cycle: raise "
                                   "CMDF_ACC_MAX (the desired-angle filter's acceleration "
                                   "limit; 20 rad/s^2 on the quad X 500), or soften the "
                                   "position loop (POS_EPS)",
}


@dataclass
class FlightResult:
    flight: Flight
    result: ScenarioResult

    @property
    def name(self) -> str:
        return self.result.scenario.name


@dataclass
class Rehearsal:
    airframe: str
    airframe_name: str
    profile: Profile
    rate_hz: float
    sensors: str | None
    model: str  # where the model came from
    parameters: dict[str, float]
    given: dict[str, float] = field(default_factory=dict)  # set on the command line
    static: list[Outcome] = field(default_factory=list)
    flights: list[FlightResult] = field(default_factory=list)
    not_flown: str | None = None  # why the flights were not flown
    wall_time_s: float = 0.0

    @property
    def passed(self) -> bool:
        return (self.not_flown is None and all(o.passed for o in self.static)
                and all(f.result.passed for f in self.flights))

    @property
    def verdict(self) -> str:
        return "GO" if self.passed else "NO-GO"

    def failed_checks(self) -> list[tuple[str, Outcome, str]]:
        """(group, outcome, what to change) of every failed check."""
        out = [("static", o, _static_advice(o)) for o in self.static if not o.passed]
        for f in self.flights:
            if f.result.error is not None:
                out.append((f.name, Outcome("flight", False, None, None, f.result.error),
                            f.flight.advice))
            out += [(f.name, o, EXPECTATION_ADVICE.get(o.name.split(" ")[0], f.flight.advice))
                    for o in f.result.failures]
        return out


def _static_advice(outcome: Outcome) -> str:
    if outcome.measured is None and outcome.limit is not None:
        return ""  # not measurable: the airframe check says why
    key = "parameters" if outcome.name.startswith("parameter ") else outcome.name
    return ADVICE.get(key, "")


def resolve_model(airframe: AirframeSpec, model: Path | None, out_dir: Path,
                  say: Callable[[str], None]) -> tuple[Path | None, str]:
    """The model the flights fly: the one given, the airframe's shipped one, or one
    identified now on the airframe (about 2 s) into the rehearsal folder."""
    if model is not None:
        load_models(model, airframe)
        return model, str(model)
    try:
        load_models(None, airframe)
        return None, f"shipped {shipped_model_name(airframe)}"
    except ValueError:
        pass
    say("no model of this airframe: identifying one on it (ivfm identify)")
    dataset = excitation_dataset(airframe_from_spec(airframe))
    models = identify_dataset(dataset, n_clusters=DEFAULT_N_CLUSTERS, seed=0,
                              metadata=model_airframe_metadata(airframe))
    path = out_dir / "model.json"
    save_model(path, models)
    return path, f"identified now ({path.name})"


def rehearse(airframe: str, profile: Profile, out_dir: Path, model: Path | None = None,
             rate_hz: float = 100.0, sensors: str | None = None,
             parameters: dict[str, float] | None = None,
             say: Callable[[str], None] = lambda text: None,
             rt_cpus: frozenset[int] | None = None) -> Rehearsal:
    """Run every check of ``profile`` on ``airframe``; ValueError on bad input (an
    unreadable airframe file, a parameter out of its range, a bad model)."""
    start = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    spec = read_airframe(airframe, controllable=False)
    given = dict(parameters or {})
    own = airframe_parameters(spec)  # the airframe file's defaults, then the given
    flown = validate_parameters({**own, **given})
    rehearsal = Rehearsal(airframe, spec.name, profile, rate_hz, sensors, "", flown,
                          {**own, **given})
    rehearsal.static = (airframe_checks(spec, flown, profile.airframe_limits)
                        + parameter_checks(flown, profile.parameter_ranges))
    write_params(out_dir / PARAMS_FILE, flown, f"{spec.name}, ivfm rehearse")
    airframe_ok = next(o for o in rehearsal.static if o.name == "airframe").passed
    if not airframe_ok:
        rehearsal.not_flown = "the airframe cannot hover: no flight was flown"
    else:
        check_controllable(spec, spec.source)  # it hovers: the flights fly it
        model_path, rehearsal.model = resolve_model(spec, model, out_dir, say)
        options = CheckOptions(out_dir / "flights", keep_passed=True, figures=True)
        options.out_dir.mkdir(parents=True, exist_ok=True)
        warm = WarmProcesses(start=True)
        try:
            for i, flight in enumerate(profile.flights):
                scenario = load_scenario(flight.scenario)
                say(f"[{i + 1}/{len(profile.flights)}] {scenario.name} "
                    f"({'real time' if flight.realtime else 'lockstep'}, "
                    f"{scenario.duration_s:g} s)")
                overrides = Overrides(airframe=spec, sensors=sensors,
                                      parameters=given, model_path=model_path,
                                      rate_hz=rate_hz, realtime=flight.realtime,
                                      rt_cpus=rt_cpus)
                result = check_one(scenario, options, warm, overrides)
                rehearsal.flights.append(FlightResult(flight, result))
                held = sum(o.passed for o in result.outcomes)
                say(f"      {result.label}: {held}/{len(result.outcomes)} held in "
                    f"{result.wall_time_s:.1f} s"
                    + (f" ({result.error.splitlines()[0]})" if result.error else ""))
        finally:
            warm.close()
    rehearsal.wall_time_s = time.perf_counter() - start
    write_outputs(rehearsal, out_dir)
    return rehearsal


# -- outputs ----------------------------------------------------------------------------

def write_outputs(r: Rehearsal, out_dir: Path) -> None:
    write_json(out_dir / "rehearsal.json", rehearsal_json(r))
    write_atomic(out_dir / "rehearsal.md", markdown(r))
    write_atomic(out_dir / "rehearsal.html", html_page(r, out_dir))
    write_atomic(out_dir / "rehearsal.xml", junit(r))


def write_params(path: Path, parameters: dict[str, float], what: str) -> None:
    """QGroundControl's parameter file (Vehicle-Id, Component-Id, Name, Value, Type; every
    parameter REAL32, type 9), which QGC's Parameters > Tools > Load from file reads;
    values in full, so the set flown reloads exactly."""
    lines = [f"# Onboard parameters of {what}", "#",
             "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{name}\t{float(value)!r}\t9"
              for name, value in sorted(parameters.items())]
    write_atomic(path, "\n".join(lines) + "\n")


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
                         "outcomes": [_outcome_json(o) for o in f.result.outcomes]}
                        for f in r.flights]}


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



