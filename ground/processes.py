"""Run a scenario through the simulator and autopilot processes (SPEC section 7).

The ground side starts ``python -m sitl`` and ``python -m autopilot`` on a free port,
hands both the scenario's schedule (plant changes to the simulator, reference kicks to
the autopilot), waits, and reads back the autopilot's per-step record.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from contracts.schedule import windows_to_json
from ground.inprocess import RunRecord
from ground.scenarios import Scenario


class ProcessRunError(RuntimeError):
    """A process of the run failed; the message carries the tail of its log."""


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text().splitlines()[-lines:])
    except OSError:
        return "(no log)"


def run_processes(
    scenario: Scenario,
    controller: str,
    plant_fidelity: str,
    airframe_name: str,
    out_dir: Path,
    model_path: Path | None = None,
    parameters: dict[str, float] | None = None,
    realtime: bool = False,
    rate_hz: float = 100.0,
    state_source: str = "odometry",
) -> tuple[RunRecord, dict]:
    """Fly ``scenario`` through the two processes; returns the record and the timing."""
    out_dir.mkdir(parents=True, exist_ok=True)
    port = free_tcp_port()
    pace = ["--realtime"] if realtime else ["--lockstep"]
    with tempfile.TemporaryDirectory(prefix="ivfm-run-") as tmp:
        schedule = Path(tmp) / "schedule.json"
        schedule.write_text(windows_to_json(scenario.windows))
        record_path = Path(tmp) / "record.npz"
        sim_log, ap_log = out_dir / "sitl.log", out_dir / "autopilot.log"
        sim_cmd = [sys.executable, "-m", "sitl", "--port", str(port), *pace,
                   "--rate-hz", str(rate_hz), "--plant", plant_fidelity,
                   "--airframe", airframe_name,
                   "--start-altitude", str(scenario.reference.altitude_m),
                   "--schedule", str(schedule), "--exit-on-disconnect"]
        ap_cmd = [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{port}", *pace,
                  "--rate-hz", str(rate_hz), "--state-source", state_source,
                  "--controller", controller, "--airframe", airframe_name,
                  "--reference", scenario.reference.kind,
                  "--altitude", str(scenario.reference.altitude_m),
                  "--schedule", str(schedule), "--arm-in-reference",
                  "--duration", str(scenario.duration_s), "--record", str(record_path),
                  "--gcs-bind", "0", "--api", "none", "--api-bind", "0"]
        if model_path is not None:
            ap_cmd += ["--model", str(model_path)]
        for name, value in (parameters or {}).items():
            ap_cmd += ["--param", f"{name}={value!r}"]
        timeout_s = 120.0 + (scenario.duration_s * (1.5 if realtime else 1.0))
        with open(sim_log, "w") as sim_out, open(ap_log, "w") as ap_out:
            sim = subprocess.Popen(sim_cmd, stdout=sim_out, stderr=subprocess.STDOUT)
            autopilot = subprocess.Popen(ap_cmd, stdout=ap_out, stderr=subprocess.STDOUT)
            try:
                _follow(autopilot, ap_log, timeout_s)
                sim.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                raise ProcessRunError(f"the run did not finish in {timeout_s:.0f} s; "
                                      f"autopilot log:\n{_tail(ap_log)}") from None
            finally:
                for proc in (autopilot, sim):
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait()
        if autopilot.returncode != 0 or not record_path.exists():
            raise ProcessRunError(f"the autopilot failed (exit {autopilot.returncode}):\n"
                                  f"{_tail(ap_log)}\nsimulator log:\n{_tail(sim_log)}")
        return _record(record_path, scenario, controller, plant_fidelity, rate_hz)


def _follow(proc: subprocess.Popen, log: Path, timeout_s: float) -> None:
    """Wait for the process, echoing its progress lines."""
    deadline = time.monotonic() + timeout_s
    seen = 0
    while proc.poll() is None:
        if time.monotonic() > deadline:
            raise subprocess.TimeoutExpired(proc.args, timeout_s)
        time.sleep(0.2)
        lines = log.read_text().splitlines()
        for line in lines[seen:]:
            if "%" in line and "sim)" in line:
                print(f"  {line}", file=sys.stderr, flush=True)
        seen = len(lines)


def _record(path: Path, scenario: Scenario, controller: str, plant: str,
            rate_hz: float) -> tuple[RunRecord, dict]:
    d = np.load(path)
    n = len(d["time_s"])
    measurement = d["measurement"]
    diverged = bool(n < round(scenario.duration_s * rate_hz) or not np.all(
        np.isfinite(measurement)) or np.max(np.abs(measurement[:, 0:3])) > 1e3)
    record = RunRecord(
        scenario=scenario.name, controller=controller, plant=plant, period_s=1.0 / rate_hz,
        time_s=d["time_s"], measurement=measurement, reference=d["reference"], kick=d["kick"],
        motor_commands=d["motor_commands"], channel_telemetry=d["channel_telemetry"],
        theta_g=d["theta_g"], theta_f=[d[f"theta_f_{i}"] for i in range(3)],
        wall_time_s=float(d["loop_wall_s"]) or math.nan, diverged=diverged)
    return record, json.loads(str(d["timing"]))
