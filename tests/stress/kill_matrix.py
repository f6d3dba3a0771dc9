"""Kill matrix: each process of a real-time flight (logger, simulator, autopilot) killed
with SIGKILL, or stopped for 2 s with SIGSTOP and continued, at each of three stages
(start-up, hovering in flight, during a wind perturbation).

For every cell it checks, as a user would from the processes' own words and files:
* the other processes are still running 3 s later;
* they said what happened (the documented message of each loss, below);
* a killed process, started again, rejoins (the autopilot reconnects to a new simulator,
  the simulator takes a new autopilot, a new logger hears both vehicle processes);
* every log file the logger wrote reads back (a killed logger's open file is salvaged),
  with records up to within a second of the kill.

    python tests/stress/kill_matrix.py            # 18 cells, about 6 minutes
    python tests/stress/kill_matrix.py --markdown docs-table.md

Loopback only; prints a table (Markdown) and exits 1 if any cell failed.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from contracts.telemetry import AUTOPILOT, SITL, vehicle_key  # noqa: E402
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402
from ground.logger import salvage  # noqa: E402
from ground.perturb import PerturbationClient  # noqa: E402
from ground.processes import LoggerProcess, free_tcp_port  # noqa: E402
from ground.run_files import iter_messages  # noqa: E402

PROCESSES = ("logger", "sitl", "autopilot")
STAGES = ("start-up", "in flight", "during a perturbation")
SIGNALS = ("KILL", "STOP 2 s")
# What the others say when a process goes (KILL) or stalls (STOP): (whose log, text).
SAYS = {
    ("sitl", "KILL"): ("autopilot", "simulator link lost"),
    ("sitl", "STOP 2 s"): ("autopilot", "no samples from the simulator"),
    ("autopilot", "KILL"): ("sitl", "motors stopped"),
    ("autopilot", "STOP 2 s"): ("sitl", "motors stopped"),
}
REJOINS = {"sitl": ("autopilot", "connected to the simulator"),
           "autopilot": ("sitl", "autopilot connected")}


@dataclass
class Run:
    out: Path
    endpoint: str = field(default_factory=lambda: f"tcp/127.0.0.1:{free_tcp_port()}")
    sim_port: int = field(default_factory=free_tcp_port)
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    loggers: list[LoggerProcess] = field(default_factory=list)
    starts: dict[str, int] = field(default_factory=dict)

    def log(self, name: str) -> str:
        return "".join(p.read_text() for p in sorted(self.out.glob(f"{name}-*.txt")))

    def start(self, name: str) -> None:
        n = self.starts.get(name, 0)
        self.starts[name] = n + 1
        if name == "logger":
            logger = LoggerProcess(self.out / f"log-{n}", self.endpoint,
                                   self.out / f"logger-{n}.txt")
            self.loggers.append(logger)
            self.procs[name] = logger.proc
            return
        zenoh = ["--zenoh-connect", self.endpoint, "--perturbations"]
        if name == "sitl":
            cmd = [sys.executable, "-m", "sitl", "--port", str(self.sim_port), "--realtime",
                   "--start-altitude", "1.0", *zenoh]
        else:
            cmd = [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{self.sim_port}",
                   "--realtime", "--reference", "attitude-sine", "--arm-in-reference",
                   "--gcs-bind", "0", "--api", "none", "--api-bind", "0", *zenoh]
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


def cell(process: str, stage: str, sig: str, tmp: Path) -> list[str]:
    """One cell; the list of what failed (empty: passed)."""
    out = tmp / f"{process}-{stage.replace(' ', '-')}-{sig.split()[0]}"
    out.mkdir()
    run = Run(out)
    failed: list[str] = []
    signalled_s = 0.0
    try:
        for name in PROCESSES:
            run.start(name)
            if name == process and stage == "start-up":
                time.sleep(0.5)
                break
            if name == "logger":
                session = open_session(ZenohOptions(connect=[run.endpoint]))
                run.loggers[0].wait_listening(session, 30.0)
        if stage != "start-up":
            if not run.wait_for("autopilot", "flying the attitude-sine reference"):
                return ["the flight never started"]
            time.sleep(3.0)
        if stage == "during a perturbation":
            s = open_session(ZenohOptions(connect=[run.endpoint]))
            PerturbationClient(session=s, timeout_s=10.0).perturb(
                1, "wind", duration_s=10.0, ned_mps=[2.0, 0.0, 0.0])
            time.sleep(1.0)
            s.close()
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
        for name in PROCESSES:
            if name in run.procs and name != process and run.procs[name].poll() is not None:
                failed.append(f"{name} exited ({run.procs[name].returncode})")
        if sig != "KILL" and target.poll() is not None:
            failed.append(f"{process} did not survive SIGSTOP/SIGCONT")
        says = SAYS.get((process, sig))
        if says and stage != "start-up" and says[1] not in run.log(says[0]):
            failed.append(f"{says[0]} did not say '{says[1]}'")
        if sig == "KILL":
            run.start(process)
        if stage == "start-up":  # the rest comes up after it, and the flight must start
            for name in PROCESSES[PROCESSES.index(process) + 1:]:
                run.start(name)
            if not run.wait_for("autopilot", "flying the attitude-sine reference"):
                failed.append("no flight after the start-up " + sig.split()[0])
        elif sig == "KILL" and process in REJOINS:
            who, text = REJOINS[process]
            deadline = time.monotonic() + 20.0
            while run.log(who).count(text) < 2 and time.monotonic() < deadline:
                time.sleep(0.1)
            if run.log(who).count(text) < 2:
                failed.append(f"a new {process} did not rejoin ({who}: '{text}' once)")
        if sig == "KILL" and process == "logger":
            session = open_session(ZenohOptions(connect=[run.endpoint]))
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
    parser.add_argument("--only", help="cells whose process is this")
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
