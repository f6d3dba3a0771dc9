"""What each ``ivfm`` subcommand does (the argument parsing is in cli.py)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

# The vehicle's modules (numba-compiled code among them) are imported by the commands
# that need them: ``ivfm ground log``, the logger of every run, starts without them.
if TYPE_CHECKING:
    from autopilot.models.ts_model import FuzzyModelSet


class UsageError(Exception):
    """Bad input from the command line: reported in one line, exit code 2."""


def fresh_folder(name: str, parent: Path = Path("runs")) -> Path:
    """``runs/NAME-YYYYMMDD-HHMMSS`` (and ``-2``, ``-3``... if that one exists): where a
    command writes when it is given no ``--out``, so that no run overwrites another."""
    base = parent / time.strftime(f"{name}-%Y%m%d-%H%M%S")
    folder, n = base, 1
    while folder.exists():
        n += 1
        folder = base.with_name(f"{base.name}-{n}")
    return folder


def run_command(args: argparse.Namespace) -> int:
    from contracts.timeline import process_start_s
    from ground.flights import Overrides, fly_inprocess, fly_processes, plan_flight
    from ground.scenarios import scenario_by_name

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
    if args.inprocess:
        metrics = fly_inprocess(plan, args.out, figures=not args.no_figures)
    else:
        from ground.processes import WarmProcesses

        # Started as soon as the input is checked: each loads its imports and compiled
        # code while the others load theirs and the run folder is prepared.
        warm = WarmProcesses(start=True)
        try:
            if args.view is not None:
                from ground.live_view import LAYOUT_FILE

                print(f"ivfm: live view on ws://{args.view[0]}:{args.view[1]} (Foxglove: "
                      f"open connection, Foxglove WebSocket; layout {LAYOUT_FILE})",
                      file=sys.stderr)
            metrics = fly_processes(plan, args.out, figures=not args.no_figures, warm=warm,
                                    started_s=started_s, view=args.view)
        finally:
            warm.close()
        telemetry = metrics["telemetry"]
        lost = sum(telemetry["lost"].values())
        print(f"telemetry: {sum(telemetry['published'].values())} records published, "
              f"{sum(telemetry['logged'].values())} logged, {lost} lost; log in {args.out}",
              file=sys.stderr)
    print(format_metrics(metrics))
    print(f"wrote {args.out / 'metrics.json'}" + ("" if args.no_figures else " and figures"))
    return 1 if metrics["diverged"] else 0


def check_command(args: argparse.Namespace) -> int:
    import os

    from ground.check import (
        CheckOptions,
        Progress,
        collect,
        junit_xml,
        markdown_summary,
        read_baseline,
        results_table,
        run_check,
    )

    scenarios = collect(args.paths)
    baseline = read_baseline(args.baseline) if args.baseline is not None else None
    out = args.out or fresh_folder("check")
    summary = args.summary or (Path(os.environ["GITHUB_STEP_SUMMARY"])
                               if os.environ.get("GITHUB_STEP_SUMMARY") else None)
    mode = "real time" if args.realtime else "lockstep"
    print(f"ivfm check: {len(scenarios)} scenario(s), {mode}, {args.jobs} at a time; run "
          f"folders in {out}", file=sys.stderr)
    start = time.perf_counter()
    results = run_check(scenarios, CheckOptions(out, realtime=args.realtime, jobs=args.jobs,
                                                baseline=baseline, tolerance=args.tolerance,
                                                keep_passed=args.keep, warm=not args.cold,
                                                rt_cpus=args.rt_cpus),
                        Progress(len(scenarios)))
    wall_s = time.perf_counter() - start
    print(results_table(results))
    failed = [r for r in results if not r.passed]
    print(f"{len(results) - len(failed)} of {len(results)} passed in {wall_s:.1f} s"
          + (f"; failed run folders kept in {out}" if failed else ""))
    if args.junit is not None:
        args.junit.parent.mkdir(parents=True, exist_ok=True)
        args.junit.write_text(junit_xml(results))
        print(f"wrote {args.junit}")
    if summary is not None:
        with open(summary, "a") as f:
            f.write(markdown_summary(results, wall_s))
        print(f"appended the summary to {summary}")
    return 1 if failed else 0


def rehearse_command(args: argparse.Namespace) -> int:
    from ground.readiness import load_profile
    from ground.rehearsal import print_progress, rehearse, summary_lines

    profile = load_profile(args.profile)
    out = args.out or fresh_folder("rehearse")
    print(f"ivfm rehearse: {args.airframe}, profile {profile.name} ({len(profile.flights)} "
          f"flights), control at {args.rate_hz:g} Hz; folder {out}", file=sys.stderr)
    result = rehearse(args.airframe, profile, out, model=args.model, rate_hz=args.rate_hz,
                      sensors=args.sensors, parameters=dict(args.param), say=print_progress,
                      rt_cpus=args.rt_cpus)
    print("\n".join(summary_lines(result)))
    print(f"wrote {out / 'rehearsal.html'}, rehearsal.md, rehearsal.xml, parameters.params")
    if args.junit is not None:
        args.junit.parent.mkdir(parents=True, exist_ok=True)
        args.junit.write_text((out / "rehearsal.xml").read_text())
        print(f"wrote {args.junit}")
    return 0 if result.passed else 1


def report_command(args: argparse.Namespace) -> int:
    from ground.report import report

    metrics, record = report(args.run_dir, figures=not args.no_figures)
    print(format_metrics(metrics))
    print(f"wrote {args.run_dir / 'metrics.json'}" + ("" if args.no_figures else " and figures"))
    return 1 if record.diverged else 0


def format_metrics(metrics: dict[str, Any]) -> str:
    lines = [f"{metrics['scenario']} | {metrics['controller']} | {metrics['plant']} plant | "
             f"{metrics['sim_time_s']:.1f} s sim in {metrics['wall_time_s']:.2f} s wall "
             f"({metrics['real_time_factor']:.0f}x real time)"
             + (" | DIVERGED" if metrics["diverged"] else "")]
    if metrics.get("startup_wall_s", 0.0) > 1.0:
        lines.append(f"  the first step loaded the compiled numerical core in "
                     f"{metrics['startup_wall_s']:.1f} s (compiling it: a fresh install; "
                     "cached after), not counted above")
    if "loop_real_time_factor" in metrics:
        lines.append(f"  loop {metrics['loop_real_time_factor']:.1f}x real time after warm-up; "
                     f"whole command {metrics.get('command_wall_time_s', math.nan):.2f} s wall")
    lines.append(f"  errors after {metrics['transient_s']:g} s:")
    for axis, m in metrics["axes"].items():
        lines.append(f"    {axis:>5}: rmse {m['rmse']:.5f}  mse {m['mse']:.3e}  "
                     f"max {m['max_abs']:.4f}")
    est = metrics.get("estimation")
    if est:
        lines.append(f"  estimation: attitude {est['attitude_rmse_rad']:.4f} rad  yaw "
                     f"{est['yaw_rmse_rad']:.4f} rad  position {est['position_rmse_m']:.3f} m  "
                     f"altitude {est['altitude_rmse_m']:.3f} m  velocity "
                     f"{est['velocity_rmse_mps']:.3f} m/s (RMSE against truth)")
    path = metrics.get("path")
    if path:
        arrivals = ", ".join("-" if t is None else f"{t:.2f}" for t in path["arrival_s"])
        lines.append(f"  path: {'every item reached' if path['all_reached'] else 'NOT ALL REACHED'}"
                     f" (arrivals [s]: {arrivals})")
        if path["cross_track_rmse_m"] is not None:
            lines.append(f"  cross-track: rmse {path['cross_track_rmse_m']:.4f} m  max "
                         f"{path['cross_track_max_m']:.4f} m")
    c = metrics["control"]
    lines.append(f"  effort {c['effort_mean_sum_c2']:.4f}  chattering "
                 f"{c['chattering_per_s']:.3f}/s  saturated {100 * c['saturated_fraction']:.1f} %")
    return "\n".join(lines)


def compare_command(args: argparse.Namespace) -> int:
    from autopilot.control.factory import load_models
    from autopilot.parameters import validate_parameters
    from contracts.airframe import airframe_by_name
    from contracts.airframe_file import read_airframe
    from ground.compare import run_comparison
    from ground.scenarios import scenario_by_name

    for name in args.scenarios:
        scenario_by_name(name)
    airframe_by_name(args.airframe)
    parameters = validate_parameters(dict(args.param))
    models = load_models(args.model, read_airframe(args.airframe), args.any_airframe_model)
    return run_comparison(args.scenarios, args.controllers, args.plants, args.airframe, models,
                          parameters, args.out or fresh_folder("compare"))


def identify_command(args: argparse.Namespace) -> int:
    from autopilot.control.factory import model_airframe_metadata
    from autopilot.identification.coverage import coverage, coverage_metadata, format_coverage
    from autopilot.identification.dataset import read_dataset, write_dataset
    from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
    from autopilot.models.model_file import save_model
    from contracts.airframe import airframe_by_name
    from contracts.airframe_file import Envelope, airframe_envelope, read_airframe
    from ground.excitation import excitation_dataset
    from ground.paper_tables import TABLE_2_VALIDATION_RMSE

    airframe = airframe_by_name(args.airframe)
    envelope = (Envelope(*args.envelope) if args.envelope else
                airframe_envelope(args.airframe))
    n_clusters = DEFAULT_N_CLUSTERS if args.clusters is None else args.clusters
    start = time.perf_counter()
    if args.data is not None and args.log is not None:
        raise UsageError("give --data or --log, not both")
    if args.log is not None:
        from ground.excitation import dataset_from_log

        dataset = dataset_from_log(args.log, args.vehicle, airframe)
        print(f"ivfm: identifying from the log {args.log} ({dataset.n_rows} samples of "
              f"vehicle {args.vehicle})", file=sys.stderr)
    elif args.data is not None:
        dataset = read_dataset(args.data)
        print(f"ivfm: identifying from {args.data} ({dataset.n_rows} samples)", file=sys.stderr)
    else:
        print(f"ivfm: flying the excitation ({args.samples} samples, seed {args.seed}) for "
              f"the envelope {envelope.attitude_rad:g} rad, {envelope.rate_rad_s:g} rad/s "
              f"(yaw {envelope.yaw_rate_rad_s:g} rad/s)", file=sys.stderr)
        from ground.progress import ProgressLine

        line = ProgressLine("  excitation", args.samples * 0.01)
        line.loading()
        try:
            dataset = excitation_dataset(airframe, n_samples=args.samples, seed=args.seed,
                                         progress=line.update, envelope=envelope)
        finally:
            line.done()
    if args.write_data is not None:
        write_dataset(args.write_data, dataset)
        print(f"wrote {args.write_data}")
    reach = coverage(dataset, envelope)
    print(format_coverage(reach))
    if not all(c.covered for c in reach):
        advice = ("the data does not cover the envelope: the model would extrapolate where "
                  "it is flown")
        if not args.allow_narrow:
            raise UsageError(f"{advice}. Fly a wider excitation, identify for the envelope "
                             f"the data covers (--envelope), or accept it (--allow-narrow); "
                             f"no model written")
        print(f"ivfm: warning: {advice} (--allow-narrow)", file=sys.stderr)
    models = identify_dataset(dataset, n_clusters=n_clusters, seed=args.seed,
                              metadata={**model_airframe_metadata(read_airframe(args.airframe)),
                                        **coverage_metadata(envelope, reach)})
    elapsed = time.perf_counter() - start
    print(format_table_2(models, TABLE_2_VALIDATION_RMSE))
    print(f"identification took {elapsed:.2f} s")
    if args.out is not None:
        save_model(args.out, models)
        print(f"wrote {args.out}")
    return 0


def format_table_2(models: FuzzyModelSet, paper: dict[str, tuple[float, float]]) -> str:
    lines = ["Validation RMSE of the identified models (paper's Table 2 beside ours)",
             f"{'function':<10}{'paper T1FM':>12}{'paper IVFM':>12}{'our T1FM':>12}"
             f"{'our IVFM':>12}  IVFM better?"]
    for name, ch in models.channels.items():
        p_t1, p_iv = paper[name]
        better = ch.rmse_valid_ivfm < ch.rmse_valid_t1fm
        verdict = "yes" if better else ("equal" if ch.rmse_valid_ivfm == ch.rmse_valid_t1fm
                                        else "no")
        lines.append(f"f_{name:<8}{p_t1:>12.4f}{p_iv:>12.4f}{ch.rmse_valid_t1fm:>12.4f}"
                     f"{ch.rmse_valid_ivfm:>12.4f}  {verdict}")
        lines.extend(f"    note: {note}" for note in ch.notes)
    return "\n".join(lines)


def shield_command(args: argparse.Namespace) -> int:
    from contracts.realtime import shield_cpus

    reserved = None if args.off else args.cpus
    moved, refused = shield_cpus(reserved)
    where = ("every CPU open to every thread again" if reserved is None else
             f"CPU {','.join(map(str, sorted(reserved)))} kept for processes started with "
             f"--rt-cpus {','.join(map(str, sorted(reserved)))}")
    print(f"{where}: {moved} threads moved"
          + (f", {refused} refused (not ours to move: run as root)" if refused else ""))
    return 0


def scenarios_command(args: argparse.Namespace) -> int:
    from ground.scenarios import shipped_scenarios

    for s in shipped_scenarios().values():
        kicks = f", {len(s.perturbations)} perturbations" if s.perturbations else ""
        print(f"{s.name:<16} {s.description} (judged on {', '.join(s.axes)} after "
              f"{s.transient_s:g} s{kicks}; {s.source})")
    return 0


def campaigns_command(args: argparse.Namespace) -> int:
    from ground.campaign.spec import read_campaign, shipped_campaigns

    for name in shipped_campaigns():
        c = read_campaign(name)
        print(f"{c.name:<22} {c.description} ({c.tasks} runs; {c.source})")
    return 0


def campaign_command(args: argparse.Namespace) -> int:
    import dataclasses

    from ground.campaign.report import markdown, write_report
    from ground.campaign.run import read_rows, run_campaign
    from ground.campaign.spec import read_campaign

    campaign = read_campaign(args.campaign)
    if args.runs is not None:
        campaign = dataclasses.replace(campaign, runs=args.runs)
    out = args.out or Path("runs") / campaign.name
    if not args.report_only:
        try:
            counts = run_campaign(campaign, out, scheduler=args.scheduler,
                                  workers=args.workers)
        except KeyboardInterrupt:
            print("ivfm: campaign stopped; its finished runs are in "
                  f"{out}; the same command goes on from there", file=sys.stderr)
            return 130
        print(f"ivfm: {counts['flown']} runs flown ({counts['failed']} failed), "
              f"{counts['skipped']} done before, of {counts['total']}", file=sys.stderr)
    rows = read_rows(out)
    if not rows:
        raise UsageError(f"{out} holds no finished runs")
    report = write_report(out, campaign.name, campaign.kind, campaign.controllers, rows)
    print(markdown(campaign.name, campaign.kind, report))
    print(f"wrote {out / 'report.md'}, report.json, results.csv and figures")
    return 0


def params_command(args: argparse.Namespace) -> int:
    from autopilot.parameters import PARAMETERS

    for p in PARAMETERS:
        print(f"{p.name:<16} {p.default:>10g}  [{p.minimum:g}, {p.maximum:g}] {p.unit:<8}"
              f" {p.description}")
    return 0


def sitl_command(args: argparse.Namespace) -> int:
    from sitl.__main__ import run

    return run(args)


def autopilot_command(args: argparse.Namespace) -> int:
    from autopilot.__main__ import run

    return run(args)


def ground_log_command(args: argparse.Namespace) -> int:
    from contracts.zenoh_link import zenoh_options_from_args
    from ground.logger import Logger, LoggerConfig

    config = LoggerConfig(args.out, zenoh_options_from_args(args), name=args.name,
                          prefix=args.prefix, chunk_bytes=args.chunk_kib * 1024,
                          flush_period_s=args.flush_s, rotate_bytes=args.rotate_mib * 2**20,
                          rotate_chunks=args.rotate_chunks,
                          compression=args.compression, foxglove=not args.no_foxglove,
                          view_rate_hz=args.view_rate_hz)
    if args.view is None:
        return Logger(config).run()
    from ground.live_view import LiveView

    live = LiveView(*args.view)
    print(f"logger: serving the live view on {live.url}", file=sys.stderr, flush=True)
    try:
        return Logger(config, live=live.publish).run()
    finally:
        live.close()


def ground_view_command(args: argparse.Namespace) -> int:
    from contracts.zenoh_link import zenoh_options_from_args
    from ground.live_view import serve_view

    return serve_view(zenoh_options_from_args(args), *args.view, rate_hz=args.view_rate_hz)


def _perturb_value(text: str) -> Any:
    """A NAME=VALUE right-hand side: a number or comma-separated numbers."""
    parts = [p.strip() for p in text.split(",")]
    try:
        numbers = [float(p) for p in parts]
    except ValueError:
        raise UsageError(f"{text!r} is not a number or a comma-separated list of numbers") \
            from None
    return numbers if len(numbers) > 1 else numbers[0]


def ground_perturb_command(args: argparse.Namespace) -> int:
    from contracts.perturbations import KINDS
    from contracts.telemetry import AUTOPILOT, SITL
    from contracts.zenoh_link import zenoh_options_from_args
    from ground.perturb import PerturbationClient, PerturbationError

    with PerturbationClient(zenoh_options_from_args(args), timeout_s=args.timeout) as client:
        try:
            if args.kind in ("list", "clear"):
                targets = [args.target] if args.target else [SITL, AUTOPILOT]
                for target in targets:
                    if args.kind == "list":
                        for entry in client.list(args.vehicle, target):
                            print(f"{target}: {json.dumps(entry)}")
                    else:
                        answer = client.clear(args.vehicle, target, args.id)
                        print(f"{target}: cleared {', '.join(answer['cleared']) or 'nothing'}")
                return 0
            request: dict[str, Any] = {"kind": args.kind, "start_s": args.start}
            if args.start != "now":
                try:
                    request["start_s"] = float(args.start)
                except ValueError:
                    raise UsageError(f"--start must be 'now' or seconds, got {args.start!r}") \
                        from None
            if args.end is not None:
                request["end_s"] = args.end
            if args.duration is not None:
                request["duration_s"] = args.duration
            if args.id is not None:
                request["id"] = args.id
            for item in args.values:
                name, sep, value = item.partition("=")
                if not sep:
                    raise UsageError(f"expected NAME=VALUE, got {item!r}; {args.kind} takes "
                                     f"{', '.join(KINDS[args.kind].params) or 'nothing'}")
                request[name] = _perturb_value(value)
            answer = client.send(args.vehicle, request)
        except PerturbationError as exc:
            print(f"ivfm: error: {exc}", file=sys.stderr)
            return 1
    print(f"accepted by vehicle {args.vehicle}: {json.dumps(answer)}")
    return 0


def ground_router_command(args: argparse.Namespace) -> int:
    from contracts.stop_request import StopRequest
    from contracts.telemetry import DEFAULT_PORT
    from contracts.zenoh_link import ZenohOptions, open_session, tls_from_args

    tls = tls_from_args(args)
    default = f"{'tls' if tls else 'tcp'}/0.0.0.0:{DEFAULT_PORT}"
    options = ZenohOptions("router", listen=args.listen or [default],
                           connect=args.connect or [], tls=tls, insecure=args.zenoh_insecure)
    session = open_session(options, exit_on_listen_failure=True)
    stop = StopRequest()
    stop.on_signals()
    print(f"ivfm ground router: listening on {', '.join(options.listen)}"
          + (f", linked to {', '.join(options.connect)}" if options.connect else ""),
          file=sys.stderr, flush=True)
    stop.wait(poll_s=0.1)
    session.close()
    return 0


def ground_certs_command(args: argparse.Namespace) -> int:
    from ground.certificates import DEFAULT_HOSTS, DEFAULT_NAMES, make_certificates

    names = tuple(args.name or DEFAULT_NAMES)
    written = make_certificates(args.out, names, tuple(args.host or DEFAULT_HOSTS))
    print(f"wrote {len(written)} files to {args.out}: the authority ca.pem and, for "
          + ", ".join(names) + ", NAME.pem and NAME-key.pem. Give each process "
          f"--zenoh-tls {args.out} --zenoh-identity NAME; keep ca-key.pem away from the "
          "vehicles.")
    return 0


def ground_tlog_command(args: argparse.Namespace) -> int:
    from ground.logger import export_tlog

    out = args.out or (args.log.with_suffix(".tlog") if args.log.is_file()
                       else args.log / "telemetry.tlog")
    count = export_tlog(args.log, out)
    print(f"wrote {count} MAVLink frames to {out}")
    return 0


def plan_command(args: argparse.Namespace) -> int:
    """Read a .plan file (every item checked first), wait for a vehicle, upload it."""
    from pymavlink import mavutil

    from ground.plan import read_plan, upload

    lists = read_plan(args.file)
    conn = mavutil.mavlink_connection(args.connect, source_system=255, source_component=190)
    try:
        print(f"ivfm: waiting for a vehicle on {args.connect}", file=sys.stderr)
        if conn.wait_heartbeat(timeout=args.timeout) is None:
            raise UsageError(f"no vehicle heard on {args.connect} within {args.timeout:g} s")
        upload(conn, lists)
    finally:
        conn.close()
    return 0
