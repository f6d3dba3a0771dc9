"""Kill matrix: each process of a real-time flight (logger, Zenoh router, simulator,
autopilot) killed with SIGKILL, or stopped for 2 s with SIGSTOP and continued, at each of
six stages: start-up, armed on the ground, hovering in flight, mid-mission, during a wind
perturbation, during log rotation.

For every cell it checks, as a user would from the processes' own words and files:
* the other processes are still running 3 s later;
* they said what happened (the documented message of each loss, below);
* with a ground tool on the link (armed on the ground, mid-mission), the vehicle did what
  the docs say: the simulator's loss is the link-loss failsafe (LAND in the air, disarmed
  on the ground); a logger's or router's loss changes nothing (still armed, still flying
  the mission);
* a killed process, started again, rejoins (the autopilot reconnects to a new simulator,
  the simulator takes a new autopilot, a new logger hears both vehicle processes, the
  logger hears records again through a new router);
* every log file the logger wrote reads back (a killed logger's open file is salvaged),
  with records up to within a second of the kill.

    python tests/stress/kill_matrix.py            # 48 cells, about 20 minutes
    python tests/stress/kill_matrix.py --only router --markdown docs-table.md

The router's cells run with the vehicles and the logger as Zenoh clients of a router (all
their traffic through it, as across machines); the others with the vehicles connected to
the logger. Loopback only; prints a
table (Markdown) and exits 1 if any cell failed.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pymavlink import mavutil  # noqa: E402

from contracts.mavlink import mavlink  # noqa: E402
from contracts.modes import FlightMode, mode_from_px4  # noqa: E402
from contracts.telemetry import AUTOPILOT, SITL, vehicle_key  # noqa: E402
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402
from ground.record.run_files import iter_messages  # noqa: E402
from ground.run.children import LoggerProcess, free_tcp_port  # noqa: E402
from ground.telemetry.mcap_file import salvage  # noqa: E402
from ground.uplink.perturb import PerturbationClient  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PLAN = ROOT / "ground" / "scenario" / "shipped" / "six-waypoints.plan"
PROCESSES = ("logger", "router", "sitl", "autopilot")
STAGES = ("start-up", "armed on the ground", "in flight", "mid-mission",
          "during a perturbation", "during log rotation")
GROUND_TOOL_STAGES = ("armed on the ground", "mid-mission")
SIGNALS = ("KILL", "STOP 2 s")
# What the others say when a process goes (KILL) or stalls (STOP): (whose log, text).
SAYS = {
    ("sitl", "KILL"): ("autopilot", "simulator link lost"),
    ("sitl", "STOP 2 s"): ("autopilot", "no samples from the simulator"),
    ("autopilot", "KILL"): ("sitl", "motors stopped"),
    ("autopilot", "STOP 2 s"): ("sitl", "motors stopped"),
    ("router", "KILL"): ("logger", "no records for"),
    ("router", "STOP 2 s"): ("logger", "no records for"),
}
# A killed process started again: (whose log, text, how many times it must show by then).
REJOINS = {"sitl": ("autopilot", "connected to the simulator", 2),
           "autopilot": ("sitl", "autopilot connected", 2),
           "router": ("logger", "records again", 1)}


class GroundTool:
    """A pymavlink ground tool on the autopilot's ground link: a heartbeat a second, an
    arm command until armed when asked, and what the vehicle shows (mode and armed from
    its HEARTBEAT, its STATUSTEXT)."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=190)
        self.mode: FlightMode | None = None
        self.armed = False
        self.texts: list[str] = []
        self.want_armed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_beat = next_arm = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                next_beat = now + 1.0
                self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS,
                                             mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink.MAV_STATE_ACTIVE)
            if self.want_armed and not self.armed and now >= next_arm:
                next_arm = now + 1.0
                self.conn.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                                0, 1, 0, 0, 0, 0, 0, 0)
            for _ in range(200):
                msg = self.conn.recv_match(blocking=False)
                if msg is None:
                    break
                if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.mode = mode_from_px4(msg.custom_mode)
                    self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                elif msg.get_type() == "STATUSTEXT":
                    self.texts.append(msg.text)
            self._stop.wait(0.01)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


