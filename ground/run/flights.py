"""One scenario flown into a run folder, the way ``ivfm run`` flies it: the scenario's
choices after overrides, the processes (or the one-process path), the run files, and
the metrics computed from the log. ``ivfm run``, ``ivfm check`` and the pytest plugin
all fly through here.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from autopilot.control.factory import load_models
from autopilot.parameters import airframe_parameters, validate_parameters
from contracts.airframe import airframe_from_spec
from contracts.airframe_file import AirframeSpec, read_airframe
from contracts.frames import Home
from ground.record import timeline as run_timeline
from ground.record.run_files import RUN_FILE, SCENARIO_FILE, write_json
from ground.report.metrics import compute_metrics
from ground.run.inprocess import run_inprocess
from ground.run.loader import ProcessLoader
from ground.run.placement import FlightSlot
from ground.run.processes import FIGURE_MODULES, REPORT_MODULES, RunSettings, run_processes
from ground.run.progress import ProgressLine
from ground.scenario.scenario_file import Scenario
from sitl.sensors import read_profile


@dataclass(frozen=True)
class Overrides:
    """Command-line choices over the scenario file's (None: the scenario's)."""

    controller: str | None = None
    plant: str | None = None
    airframe: AirframeSpec | str | None = None  # a name or path is read here, once
    sensors: str | None = None
    state_source: str | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    model_path: Path | None = None
    any_airframe_model: bool = False
    rate_hz: float = 100.0
    realtime: bool = False
    seed: int = 0
    home: Home | None = None
    rt_cpus: frozenset[int] | None = None  # the vehicle processes' CPUs (None: any)


@dataclass(frozen=True)
class FlightPlan:
    """Everything a flight needs, resolved and checked."""

    scenario: Scenario
    controller: str
    plant: str
    airframe: AirframeSpec
    sensors: str
    state_source: str
    parameters: dict[str, float]  # every parameter, defaults included
    given: frozenset[str]  # the names the scenario or the command line set
    model_path: Path | None
    any_airframe_model: bool
    rate_hz: float
    realtime: bool
    seed: int
    home: Home
    rt_cpus: frozenset[int] | None = None

    @property
    def how(self) -> str:
        return ("logger + simulator + autopilot, real time" if self.realtime else
                "logger + simulator + autopilot, lockstep")


def plan_flight(scenario: Scenario, overrides: Overrides | None = None) -> FlightPlan:
    """The scenario's choices after ``overrides``; ValueError on a bad combination
    (an unknown airframe, a model for another airframe)."""
    o = overrides or Overrides()
    controller = o.controller or scenario.controller
    airframe = (scenario.airframe if o.airframe is None else
                read_airframe(o.airframe) if isinstance(o.airframe, str) else o.airframe)
    airframe_from_spec(airframe)
    sensors = o.sensors or scenario.sensors
    state_source = o.state_source or scenario.state_source
    # The airframe file's own defaults, then the scenario's, then the command line's.
    given = {**airframe_parameters(airframe),
             **scenario.parameters, **o.parameters}
    if state_source == "estimator" and "EKF2_GPS_DELAY" not in given:
        # The vehicle's estimator is set up for its GPS receiver, as a user would set it.
        given["EKF2_GPS_DELAY"] = 1000.0 * read_profile(sensors).gps_latency_s
    model_path = o.model_path or scenario.model_path
    if controller in ("ivfc", "t1fc"):  # refused now, not in the autopilot's log
        load_models(model_path, airframe, o.any_airframe_model)
    if not (o.rate_hz > 0.0 and o.rate_hz <= 10_000.0):
        raise ValueError(f"--rate-hz must be in (0, 10000], got {o.rate_hz!r}")
    return FlightPlan(scenario.on_airframe(airframe), controller, o.plant or scenario.plant,
                      airframe, sensors,
                      state_source, validate_parameters(given), frozenset(given), model_path,
                      o.any_airframe_model, o.rate_hz, o.realtime, o.seed,
                      o.home or scenario.home, o.rt_cpus)


def fly_processes(plan: FlightPlan, out_dir: Path, figures: bool | str = True,
                  quiet: bool = False, loader: ProcessLoader | None = None,
                  started_s: float | None = None,
                  view: tuple[str, int] | None = None,
                  log_sensors: bool = False,
                  flight_slot: FlightSlot | None = None) -> dict[str, Any]:
    """Fly through the processes into ``out_dir`` (run.json, scenario copy, log, process
    logs); returns metrics.json's content. ``quiet``: no progress on stderr; ``loader``:
    the processes forked by this process loader (ground/run/loader.py), not started anew;
    ``started_s``: when the command started (time.monotonic), for the run's timeline;
    ``view``: (host, port) of a live view the logger serves; ``log_sensors``: the log
    keeps the simulator's sensor readings too (a ULog's sensor topics); ``flight_slot``:
    what the flight holds while it flies (``run_processes``)."""
    scenario = plan.scenario
    settings = RunSettings(plan.controller, plan.plant, plan.airframe.argument, plan.model_path,
                           {k: v for k, v in plan.parameters.items() if k in plan.given},
                           realtime=plan.realtime, rate_hz=plan.rate_hz,
                           state_source=plan.state_source, sensors=plan.sensors,
                           seed=plan.seed, any_airframe_model=plan.any_airframe_model,
                           home=plan.home, rt_cpus=plan.rt_cpus, log_sensors=log_sensors)
    accounting = run_processes(
        scenario, settings, out_dir, quiet=quiet, loader=loader, started_s=started_s, view=view,
        report_modules=REPORT_MODULES + (FIGURE_MODULES if figures else ()),
        flight_slot=flight_slot)
    timing = accounting.pop("timing")
    shutil.copyfile(scenario.source, out_dir / SCENARIO_FILE)
    if scenario.plan is not None and scenario.plan.is_relative_to(scenario.source.parent):
        # beside the copy, where its [mission] names it (an absolute name needs no copy)
        beside = out_dir / scenario.plan.relative_to(scenario.source.parent)
        beside.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(scenario.plan, beside)
    write_json(out_dir / RUN_FILE, {
        "scenario": scenario.name, "controller": plan.controller, "plant": plan.plant,
        "airframe": plan.airframe.argument, "rate_hz": plan.rate_hz, "vehicle": settings.vehicle,
        "mode": "realtime" if plan.realtime else "lockstep",
        "state_source": plan.state_source, "sensors": plan.sensors, "seed": plan.seed,
        "home": list(plan.home), "parameters": plan.parameters,
        "model": str(plan.model_path) if plan.model_path else None,
        "telemetry": accounting, "timing": timing})
    from ground.report.run_report import report  # imported during the flight (run_processes)

    metrics, _record = report(out_dir, figures=figures)
    return run_timeline.finish(out_dir, metrics)


def fly_inprocess(plan: FlightPlan, out_dir: Path, figures: bool = True) -> dict[str, Any]:
    """Fly plant and controller in one process; metrics.json (no events: no processes)."""
    scenario = plan.scenario
    models = (load_models(plan.model_path, plan.airframe, plan.any_airframe_model)
              if plan.controller in ("ivfc", "t1fc") else None)
    line = ProgressLine(scenario.name, scenario.duration_s)
    line.loading()
    try:
        record = run_inprocess(scenario, plan.controller, plan.plant,
                               airframe_from_spec(plan.airframe), models,
                               period_s=1.0 / plan.rate_hz, parameters=plan.parameters,
                               sensors=plan.sensors, state_source=plan.state_source,
                               seed=plan.seed, home=plan.home, progress=line.update)
    finally:
        line.done()
    metrics = compute_metrics(record, scenario, plan.airframe.argument)
    metrics["mode"] = "inprocess"
    metrics["sensors"], metrics["state_source"] = plan.sensors, plan.state_source
    metrics["seed"] = plan.seed
    metrics["parameters"] = plan.parameters
    write_json(out_dir / "metrics.json", metrics)
    if figures:
        from ground.report.figures import plot_run  # matplotlib: 0.3 s, only when drawn

        plot_run(record, scenario, out_dir)
    return metrics
