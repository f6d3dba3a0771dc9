"""``ivfm rehearse``: the checks a person runs before a first flight of their airframe,
and one go / no-go.

Checks that need no flight (ground/rehearsal/readiness.py: the airframe file, the parameters) come
first; then the profile's flights, each a scenario flown through the processes (lockstep,
or real time where timing is the point) with the rehearsed airframe, model, rate and
sensors, and judged by its own ``[expect]`` table, as ``ivfm check`` judges. Beside each
real-time flight a reference sleeper (ground/run/reference.py) wakes on the autopilot's
period at its priority and on its CPUs: the periods it lost while the autopilot's loop ran
are reported next to the autopilot's deadline misses (information: the verdict is the
flights' own). Outputs in the rehearsal folder: ``rehearsal.md``, a self-contained
``rehearsal.html``, JUnit XML, the parameter set flown as a QGroundControl ``.params``
file, ``rehearsal.json``, and one run folder per flight. docs/rehearsal.md is the guide.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from autopilot.control.factory import load_models, model_airframe_metadata, shipped_model_name
from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
from autopilot.models.model_file import save_model
from autopilot.parameters import airframe_parameters, validate_parameters
from contracts.airframe import airframe_from_spec
from contracts.airframe_file import AirframeSpec, check_controllable, read_airframe
from contracts.arguments import AUTOPILOT_RT_PRIORITY
from contracts.atomic_file import write_atomic
from ground.check.checker import CheckOptions, check_one
from ground.identify.excitation import excitation_dataset
from ground.record.timeline import TIMELINE_FILE
from ground.rehearsal.outputs import PARAMS_FILE, write_outputs
from ground.rehearsal.readiness import Flight, Profile, airframe_checks, parameter_checks
from ground.rehearsal.results import FlightResult, Rehearsal
from ground.report.run_report import TRACKING_ONLY
from ground.run.flights import Overrides
from ground.run.loader import ProcessLoader, take_loader
from ground.run.reference import CHOICES, CYCLICTEST, ReferenceSleeper, tally
from ground.run.reference import summary as reference_summary
from ground.scenario.scenario_file import Scenario, load_scenario


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
             rt_cpus: frozenset[int] | None = None,
             reference: str = "auto") -> Rehearsal:
    """Run every check of ``profile`` on ``airframe``; ValueError on bad input (an
    unreadable airframe file, a parameter out of its range, a bad model, cyclictest asked
    for and not installed). ``reference``: the sleeper beside each real-time flight
    (ground/run/reference.py: auto, cyclictest, built-in; none: no reference)."""
    if reference not in (*CHOICES, "none"):
        raise ValueError(f"reference must be one of {', '.join(CHOICES)} or none")
    if reference == CYCLICTEST and shutil.which(CYCLICTEST) is None:
        raise ValueError("cyclictest is not installed (Debian: apt-get install rt-tests)")
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
        # Each flight's tracking figure (the page shows it); a failed flight's every figure
        # and its page, for the diagnosis; the others' on request (ivfm report).
        options = CheckOptions(out_dir / "flights", keep_passed=True, figures=TRACKING_ONLY,
                               figures_on_failure=True)
        options.out_dir.mkdir(parents=True, exist_ok=True)
        loader = take_loader()
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
                if flight.realtime and reference != "none":
                    flown = fly_beside_reference(flight, scenario, options, loader, overrides,
                                                 reference)
                else:
                    flown = FlightResult(flight, check_one(scenario, options, loader,
                                                           overrides))
                rehearsal.flights.append(flown)
                result = flown.result
                held = sum(o.passed for o in result.outcomes)
                say(f"      {result.label}: {held}/{len(result.outcomes)} held in "
                    f"{result.wall_time_s:.1f} s"
                    + (f" ({result.error.splitlines()[0]})" if result.error else ""))
        finally:
            loader.close()
    rehearsal.wall_time_s = time.perf_counter() - start
    write_outputs(rehearsal, out_dir)
    return rehearsal


def fly_beside_reference(flight: Flight, scenario: Scenario, options: CheckOptions,
                         loader: ProcessLoader, overrides: Overrides,
                         prefer: str) -> FlightResult:
    """A real-time flight with the reference sleeper beside it, on the autopilot's period,
    priority and CPUs; its figures over the autopilot's loop (first to last control
    step, from the run's timeline), else over the whole flight."""
    samples: list[tuple[float, float]] = []
    period_s = 1.0 / overrides.rate_hz
    sleeper = ReferenceSleeper(period_s, lambda t_s, late_s: samples.append((t_s, late_s)),
                               AUTOPILOT_RT_PRIORITY, overrides.rt_cpus, prefer)
    error = None
    try:
        sleeper.start()
    except RuntimeError as exc:
        error = str(exc)
    started_s = time.monotonic()
    try:
        result = check_one(scenario, options, loader, overrides, started_s=started_s)
    finally:
        sleeper.stop()
    flown = FlightResult(flight, result)
    if error is not None:
        flown.reference = {"error": error}
        return flown
    loop = loop_window(result.run_dir, started_s)
    start_s, end_s = loop or (started_s, samples[-1][0] if samples else started_s)
    end_s = min(end_s, samples[-1][0]) if samples else end_s
    flown.reference = {**reference_summary(sleeper, tally(samples, period_s, start_s, end_s)),
                       "window": "the autopilot's loop" if loop else "the whole flight",
                       "window_s": round(max(0.0, end_s - start_s), 3)}
    return flown


def loop_window(run_dir: Path, started_s: float) -> tuple[float, float] | None:
    """The autopilot's loop, first to last control step, on time.monotonic: the run's
    timeline counts from ``started_s``. None without a first step; a loop that never
    marked its last step (the flight failed) ends at infinity."""
    try:
        events = json.loads((run_dir / TIMELINE_FILE).read_text())["events"]
    except (OSError, ValueError, KeyError):
        return None
    marks: dict[str, float] = {}
    for e in events:
        if e.get("process") == "autopilot":
            marks.setdefault(e["event"], started_s + e["t_s"])
    if "first control step" not in marks:
        return None
    return marks["first control step"], marks.get("last control step", math.inf)


def write_params(path: Path, parameters: dict[str, float], what: str) -> None:
    """QGroundControl's parameter file (Vehicle-Id, Component-Id, Name, Value, Type; every
    parameter REAL32, type 9), which QGC's Parameters > Tools > Load from file reads;
    values in full, so the set flown reloads exactly."""
    lines = [f"# Onboard parameters of {what}", "#",
             "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{name}\t{float(value)!r}\t9"
              for name, value in sorted(parameters.items())]
    write_atomic(path, "\n".join(lines) + "\n")