@dataclass
class Run:
    out: Path
    stage: str
    via_router: bool = False
    endpoint: str = field(default_factory=lambda: f"tcp/127.0.0.1:{free_tcp_port()}")
    sim_port: int = field(default_factory=free_tcp_port)
    gcs_port: int = field(default_factory=free_tcp_port)
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    loggers: list[LoggerProcess] = field(default_factory=list)
    starts: dict[str, int] = field(default_factory=dict)

    def zenoh(self) -> list[str]:
        """How a process joins: a client of the router, or a peer of the logger."""
        return (["--zenoh-mode", "client"] if self.via_router else []) + \
            ["--zenoh-connect", self.endpoint]

    def session(self):
        return open_session(ZenohOptions("client" if self.via_router else "peer",
                                         connect=[self.endpoint]))

    def wait_for_logger(self, timeout_s: float = 30.0) -> None:
        """Until the newest logger answers (through the router) or listens."""
        session = self.session()
        try:
            if not self.via_router:
                self.loggers[-1].wait_listening(session, timeout_s)
                return
            deadline = time.monotonic() + timeout_s
            while self.loggers[-1].status(session) is None:
                if time.monotonic() > deadline:
                    raise RuntimeError("the logger did not answer through the router")
        finally:
            session.close()

    @property
    def order(self) -> tuple[str, ...]:
        """Start-up order: the router (when there is one), the logger, the vehicle."""
        return ("router", "logger", "sitl", "autopilot") if self.via_router \
            else ("logger", "sitl", "autopilot")

    def log(self, name: str) -> str:
        return "".join(p.read_text() for p in sorted(self.out.glob(f"{name}-*.txt")))

    def start(self, name: str) -> None:
        n = self.starts.get(name, 0)
        self.starts[name] = n + 1
        if name == "logger":
            extra = self.zenoh() if self.via_router else []
            if self.stage == "during log rotation":
                extra += ["--rotate-chunks", "16", "--flush-s", "0.05"]
            logger = LoggerProcess(self.out / f"log-{n}",
                                   "none" if self.via_router else self.endpoint,
                                   self.out / f"logger-{n}.txt", extra=extra)
            self.loggers.append(logger)
            self.procs[name] = logger.proc
            return
        zenoh = [*self.zenoh(), "--perturbations"]
        on_ground = self.stage in GROUND_TOOL_STAGES
        if name == "router":
            cmd = [sys.executable, "-m", "ground.cli", "ground", "router",
                   "--listen", self.endpoint]
        elif name == "sitl":
            cmd = [sys.executable, "-m", "sitl", "--port", str(self.sim_port), "--realtime",
                   "--start-altitude", "0.0" if on_ground else "1.0", *zenoh]
        else:
            flies = (["--reference", "attitude-sine", "--arm-in-reference"] if not on_ground
                     else ["--mission", str(PLAN), "--start-mission"]
                     if self.stage == "mid-mission" else [])
            cmd = [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{self.sim_port}",
                   "--realtime", *flies, "--gcs-bind", str(self.gcs_port), "--api", "none",
                   "--api-bind", "0", *zenoh]
        log = open(self.out / f"{name}-{n}.txt", "w")  # noqa: SIM115 (lives with it)
        self.procs[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)

    def wait_for(self, name: str, text: str, timeout_s: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if text in self.log(name):
                return True
            time.sleep(0.05)
        return False

    def stop_all(self) -> None:
        for name in ("autopilot", "sitl"):
            proc = self.procs.get(name)
            if proc is not None and proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for logger in self.loggers:
            if logger.proc.poll() is None:
                logger.stop()
        router = self.procs.get("router")
        if router is not None and router.poll() is None:
            router.terminate()
            router.wait(10)


def read_logs(out: Path) -> tuple[int, float]:
    """Salvage what a killed logger left open; (records read, wall time of the first
    logger's last record [s since the epoch])."""
    for active in out.glob("log-*/*.active"):
        salvage(active, log=lambda _text: None)
    records, first_last_ns = 0, 0
    for folder in sorted(out.glob("log-*")):
        for _topic, message, _data in iter_messages(folder):
            records += 1
            if folder.name == "log-0":
                first_last_ns = max(first_last_ns, message.log_time)
    return records, first_last_ns / 1e9


def wait_until(condition, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def get_going(run: Run, tool: GroundTool | None) -> str | None:
    """Bring the run to its stage; None, or what never happened."""
    if run.stage == "armed on the ground":
        tool.want_armed = True
        if not wait_until(lambda: tool.armed, 60.0):
            return "the vehicle never armed"
        time.sleep(2.0)
        return None
    flying = "flying the mission" if run.stage == "mid-mission" \
        else "flying the attitude-sine reference"
    if not run.wait_for("autopilot", flying):
        return "the flight never started"
    if run.stage == "mid-mission":  # climbed and on its way to the first waypoints
        time.sleep(12.0)
        return None if tool.mode == FlightMode.MISSION else f"in {tool.mode}, not MISSION"
    time.sleep(3.0)
    if run.stage == "during a perturbation":
        s = run.session()
        PerturbationClient(session=s, timeout_s=10.0).perturb(
            1, "wind", duration_s=10.0, ned_mps=[2.0, 0.0, 0.0])
        time.sleep(1.0)
        s.close()
    elif run.stage == "during log rotation":  # a file every 16 chunks of 0.05 s
        folder = run.out / "log-0"
        if not wait_until(lambda: len(list(folder.glob("*.mcap"))) >= 2, 20.0):
            return "the logger did not rotate"
    return None


def cell(process: str, stage: str, sig: str, tmp: Path) -> list[str]:
    """One cell; the list of what failed (empty: passed)."""
    out = tmp / f"{process}-{stage.replace(' ', '-')}-{sig.split()[0]}"
    out.mkdir()
    run = Run(out, stage, via_router=process == "router")
    tool = GroundTool(run.gcs_port) if stage in GROUND_TOOL_STAGES else None
    failed: list[str] = []
    signalled_s = 0.0
    try:
        for name in run.order:
            run.start(name)
            if name == process and stage == "start-up":
                time.sleep(0.5)
                break
            if name == "logger":
                run.wait_for_logger()
        if stage != "start-up":
            missing = get_going(run, tool)
            if missing:
                return [missing]
        before = (tool.mode, tool.armed) if tool else None
        target = run.procs[process]
        signalled_s = time.time()
        if sig == "KILL":
            target.kill()
            target.wait()
        else:
            target.send_signal(signal.SIGSTOP)
            time.sleep(2.0)
            target.send_signal(signal.SIGCONT)
        time.sleep(3.0)
        for name in run.order:
            if name in run.procs and name != process and run.procs[name].poll() is not None:
                failed.append(f"{name} exited ({run.procs[name].returncode})")
        if sig != "KILL" and target.poll() is not None:
            failed.append(f"{process} did not survive SIGSTOP/SIGCONT")
        says = SAYS.get((process, sig))
        if says and stage != "start-up" and says[1] not in run.log(says[0]):
            failed.append(f"{says[0]} did not say '{says[1]}'")
        if tool is not None:  # what the ground tool sees the vehicle do
            now = (tool.mode, tool.armed)
            if process in ("logger", "router") and now != before:
                failed.append(f"the vehicle went from {before} to {now}")
            if process == "sitl" and sig == "KILL":  # the link-loss failsafe
                if stage == "armed on the ground" and tool.armed:
                    failed.append("not disarmed on the ground")
                if stage == "mid-mission" and tool.mode != FlightMode.LAND:
                    failed.append(f"no LAND failsafe: in {tool.mode}")
        if sig == "KILL":
            run.start(process)
        if stage == "start-up":  # the rest comes up after it, and the flight must start
            for name in run.order[run.order.index(process) + 1:]:
                run.start(name)
            if not run.wait_for("autopilot", "flying the attitude-sine reference"):
                failed.append("no flight after the start-up " + sig.split()[0])
        elif sig == "KILL" and process in REJOINS:
            who, text, times = REJOINS[process]
            wait_until(lambda: run.log(who).count(text) >= times, 20.0)
            if run.log(who).count(text) < times:
                failed.append(f"a new {process} did not rejoin ({who}: '{text}' "
                              f"{run.log(who).count(text)} times, not {times})")
        if sig == "KILL" and process == "logger":
            session = run.session()
            try:
                run.loggers[-1].wait_until(
                    session, [vehicle_key(1, p, "status") for p in (SITL, AUTOPILOT)],
                    final=False, timeout_s=30.0)
            except RuntimeError as exc:
                failed.append(f"a new logger did not hear the vehicle: {exc}")
            session.close()
        time.sleep(2.0)
    finally:
        run.stop_all()
        if tool is not None:
            tool.close()
    try:
        records, last_s = read_logs(out)
        if records == 0:
            failed.append("the logs hold no record")
        if process == "logger" and sig == "KILL" and stage != "start-up" \
                and signalled_s - last_s > 1.0:
            failed.append(f"the killed logger's file ends {signalled_s - last_s:.2f} s "
                          "before the kill")
    except Exception as exc:  # noqa: BLE001 - any reader error fails the cell
        failed.append(f"a log did not read back: {exc}")
    return failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    parser.add_argument("--only", choices=PROCESSES, help="cells whose process is this")
    parser.add_argument("--stage", choices=STAGES, help="only this stage")
    args = parser.parse_args()
    rows = ["| process | signal | " + " | ".join(STAGES) + " |",
            "|---|---|" + "---|" * len(STAGES)]
    any_failed = False
    with tempfile.TemporaryDirectory() as tmp:
        for process in PROCESSES:
            if args.only and process != args.only:
                continue
            for sig in SIGNALS:
                results = []
                for stage in STAGES:
                    if args.stage and stage != args.stage:
                        continue
                    started = time.monotonic()
                    failed = cell(process, stage, sig, Path(tmp))
                    any_failed |= bool(failed)
                    results.append("pass" if not failed else "FAIL: " + "; ".join(failed))
                    print(f"{process:9s} {sig:8s} {stage:22s} {results[-1]} "
                          f"({time.monotonic() - started:.0f} s)", flush=True)
                rows.append(f"| {process} | {sig} | " + " | ".join(results) + " |")
    table = "\n".join(rows)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")
    sys.exit(1 if any_failed else 0)


if __name__ == "__main__":
    main()
