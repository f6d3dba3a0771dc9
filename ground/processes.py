"""Run a scenario through every process: logger, simulator and autopilot (docs/architecture.md).

The ground station starts ``ivfm ground log`` (listening on a free loopback port: the
Zenoh meeting point), ``python -m sitl --hold`` and ``python -m autopilot``. When the
logger has heard both vehicle processes it delivers the scenario's perturbations as
acknowledged Zenoh requests, releases the simulator, shows progress from the
simulator's status records, and at the end stops the logger once it holds both
processes' final status (so every record published before it has arrived). The run
folder then holds the MCAP log and the processes' logs; ``ground/report.py`` computes
everything else from the log.
"""

from __future__ import annotations

import importlib
import json
import os
import select
import shutil
import signal
import socket
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
from contracts.telemetry import AUTOPILOT, SITL, logger_key, vehicle_key
from contracts.warm import WARM_FLAG
from contracts.zenoh_link import ZenohOptions, open_session
from ground import run_timeline
from ground.ground_station import GroundStation
from ground.perturb import PerturbationClient, PerturbationError
from ground.progress import ProgressLine
from ground.scenarios import Scenario

LOG_PREFIX = "telemetry"
LOGGER_NAME = "run"


class ProcessRunError(RuntimeError):
    """A process of the run failed; the message carries the tail of its log."""


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text().splitlines()[-lines:])
    except OSError:
        return "(no log)"


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


def vehicle_commands(scenario: Scenario, settings: RunSettings, sim_port: int,
                     endpoint: str, gcs_port: int = 0) -> tuple[list, list]:
    """The simulator's and the autopilot's command lines for one vehicle of a run
    (``gcs_port``: the autopilot's ground link, for a scenario's ground station)."""
    pace = ["--realtime"] if settings.realtime else ["--lockstep"]
    # "--home=": a southern or western home starts with "-", which argparse would take
    # for an option if it came as its own argument.
    # "--perturbations": the run delivers the scenario's perturbations over Zenoh.
    zenoh_args = ["--zenoh-connect", endpoint, "--perturbations",
                  "--home=" + ",".join(repr(v) for v in settings.home)]
    if settings.rt_cpus is not None:
        zenoh_args += ["--rt-cpus", ",".join(map(str, sorted(settings.rt_cpus)))]
    ref = scenario.reference
    sim = [sys.executable, "-m", "sitl", "--port", str(sim_port), *pace,
           "--rate-hz", str(settings.rate_hz), "--plant", settings.plant,
           "--airframe", settings.airframe, "--start-altitude", str(ref.altitude_m),
           "--exit-on-disconnect", "--vehicle", str(settings.vehicle), "--hold",
           "--sensors", settings.sensors, "--seed", str(settings.seed), *zenoh_args]
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
    for name, value in (settings.parameters or {}).items():
        autopilot += ["--param", f"{name}={value!r}"]
    return sim, autopilot


class WarmProcess:
    """A warm process (contracts/warm.py) that runs one command after another; its
    current run is used as a ``subprocess.Popen`` is (poll, wait, send_signal, kill)."""

    def __init__(self, module: str) -> None:
        self.module = module
        self.proc = subprocess.Popen([sys.executable, "-m", module, WARM_FLAG],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, text=True, bufsize=1)
        self.returncode: int | None = None

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def start(self, argv: list[str], log_path: Path,
              timeline_path: str | None = None) -> WarmProcess:
        """Begin a run of ``argv`` with its output in ``log_path`` (and its timeline marks
        in ``timeline_path``)."""
        self.returncode = None
        assert self.proc.stdin is not None
        request = {"argv": argv, "log": str(log_path)}
        if timeline_path:
            request["timeline"] = timeline_path
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        return self

    def poll(self, timeout_s: float = 0.0) -> int | None:
        """The run's exit status once it has ended (waiting up to ``timeout_s``)."""
        if self.returncode is None:
            assert self.proc.stdout is not None
            if select.select([self.proc.stdout], [], [], timeout_s)[0]:
                line = self.proc.stdout.readline()
                self.returncode = int(json.loads(line)["rc"]) if line else \
                    (self.proc.wait() or -1)
            elif not self.alive:
                self.returncode = self.proc.returncode
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll(0.5 if deadline is None else max(0.0, deadline - time.monotonic())) \
                is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(self.module, timeout or 0.0)
        return self.returncode  # type: ignore[return-value]

    def send_signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def kill(self) -> None:
        """Ends the warm process itself (a run that would not stop): it is started anew."""
        self.proc.kill()
        self.proc.wait()
        if self.returncode is None:
            self.returncode = self.proc.returncode

    def close(self) -> None:
        if self.alive:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                self.kill()


