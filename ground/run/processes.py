"""Run a scenario through every process: logger, simulator and autopilot (docs/architecture.md).

The ground station starts ``ivfm ground log`` (listening on a free loopback port: the
Zenoh meeting point), ``python -m sitl --hold`` and ``python -m autopilot``. When the
logger has heard both vehicle processes it delivers the scenario's perturbations as
acknowledged Zenoh requests, releases the simulator, shows progress from the
simulator's status records, and at the end stops the logger once it holds both
processes' final status (so every record published before it has arrived). The run
folder then holds the MCAP log and the processes' logs; ``ground/report/run_report.py`` computes
everything else from the log.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import select
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from autopilot.trajectories import REFERENCE_OPTIONS
from contracts import timeline
from contracts.frames import DEFAULT_HOME, Home
from contracts.process_main import ended_with_this_command
from contracts.telemetry import AUTOPILOT, SITL, vehicle_key
from contracts.zenoh_link import ZenohOptions, open_session
from ground.record import timeline as run_timeline
from ground.run.children import LOG_PREFIX, LoggerProcess, free_tcp_port, free_udp_port, tail
from ground.run.loader import ForkedProcess, ProcessLoader, ProcessRunError
from ground.run.placement import HANDOVER_CPUS, FlightSlot
from ground.run.progress import ProgressLine
from ground.scenario.ground_station import GroundStation
from ground.scenario.scenario_file import Scenario
from ground.uplink.perturb import PerturbationClient, PerturbationError


@dataclass
class RunSettings:
    """How a scenario is flown (the scenario file's choices after command-line overrides)."""

    controller: str
    plant: str
    airframe: str
    model_path: Path | None = None
    parameters: dict[str, float] | None = None
    realtime: bool = False
    rate_hz: float = 100.0
    state_source: str = "auto"
    sensors: str = "ideal"  # the simulator's sensor profile
    seed: int = 0  # the simulator's sensors and link loss
    vehicle: int = 1
    any_airframe_model: bool = False  # fly a model identified on another airframe
    home: Home = DEFAULT_HOME  # given to both: the run's frames agree from the first sample
    rt_cpus: frozenset[int] | None = None  # both vehicle processes' CPUs (None: any)
    log_sensors: bool = False  # the simulator logs its HIL_SENSOR and HIL_GPS frames too
    spin_us: float | None = None  # real time: the autopilot's busy-wait (None: its default)


# How long the wait for a run's processes sleeps at most between its checks (its deadline,
# a failed autopilot); a process's end wakes it at once.
FOLLOW_WAIT_S = 0.25
# What a run's report imports: the metrics; with figures, matplotlib too (FIGURE_MODULES).
REPORT_MODULES = ("ground.report.run_report",)
FIGURE_MODULES = ("ground.report.figures", "ground.report.run_page")


def vehicle_commands(scenario: Scenario, settings: RunSettings, sim_port: int,
                     endpoint: str, gcs_port: int = 0,
                     handover_cpu: int | None = None,
                     ground_endpoint: str | None = None) -> tuple[list, list]:
    """The simulator's and the autopilot's command lines for one vehicle of a run
    (``gcs_port``: the autopilot's ground link, for a scenario's ground station;
    ``handover_cpu``: lockstep, both loops' CPU; ``ground_endpoint``: where the run's own
    session listens, connected to at once instead of found through the logger)."""
    pace = ["--realtime"] if settings.realtime else ["--lockstep"]
    # "--home=": a southern or western home starts with "-", which argparse would take
    # for an option if it came as its own argument.
    # "--perturbations": the run delivers the scenario's perturbations over Zenoh.
    zenoh_args = ["--zenoh-connect", endpoint,
                  *(["--zenoh-connect", ground_endpoint] if ground_endpoint else []),
                  "--perturbations",
                  "--home=" + ",".join(repr(v) for v in settings.home)]
    if settings.rt_cpus is not None:
        zenoh_args += ["--rt-cpus", ",".join(map(str, sorted(settings.rt_cpus)))]
    if handover_cpu is not None and not settings.realtime:
        zenoh_args += ["--handover-cpu", str(handover_cpu)]
    ref = scenario.reference
    sim = [sys.executable, "-m", "sitl", "--port", str(sim_port), *pace,
           "--rate-hz", str(settings.rate_hz), "--plant", settings.plant,
           "--airframe", settings.airframe, "--start-altitude", str(ref.altitude_m),
           "--exit-on-disconnect", "--vehicle", str(settings.vehicle), "--hold",
           "--sensors", settings.sensors, "--seed", str(settings.seed), *zenoh_args,
           *(["--log-sensors"] if settings.log_sensors else [])]
    if scenario.plan is not None:  # armed in AUTO.MISSION on the ground
        flies = ["--mission", str(scenario.plan), "--start-mission"]
    else:  # armed in the reference from the first sample
        flies = ["--reference", ref.kind, "--altitude", str(ref.altitude_m),
                 *(arg for name in REFERENCE_OPTIONS
                   for arg in ("--reference-option", f"{name}={getattr(ref, name)!r}")),
                 "--arm-in-reference"]
    autopilot = [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{sim_port}", *pace,
                 "--rate-hz", str(settings.rate_hz), "--state-source", settings.state_source,
                 "--controller", settings.controller, "--airframe", settings.airframe,
                 *flies, "--duration", str(scenario.duration_s),
                 "--sysid", str(settings.vehicle), "--gcs-bind", str(gcs_port), "--api", "none",
                 "--api-bind", "0", *zenoh_args]
    if settings.model_path is not None:
        autopilot += ["--model", str(settings.model_path)]
    if settings.any_airframe_model:
        autopilot.append("--any-airframe-model")
    if settings.spin_us is not None:
        autopilot += ["--spin-us", str(settings.spin_us)]
    for name, value in (settings.parameters or {}).items():
        autopilot += ["--param", f"{name}={value!r}"]
    return sim, autopilot


def clear_run_folder(out_dir: Path) -> None:
    """A run folder holds one run: remove the telemetry of a previous one."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in [*out_dir.glob(f"{LOG_PREFIX}-*.mcap"), *out_dir.glob(f"{LOG_PREFIX}-*.active"),
                run_timeline.raw_path(out_dir), out_dir / run_timeline.TIMELINE_FILE]:
        old.unlink(missing_ok=True)
    figures = out_dir / "figures"
    if figures.is_dir():
        shutil.rmtree(figures)


def run_processes(scenario: Scenario, settings: RunSettings, out_dir: Path,
                  quiet: bool = False, loader: ProcessLoader | None = None,
                  started_s: float | None = None,
                  view: tuple[str, int] | None = None,
                  report_modules: tuple[str, ...] = REPORT_MODULES,
                  flight_slot: FlightSlot | None = None) -> dict[str, Any]:
    """Fly ``scenario`` through the processes; returns the telemetry accounting (records
    published and logged per key) and the autopilot's timing summary. ``quiet``: no
    progress on stderr; ``loader``: the processes forked by it, not started anew; ``view``:
    (host, port) where the logger serves the flight live to Foxglove; ``report_modules``:
    what the command's report after the flight imports, imported while it flies. Every
    process marks its phases into the run folder's ``timeline.json``, from ``started_s``
    (when the command started, on time.monotonic; default: now). ``flight_slot``: the
    run's place in a batch's ``FlightSlots`` (its CPU, and the lock it flies under), for
    a CPU of its own otherwise."""
    clear_run_folder(out_dir)
    run_timeline.mark(out_dir, "command start", started_s)
    run_timeline.mark(out_dir, "run start")
    env = {**os.environ, timeline.ENV: str(run_timeline.raw_path(out_dir))}
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    sim_port = free_tcp_port()
    v = settings.vehicle
    logs = {name: out_dir / f"{name}.log" for name in ("logger", SITL, AUTOPILOT)}
    gcs_port = free_udp_port() if scenario.ground_station is not None else 0
    # Lockstep: both loops on one CPU, so a hand-over does not wake a thread elsewhere.
    placed = not settings.realtime and settings.rt_cpus is None
    own_cpu = placed and flight_slot is None  # taken here, given back at the run's end
    handover_cpu = (HANDOVER_CPUS.take() if own_cpu else
                    flight_slot.cpu if placed else None)
    # The run's own session listens where the vehicles connect at once: found through
    # the logger (gossip), its requests waited ~0.2 s for a route to a new vehicle.
    ground_endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    sim_cmd, ap_cmd = vehicle_commands(scenario, settings, sim_port, endpoint, gcs_port,
                                       handover_cpu, ground_endpoint)
    ground_station = None
    try:
        logger = LoggerProcess(out_dir, endpoint, logs["logger"], loader=loader, env=env,
                               extra=[*(["--view", f"{view[0]}:{view[1]}"] if view else []),
                                      *(["--off-cpu", str(handover_cpu)]
                                        if handover_cpu is not None else [])])
    except BaseException:
        if own_cpu:
            HANDOVER_CPUS.give(handover_cpu)  # the run ends here: its CPU is free again
        raise
    run_timeline.mark(out_dir, "logger started")
    procs: dict[str, subprocess.Popen | ForkedProcess] = {}
    outs = []
    session = None
    holding_slot = False
    timeout_s = 120.0 + scenario.duration_s * (1.5 if settings.realtime else 1.0)
    try:
        # The vehicles start once the logger listens: a vehicle's session opened before
        # would wait half a second for it (forked processes: a few milliseconds).
        session = open_session(ZenohOptions(connect=[endpoint], listen=[ground_endpoint],
                                            wait_on_open=False))
        run_timeline.mark(out_dir, "zenoh session open")
        logger.wait_listening(session, timeout_s=60.0, say=_say)
        run_timeline.mark(out_dir, "logger listening")
        for name, cmd in ((SITL, sim_cmd), (AUTOPILOT, ap_cmd)):
            if loader is not None:  # cmd: python -m MODULE ARGS...
                procs[name] = loader.start(cmd[2], cmd[3:], logs[name], env, say=_say)
                run_timeline.mark(out_dir, f"{name} started")
                continue
            out = open(logs[name], "w")  # noqa: SIM115 (closed below)
            outs.append(out)
            procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT,
                                           env=ended_with_this_command(env))
            run_timeline.mark(out_dir, f"{name} started")
        status_keys = [vehicle_key(v, p, "status") for p in (SITL, AUTOPILOT)]
        logger.wait_until(session, status_keys, final=False, timeout_s=60.0,
                          others={name: (proc, logs[name]) for name, proc in procs.items()},
                          starting=True, say=_say)
        run_timeline.mark(out_dir, "logger heard both")
        client = PerturbationClient(session=session, timeout_s=10.0)
        for entry in scenario.perturbations:
            answer = client.send(v, entry.to_request())
            if not quiet:
                print(f"  perturbation {answer.get('id')}: {entry.kind} "
                  f"[{entry.start_s:g}, {entry.end_s:g}) s acknowledged by the "
                      f"{entry.target}", file=sys.stderr, flush=True)
        run_timeline.mark(out_dir, "ready to fly")
        if flight_slot is not None:
            flight_slot.lock.acquire()
            holding_slot = True
        client.start(v)
        run_timeline.mark(out_dir, "simulator released")
        if scenario.ground_station is not None:
            ref = scenario.reference
            ground_station = GroundStation(scenario.ground_station, gcs_port, v,
                                           (0.0, 0.0, -ref.altitude_m), ref.yaw_rad)
            ground_station.start()
        # The report's imports (the metrics; matplotlib for figures) load while it flies.
        threading.Thread(target=_import_all, args=(report_modules,), daemon=True).start()
        _follow(session, procs, v, scenario.duration_s, timeout_s, logs, quiet)
        if holding_slot:
            flight_slot.lock.release()
            holding_slot = False
        if ground_station is not None and ground_station.error is not None:
            raise ProcessRunError(f"the ground station failed: {ground_station.error}")
        run_timeline.mark(out_dir, "processes exited")
        final = logger.wait_until(session, status_keys, final=True, timeout_s=30.0)
        run_timeline.mark(out_dir, "logger heard the final status")
    except PerturbationError as exc:
        raise ProcessRunError(f"{exc}\n{tail(logs[SITL])}") from None
    finally:
        if holding_slot:
            flight_slot.lock.release()
        if ground_station is not None:
            ground_station.stop()
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        for out in outs:
            out.close()
        if session is not None:
            session.close()
            run_timeline.mark(out_dir, "zenoh session closed")
        logger_rc = logger.stop()
        run_timeline.mark(out_dir, "logger stopped")
        if own_cpu:
            HANDOVER_CPUS.give(handover_cpu)
    if procs[AUTOPILOT].returncode != 0:
        raise ProcessRunError(f"the autopilot failed (exit {procs['autopilot'].returncode}):\n"
                              f"{tail(logs['autopilot'])}\nsimulator log:\n"
                              f"{tail(logs[SITL])}")
    if logger_rc != 0:
        raise ProcessRunError(f"the logger failed (exit {logger_rc}):\n{tail(logs['logger'])}")
    accounting = telemetry_accounting(final)
    run_timeline.mark(out_dir, "run end")
    steps = round(scenario.duration_s * settings.rate_hz)
    run_timeline.write(out_dir, sim_loop_s=(steps - 1) / settings.rate_hz)
    return accounting


def telemetry_accounting(logger_status: dict[str, Any]) -> dict[str, Any]:
    """Per key: records the processes say they published vs records the logger wrote."""
    published: dict[str, int] = {}
    timing: dict[str, Any] = {}
    for record in logger_status["heard"].values():
        published.update(record.get("published", {}))
        if record.get("timing"):
            timing = record["timing"]
    logged = logger_status["per_key"]
    lost = {k: n - logged.get(k, 0) for k, n in published.items() if n != logged.get(k, 0)}
    usage = {record["process"]: record["usage"] for record in logger_status["heard"].values()
             if "usage" in record}
    usage["logger"] = logger_status.get("usage", {})
    return {"published": published, "logged": {k: logged.get(k, 0) for k in published},
            "lost": lost, "refused_by_logger": logger_status["rejected"], "timing": timing,
            "usage": usage}


def _import_all(modules: tuple[str, ...]) -> None:
    for module in modules:
        importlib.import_module(module)


def _say(text: str) -> None:
    print(f"ivfm: {text}", file=sys.stderr, flush=True)


def _follow(session: zenoh.Session, procs: dict[str, subprocess.Popen | ForkedProcess],
            vehicle: int,
            duration_s: float, timeout_s: float, logs: dict[str, Path],
            quiet: bool = False) -> None:
    """Wait for the vehicle processes, showing progress from the simulator's status (on a
    terminal: ground/run/progress.py)."""
    line = ProgressLine("  flying", duration_s)

    def on_status(sample: zenoh.Sample) -> None:
        try:
            t = json.loads(sample.payload.to_bytes())["sim_time_us"] / 1e6
        except (ValueError, KeyError, TypeError):
            return
        line.update(t)

    sub = None if quiet else session.declare_subscriber(
        vehicle_key(vehicle, SITL, "status"), on_status)
    deadline = time.monotonic() + timeout_s
    try:
        while running := [p for p in procs.values() if p.poll() is None]:
            if time.monotonic() > deadline:
                raise ProcessRunError(f"the run did not finish in {timeout_s:.0f} s; autopilot "
                                      f"log:\n{tail(logs['autopilot'])}")
            if procs[AUTOPILOT].poll() not in (None, 0):
                return
            _wait_for_end(running[0], FOLLOW_WAIT_S)
    finally:
        if sub is not None:
            sub.undeclare()
        line.done()


def _wait_for_end(proc: subprocess.Popen | ForkedProcess, timeout_s: float) -> None:
    """Up to ``timeout_s`` for ``proc`` to end, woken by its end at once: a forked process's
    by the loader's answer, a started one's by its pidfd (``Popen.wait`` with a timeout
    polls, waking up to 500 times a second)."""
    if isinstance(proc, ForkedProcess):
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=timeout_s)
        return
    try:
        fd = os.pidfd_open(proc.pid)
    except (OSError, AttributeError):  # gone already, or no pidfd here: a short wait
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=min(timeout_s, 0.01))
        return
    try:
        select.select([fd], [], [], timeout_s)
    finally:
        os.close(fd)
    proc.poll()


def fly(scenario: Scenario, settings: RunSettings, out_dir: Path,
        view: tuple[str, int] | None = None):
    """Run the processes and read the run back from its log: (RunRecord, accounting)."""
    from ground.record.run_files import record_from_log

    accounting = run_processes(scenario, settings, out_dir, view=view)
    record = record_from_log(out_dir, settings.vehicle, scenario, settings.controller,
                             settings.plant, settings.rate_hz,
                             with_truth=settings.state_source == "estimator")
    return record, accounting
