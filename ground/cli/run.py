"""``ivfm run``: one scenario flown into a run folder (processes, or in process), its
metrics printed."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autopilot.control.factory import CONTROLLERS
from contracts.arguments import RATE_HZ, SEED
from contracts.frames import home_argument
from contracts.mavlink import STATE_SOURCES
from contracts.timeline import process_start_s
from ground.cli.common import UsageError, add_rt_cpus, add_vehicle_options, fresh_folder
from ground.record.run_files import ULOG_FILE
from ground.report.metrics import format_metrics
from ground.run.flights import Overrides, fly_inprocess, fly_processes, plan_flight
from ground.run.loader import take_loader
from ground.scenario.scenario_file import scenario_by_name, shipped_names
from ground.telemetry.live_view import LAYOUT_FILE, view_address
from sitl.dynamics import FIDELITIES
from sitl.sensors import profile_argument


def add_arguments(run: argparse.ArgumentParser) -> None:
    run.add_argument("scenario", help=f"one of: {', '.join(shipped_names())}; or a scenario .toml")
    pace = run.add_mutually_exclusive_group()
    pace.add_argument("--inprocess", action="store_true",
                      help="plant and controller in one process (no MAVLink)")
    pace.add_argument("--realtime", action="store_true",
                      help="the two processes paced to the wall clock (default: lockstep)")
    run.add_argument("--rate-hz", type=RATE_HZ, default=100.0,
                     help="control rate, 1-1000 Hz (default 100)")
    add_rt_cpus(run)
    run.add_argument("--view", type=view_address, metavar="[HOST:]PORT",
                     help="serve the flight live to Foxglove on this WebSocket port while it "
                          "flies (e.g. 8765; docs/telemetry.md#foxglove)")
    run.add_argument("--state-source", choices=list(STATE_SOURCES),
                     help="what the autopilot flies on: the simulator's truth (auto, odometry, "
                          "hil-state) or its estimator on the sensors (default: the "
                          "scenario's, else auto)")
    run.add_argument("--sensors", type=profile_argument,
                     help="the simulator's sensor profile: ideal, typical, degraded or a "
                          ".toml file (default: the scenario's, else ideal)")
    run.add_argument("--seed", type=SEED, default=0,
                     help="seed of the simulator's sensors and link loss (default 0)")
    run.add_argument("--home", type=home_argument, metavar="NAME|LAT,LON,ALT",
                     help="where on Earth the flight is: a named home (CMAC, PX4, ...) or "
                          "degrees, degrees, metres AMSL "
                          "(default: the scenario's, else PX4's SITL home in Zurich); "
                          "south or west: --home=-33.86,151.21,40")
    run.add_argument("--controller", choices=CONTROLLERS, help="(default: the scenario's)")
    run.add_argument("--plant", choices=list(FIDELITIES), help="(default: the scenario's)")
    run.add_argument("--out", type=Path, default=None,
                     help="the run folder (default: a new one under runs/ named after the "
                          "scenario)")
    run.add_argument("--no-figures", action="store_true")
    run.add_argument("--ulog", action="store_true",
                     help=f"also write the run as a PX4 flight log, {ULOG_FILE} in the run "
                          "folder, its sensor readings logged for it (docs/ulog.md)")
    add_vehicle_options(run)
    run.set_defaults(airframe=None)


def handle(args: argparse.Namespace) -> int:
    started_s = process_start_s()
    scenario = scenario_by_name(args.scenario)
    if args.out is None:
        args.out = fresh_folder(scenario.name)
    plan = plan_flight(scenario, Overrides(
        controller=args.controller, plant=args.plant, airframe=args.airframe,
        sensors=args.sensors, state_source=args.state_source, parameters=dict(args.param),
        model_path=args.model, any_airframe_model=args.any_airframe_model,
        rate_hz=args.rate_hz, realtime=args.realtime, seed=args.seed,
        home=args.home, rt_cpus=args.rt_cpus))
    how = "in process" if args.inprocess else plan.how
    flying_on = ("its estimator" if plan.state_source == "estimator" else
                 "the simulator's truth")
    print(f"ivfm: {scenario.name} with {plan.controller} on the {plan.plant} plant, "
          f"{plan.sensors} sensors, flying on {flying_on} ({scenario.duration_s:g} s sim, "
          f"{how}); run folder {args.out}", file=sys.stderr)
    if args.inprocess and args.view is not None:
        raise UsageError("--view serves the telemetry of the processes: not with --inprocess")
    if args.inprocess and args.ulog:
        raise UsageError("--ulog writes the log of the processes: not with --inprocess "
                         "(which keeps no log)")
    if args.inprocess:
        metrics = fly_inprocess(plan, args.out, figures=not args.no_figures)
    else:
        # The loader the command line started first (ground/cli/main.py), loading the
        # processes' imports and compiled code while this process loaded its own.
        loader = take_loader()
        try:
            if args.view is not None:
                print(f"ivfm: live view on ws://{args.view[0]}:{args.view[1]} (Foxglove: "
                      f"open connection, Foxglove WebSocket; layout {LAYOUT_FILE})",
                      file=sys.stderr)
            metrics = fly_processes(plan, args.out, figures=not args.no_figures,
                                    loader=loader,
                                    started_s=started_s, view=args.view,
                                    log_sensors=args.ulog)
        finally:
            loader.close()
        telemetry = metrics["telemetry"]
        lost = sum(telemetry["lost"].values())
        print(f"telemetry: {sum(telemetry['published'].values())} records published, "
              f"{sum(telemetry['logged'].values())} logged, {lost} lost; log in {args.out}",
              file=sys.stderr)
    print(format_metrics(metrics))
    print(f"wrote {args.out / 'metrics.json'}" + ("" if args.no_figures else " and figures"))
    if args.ulog:
        from ground.ulog.export import export_ulog  # pyulog: only when asked for

        print(export_ulog(args.out, args.out / ULOG_FILE))
    return 1 if metrics["diverged"] else 0