class WarmProcesses:
    """The three processes of a run (logger, simulator, autopilot), kept warm between
    runs; one that died is started again for the next run."""

    MODULES = {"logger": "ground.cli", SITL: "sitl", AUTOPILOT: "autopilot"}

    def __init__(self, start: bool = False) -> None:
        """``start``: start all three now, so they load while the caller prepares a run."""
        self._procs: dict[str, WarmProcess] = {}
        if start:
            for name in self.MODULES:
                self.get(name)

    def get(self, name: str) -> WarmProcess:
        proc = self._procs.get(name)
        if proc is None or not proc.alive:
            proc = self._procs[name] = WarmProcess(self.MODULES[name])
        return proc

    def close(self) -> None:
        for proc in self._procs.values():
            proc.close()
        self._procs.clear()


class LoggerProcess:
    """``ivfm ground log`` as a child process (or a run of a warm one), and questions to it
    over Zenoh."""

    def __init__(self, out_dir: Path, endpoint: str, log_path: Path,
                 name: str = LOGGER_NAME, extra: list[str] | None = None,
                 warm: WarmProcesses | None = None, env: dict[str, str] | None = None) -> None:
        self.name = name
        self.log_path = log_path
        argv = ["ground", "log", "--out", str(out_dir), "--name", name, "--prefix", LOG_PREFIX,
                "--zenoh-listen", endpoint, *(extra or [])]
        self._out = None
        self.proc: subprocess.Popen | WarmProcess
        if warm is not None:
            self.proc = warm.get("logger").start(argv, log_path, (env or {}).get(timeline.ENV))
        else:
            self._out = open(log_path, "w")  # noqa: SIM115 (closed in stop)
            self.proc = subprocess.Popen([sys.executable, "-m", "ground.cli", *argv],
                                         stdout=self._out, stderr=subprocess.STDOUT, env=env)

    def status(self, session: zenoh.Session) -> dict[str, Any] | None:
        for reply in session.get(logger_key(self.name, "status"), timeout=2.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def wait_listening(self, session: zenoh.Session, timeout_s: float) -> None:
        """Until ``session`` (connecting to the logger's endpoint and nothing else) has
        reached the logger."""
        deadline = time.monotonic() + timeout_s
        while not list(session.info.peers_zid()):
            if self.proc.poll() is not None:
                raise ProcessRunError(f"the logger exited ({self.proc.returncode}):\n"
                                      f"{_tail(self.log_path)}")
            if time.monotonic() > deadline:
                raise ProcessRunError(f"the logger did not listen within {timeout_s:g} s\n"
                                      f"{_tail(self.log_path)}")
            time.sleep(0.002)

    def wait_until(self, session: zenoh.Session, heard: list[str], final: bool,
                   timeout_s: float,
                   others: dict[str, tuple[subprocess.Popen | WarmProcess, Path]] | None = None
                   ) -> dict[str, Any]:
        """Until the logger holds a status record (the final one, if asked) from each key;
        ``others``: processes (name -> process, log) whose early exit ends the wait."""
        deadline = time.monotonic() + timeout_s
        status: dict[str, Any] | None = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise ProcessRunError(f"the logger exited ({self.proc.returncode}):\n"
                                      f"{_tail(self.log_path)}")
            for name, (proc, log) in (others or {}).items():
                if proc.poll() is not None:
                    raise ProcessRunError(f"the {name} exited ({proc.returncode}) before it "
                                          f"was heard:\n{_tail(log)}")
            status = self.status(session)
            if status is not None and all(
                    key in status["heard"] and (status["heard"][key].get("final") or not final)
                    for key in heard):
                return status
            time.sleep(0.01)
        raise ProcessRunError(f"the logger did not hear {', '.join(heard)} within "
                              f"{timeout_s:g} s (last status: {status})\n{_tail(self.log_path)}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=20.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._out is not None:
            self._out.close()
        return self.proc.returncode


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
                  quiet: bool = False, warm: WarmProcesses | None = None,
                  started_s: float | None = None,
                  view: tuple[str, int] | None = None) -> dict[str, Any]:
    """Fly ``scenario`` through the processes; returns the telemetry accounting (records
    published and logged per key) and the autopilot's timing summary. ``quiet``: no
    progress on stderr; ``warm``: runs of warm processes instead of new ones; ``view``:
    (host, port) where the logger serves the flight live to Foxglove. Every
    process marks its phases into the run folder's ``timeline.json``, from ``started_s``
    (when the command started, on time.monotonic; default: now)."""
    clear_run_folder(out_dir)
    run_timeline.mark(out_dir, "command start", started_s)
    run_timeline.mark(out_dir, "run start")
    env = {**os.environ, timeline.ENV: str(run_timeline.raw_path(out_dir))}
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    sim_port = free_tcp_port()
    v = settings.vehicle
    logs = {name: out_dir / f"{name}.log" for name in ("logger", SITL, AUTOPILOT)}
    gcs_port = free_udp_port() if scenario.ground_station is not None else 0
    sim_cmd, ap_cmd = vehicle_commands(scenario, settings, sim_port, endpoint, gcs_port)
    ground_station = None
    logger = LoggerProcess(out_dir, endpoint, logs["logger"], warm=warm, env=env,
                           extra=["--view", f"{view[0]}:{view[1]}"] if view else None)
    run_timeline.mark(out_dir, "logger started")
    procs: dict[str, subprocess.Popen | WarmProcess] = {}
    outs = []
    session = None
    timeout_s = 120.0 + scenario.duration_s * (1.5 if settings.realtime else 1.0)
    try:
        # The vehicles start once the logger listens: a vehicle's session opened before
        # would wait half a second for it (warm processes: a few milliseconds).
        session = open_session(ZenohOptions(connect=[endpoint], listen=["tcp/127.0.0.1:0"],
                                            wait_on_open=False))
        run_timeline.mark(out_dir, "zenoh session open")
        logger.wait_listening(session, timeout_s=60.0)
        run_timeline.mark(out_dir, "logger listening")
        for name, cmd in ((SITL, sim_cmd), (AUTOPILOT, ap_cmd)):
            if warm is not None:  # cmd: python -m MODULE ARGS...
                procs[name] = warm.get(name).start(cmd[3:], logs[name], env[timeline.ENV])
                run_timeline.mark(out_dir, f"{name} started")
                continue
            out = open(logs[name], "w")  # noqa: SIM115 (closed below)
            outs.append(out)
            procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env)
            run_timeline.mark(out_dir, f"{name} started")
        status_keys = [vehicle_key(v, p, "status") for p in (SITL, AUTOPILOT)]
        logger.wait_until(session, status_keys, final=False, timeout_s=60.0,
                          others={name: (proc, logs[name]) for name, proc in procs.items()})
        run_timeline.mark(out_dir, "logger heard both")
        client = PerturbationClient(session=session, timeout_s=10.0)
        for entry in scenario.perturbations:
            answer = client.send(v, entry.to_request())
            if not quiet:
                print(f"  perturbation {answer.get('id')}: {entry.kind} "
                  f"[{entry.start_s:g}, {entry.end_s:g}) s acknowledged by the "
                      f"{entry.target}", file=sys.stderr, flush=True)
        run_timeline.mark(out_dir, "schedule delivered")
        client.start(v)
        run_timeline.mark(out_dir, "simulator released")
        if scenario.ground_station is not None:
            ref = scenario.reference
            ground_station = GroundStation(scenario.ground_station, gcs_port, v,
                                           (0.0, 0.0, -ref.altitude_m), ref.yaw_rad)
            ground_station.start()
        # The report's imports (matplotlib, the metrics) load while the vehicle flies.
        threading.Thread(target=importlib.import_module, args=("ground.report",),
                         daemon=True).start()
        _follow(session, procs, v, scenario.duration_s, timeout_s, logs, quiet)
        if ground_station is not None and ground_station.error is not None:
            raise ProcessRunError(f"the ground station failed: {ground_station.error}")
        run_timeline.mark(out_dir, "processes exited")
        final = logger.wait_until(session, status_keys, final=True, timeout_s=30.0)
        run_timeline.mark(out_dir, "logger heard the final status")
    except PerturbationError as exc:
        raise ProcessRunError(f"{exc}\n{_tail(logs[SITL])}") from None
    finally:
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
    if procs[AUTOPILOT].returncode != 0:
        raise ProcessRunError(f"the autopilot failed (exit {procs['autopilot'].returncode}):\n"
                              f"{_tail(logs['autopilot'])}\nsimulator log:\n"
                              f"{_tail(logs[SITL])}")
    if logger_rc != 0:
        raise ProcessRunError(f"the logger failed (exit {logger_rc}):\n{_tail(logs['logger'])}")
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
    return {"published": published, "logged": {k: logged.get(k, 0) for k in published},
            "lost": lost, "refused_by_logger": logger_status["rejected"], "timing": timing}


def _follow(session: zenoh.Session, procs: dict[str, subprocess.Popen | WarmProcess],
            vehicle: int,
            duration_s: float, timeout_s: float, logs: dict[str, Path],
            quiet: bool = False) -> None:
    """Wait for the vehicle processes, showing progress from the simulator's status (on a
    terminal: ground/progress.py)."""
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
        while any(p.poll() is None for p in procs.values()):
            if time.monotonic() > deadline:
                raise ProcessRunError(f"the run did not finish in {timeout_s:.0f} s; autopilot "
                                      f"log:\n{_tail(logs['autopilot'])}")
            if procs[AUTOPILOT].poll() not in (None, 0):
                return
            time.sleep(0.01)
    finally:
        if sub is not None:
            sub.undeclare()
        line.done()


def fly(scenario: Scenario, settings: RunSettings, out_dir: Path,
        view: tuple[str, int] | None = None):
    """Run the processes and read the run back from its log: (RunRecord, accounting)."""
    from ground.run_files import record_from_log

    accounting = run_processes(scenario, settings, out_dir, view=view)
    record = record_from_log(out_dir, settings.vehicle, scenario, settings.controller,
                             settings.plant, settings.rate_hz,
                             with_truth=settings.state_source == "estimator")
    return record, accounting
