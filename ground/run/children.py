"""The child processes of a run: the simulator, the autopilot and the logger (started
fresh, or forked by the process loader: ground/run/loader.py), the logger as a
process the run asks over Zenoh whether it has heard everything (``LoggerProcess``),
and the free loopback ports they meet on."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from contracts.process_main import ended_with_this_command
from contracts.telemetry import logger_key
from ground.run.loader import ForkedProcess, ProcessLoader, ProcessRunError, StartingDeadline

LOG_PREFIX = "telemetry"
LOGGER_NAME = "run"


PORT_SPAN = 8000  # ports claimed from, just below the kernel's ephemeral range
PORT_LEASE_S = 600.0  # a claim stands this long: a run's children bind well within it
PORTS_FOLDER = "ivfm-ports"  # in the temporary folder: one empty file per claimed port


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A loopback port of ``kind`` for a child process to bind soon: a run's simulator,
    its Zenoh endpoints, a test's ground tool. Not bind(0)'s: the kernel hands a probed
    port out again the moment the probe closes, so runs starting together (``ivfm check
    -j 2``, a campaign's workers, tests in parallel) could each be given it, and two UDP
    sockets with SO_REUSEADDR then share it (seen: two MAVSDK tests each flew the other's
    vehicle). Ports come from just below the ephemeral range instead, each claimed by a
    file in the temporary folder that every run on the machine skips for
    ``PORT_LEASE_S``, and probed free."""
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768  # Linux's default
    first = max(1024, low - PORT_SPAN)
    span = low - first
    folder = Path(tempfile.gettempdir()) / PORTS_FOLDER
    if not folder.is_dir():
        folder.mkdir(exist_ok=True)
        with contextlib.suppress(OSError):
            folder.chmod(0o1777)  # every user's runs claim here (sticky, as the folder above)
    start = (os.getpid() * 7919 + time.monotonic_ns() // 1000) % span
    for i in range(span):
        port = first + (start + i) % span
        if _claim(folder / str(port)) and _bindable(port, kind):
            return port
    raise OSError(f"no free port in [{first}, {low}) (claims in {folder})")


def free_tcp_port() -> int:
    return free_port(socket.SOCK_STREAM)


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def _claim(path: Path) -> bool:
    """Whether this process now holds the port's claim (a new file, or one run out)."""
    for _attempt in range(2):
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
            return True
        except FileExistsError:
            try:
                if time.time() - path.stat().st_mtime < PORT_LEASE_S:
                    return False
                path.unlink()  # a claim run out: taken again
            except OSError:  # gone meanwhile (try again), or another user's: skip it
                continue
        except OSError:
            return False
    return False


def _bindable(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text().splitlines()[-lines:])
    except OSError:
        return "(no log)"


class LoggerProcess:
    """``ivfm ground log`` as a child process (forked by ``loader`` if given), and
    questions to it over Zenoh."""

    def __init__(self, out_dir: Path, endpoint: str, log_path: Path,
                 name: str = LOGGER_NAME, extra: list[str] | None = None,
                 loader: ProcessLoader | None = None, env: dict[str, str] | None = None
                 ) -> None:
        self.name = name
        self.log_path = log_path
        argv = ["ground", "log", "--out", str(out_dir), "--name", name, "--prefix", LOG_PREFIX,
                "--zenoh-listen", endpoint, *(extra or [])]
        self._out = None
        self.proc: subprocess.Popen | ForkedProcess
        if loader is not None:
            self.proc = loader.start("ground.cli", argv, log_path, env)
        else:
            self._out = open(log_path, "w")  # noqa: SIM115 (closed in stop)
            self.proc = subprocess.Popen([sys.executable, "-m", "ground.cli", *argv],
                                         stdout=self._out, stderr=subprocess.STDOUT,
                                         env=ended_with_this_command(env or dict(os.environ)))

    def status(self, session: zenoh.Session) -> dict[str, Any] | None:
        for reply in session.get(logger_key(self.name, "status"), timeout=2.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def wait_listening(self, session: zenoh.Session, timeout_s: float,
                       say: Callable[[str], None] | None = None) -> None:
        """Until ``session`` (connecting to the logger's endpoint and nothing else) has
        reached the logger; ``timeout_s`` without the logger using CPU ends the wait
        (``StartingDeadline``)."""
        deadline = StartingDeadline({"logger": self.proc.pid}, timeout_s, say=say)
        while not list(session.info.peers_zid()):
            if self.proc.poll() is not None:
                raise ProcessRunError(f"the logger exited ({self.proc.returncode}):\n"
                                      f"{tail(self.log_path)}")
            if (why := deadline.expired("the logger to listen")) is not None:
                raise ProcessRunError(f"the logger did not listen {why}\n"
                                      f"{tail(self.log_path)}")
            time.sleep(0.002)

    def wait_until(self, session: zenoh.Session, heard: list[str], final: bool,
                   timeout_s: float,
                   others: dict[str, tuple[subprocess.Popen | ForkedProcess, Path]] | None = None,
                   starting: bool = False, say: Callable[[str], None] | None = None
                   ) -> dict[str, Any]:
        """Until the logger holds a status record (the final one, if asked) from each key;
        ``others``: processes (name -> process, log) whose early exit ends the wait.
        ``starting``: they are starting, and ``timeout_s`` counts from the last CPU any of
        them used (``StartingDeadline``), not from now."""
        deadline_s = time.monotonic() + timeout_s
        pids = {"logger": self.proc.pid, **{name: proc.pid
                                             for name, (proc, _) in (others or {}).items()}}
        start = StartingDeadline(pids, timeout_s, say=say) if starting else None
        status: dict[str, Any] | None = None
        why = f"within {timeout_s:g} s"
        while start is not None or time.monotonic() < deadline_s:
            if start is not None and (why := start.expired(
                    "the logger to hear " + ", ".join(heard))) is not None:
                break
            if self.proc.poll() is not None:
                raise ProcessRunError(f"the logger exited ({self.proc.returncode}):\n"
                                      f"{tail(self.log_path)}")
            for name, (proc, log) in (others or {}).items():
                if proc.poll() is not None:
                    raise ProcessRunError(f"the {name} exited ({proc.returncode}) before it "
                                          f"was heard:\n{tail(log)}")
            status = self.status(session)
            if status is not None and all(
                    key in status["heard"] and (status["heard"][key].get("final") or not final)
                    for key in heard):
                return status
            time.sleep(0.01)
        missing = [key for key in heard if status is None or key not in status["heard"]
                   or (final and not status["heard"][key].get("final"))]
        logs = "".join(f"\n{name} log:\n{tail(log, 5)}" for name, (_, log) in
                       (others or {}).items())
        raise ProcessRunError(f"the logger did not hear {'the final ' if final else ''}"
                              f"{', '.join(missing)} {why} (last status: {status})\n"
                              f"logger log:\n{tail(self.log_path)}{logs}")

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
