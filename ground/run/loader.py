"""Starting a run's processes: the process loader they are forked from (its server side
is contracts/zygote.py), how long to wait for a start, and the error a failed process
is. Standard library only: a command starts its loader before its own heavy imports
(``start_early``), so the two load side by side."""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from contracts.zygote import RUN_MODULES

# The CPU time of every forked process of this process's loaders that has ended [s]:
# not in this process's getrusage children (they are the loader's), so accounted here
# (tests/cpu_accounting.py).
FORKED_CPU_S = [0.0]


class ProcessRunError(RuntimeError):
    """A process of the run failed; the message carries the tail of its log."""


def cpu_seconds(pid: int) -> float | None:
    """A process's CPU time so far (user and system, all its threads), from /proc; None
    once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class StartingDeadline:
    """How long to wait for processes that are starting. A cold start (numba compiling the
    numerical core on the first run after a change) took over a minute beside busy
    neighbours, and a fixed minute failed such runs; a hung process uses no CPU. So the
    wait ends ``idle_s`` after the last CPU any of them used, or at ``cap_s``; every
    ``note_every_s`` it says what it waits for (through ``say``)."""

    def __init__(self, pids: dict[str, int], idle_s: float, cap_s: float = 600.0,
                 say: Callable[[str], None] | None = None, note_every_s: float = 15.0,
                 clock: Callable[[], float] = time.monotonic,
                 cpu: Callable[[int], float | None] = cpu_seconds) -> None:
        self.pids, self.idle_s, self.cap_s = pids, idle_s, cap_s
        self.say, self.note_every_s = say, note_every_s
        self._clock, self._cpu = clock, cpu
        self.started_s = self._last_progress_s = clock()
        self._next_note_s = self.started_s + note_every_s
        self._used = {name: cpu(pid) for name, pid in pids.items()}

    def expired(self, waiting_for: str) -> str | None:
        """None while the wait goes on; else why it ended."""
        now = self._clock()
        used = {name: self._cpu(pid) for name, pid in self.pids.items()}
        if any(u is not None and (self._used[name] is None or u > self._used[name])
               for name, u in used.items()):
            self._last_progress_s = now
        self._used = used
        waited_s = now - self.started_s
        if now - self._last_progress_s > self.idle_s:
            return (f"after {waited_s:.0f} s: no process of the run used any CPU for "
                    f"{self.idle_s:g} s")
        if waited_s > self.cap_s:
            return f"after {waited_s:.0f} s (the longest a start may take)"
        if self.say is not None and now >= self._next_note_s:
            self._next_note_s = now + self.note_every_s
            cpu = ", ".join(f"the {name} {u:.1f} s" for name, u in used.items()
                            if u is not None)
            self.say(f"still waiting for {waiting_for} ({waited_s:.0f} s; CPU used so far: "
                     f"{cpu}; a first run after a change compiles for a while)")
        return None


class ForkedProcess:
    """A process forked by the process loader (``ProcessLoader``), used as a
    ``subprocess.Popen`` is (pid, returncode, poll, wait, send_signal, terminate, kill)."""

    def __init__(self, loader: ProcessLoader, request_id: int, pid: int) -> None:
        self._loader, self._id = loader, request_id
        self.pid = pid
        self.returncode: int | None = None

    def poll(self, timeout_s: float = 0.0) -> int | None:
        """The exit status once the process has ended (waiting up to ``timeout_s``)."""
        if self.returncode is None:
            self.returncode = self._loader.exit_status(self._id, self.pid, timeout_s)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll(0.5 if deadline is None else max(0.0, deadline - time.monotonic())) \
                is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(f"process {self.pid}", timeout or 0.0)
        return self.returncode  # type: ignore[return-value]

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ProcessLoader:
    """The process loader (contracts/zygote.py) as seen from the run: started at once, so
    it loads while the command prepares; ``start`` forks a run's process from it.
    Without a loader (``ivfm check --cold``), the same processes start fresh."""

    def __init__(self, modules: tuple[str, ...] = RUN_MODULES) -> None:
        self.modules = modules
        self._env = dict(os.environ)  # the loader's, and its children's unless a start says
        self._proc = subprocess.Popen([sys.executable, "-m", "contracts.zygote", *modules],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=subprocess.DEVNULL, env=self._env)
        self._next_id = 0
        self._lock = threading.Lock()  # a check's jobs start and poll from their threads
        self._pending = b""
        self._answers: dict[int, dict[str, Any]] = {}
        self._ended: dict[int, int] = {}
        self.started: list[tuple[str, int]] = []  # (module, pid) of each process started

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def start(self, module: str, argv: list[str], log_path: Path,
              env: dict[str, str] | None = None, idle_s: float = 60.0,
              say: Callable[[str], None] | None = None) -> ForkedProcess:
        """Fork ``python -m module argv`` with its output in ``log_path`` and ``env`` (what
        differs from the environment the loader started with is sent). The first start
        waits for the loader to load; ``idle_s`` without it using CPU ends the wait."""
        changed = {k: v for k, v in (env or {}).items() if self._env.get(k) != v}
        with self._lock:
            self._next_id += 1
            rid = self._next_id
            request = {"id": rid, "module": module, "argv": argv, "log": str(log_path),
                       "env": changed, "cwd": os.getcwd()}
            assert self._proc.stdin is not None
            try:
                self._proc.stdin.write((json.dumps(request) + "\n").encode())
                self._proc.stdin.flush()
            except BrokenPipeError:
                raise ProcessRunError(f"the process loader is gone (exit "
                                      f"{self._proc.poll()})") from None
        deadline = StartingDeadline({"process loader": self.pid}, idle_s, say=say)
        while rid not in self._answers:
            if not self._read(0.05):
                if not self.alive:
                    raise ProcessRunError(f"the process loader exited ({self._proc.returncode})"
                                          f" before it started {module}")
                if (why := deadline.expired(f"the process loader to start {module}")):
                    raise ProcessRunError(f"the process loader did not start {module} {why}")
        answer = self._answers.pop(rid)
        if "pid" not in answer:
            raise ProcessRunError(f"the process loader refused to start {module}: "
                                  f"{answer.get('error')}")
        self.started.append((module, int(answer["pid"])))
        return ForkedProcess(self, rid, int(answer["pid"]))

    def exit_status(self, rid: int, pid: int, timeout_s: float) -> int | None:
        """Request ``rid``'s exit status, once the loader has said it (waiting up to
        ``timeout_s``). A loader gone before saying it: the status is -1 once the
        process is gone too."""
        deadline = time.monotonic() + timeout_s
        while rid not in self._ended:
            if not self._read(max(0.0, deadline - time.monotonic())):
                if not self.alive and not _exists(pid):
                    return -1
                if time.monotonic() >= deadline:
                    return None
        return self._ended[rid]

    def _read(self, timeout_s: float) -> bool:
        """Take in what the loader has said (waiting up to ``timeout_s`` for it); whether
        anything came."""
        assert self._proc.stdout is not None
        fd = self._proc.stdout.fileno()
        if not select.select([fd], [], [], timeout_s)[0]:
            return False
        with self._lock:
            if not select.select([fd], [], [], 0.0)[0]:
                return True  # another thread took it in
            chunk = os.read(fd, 65536)
            if not chunk:
                time.sleep(min(timeout_s, 0.01))  # the loader is gone: nothing more comes
                return False
            *lines, self._pending = (self._pending + chunk).split(b"\n")
            for line in lines:
                answer = json.loads(line)
                if "pid" in answer or "error" in answer:  # a start's answer
                    self._answers[answer["id"]] = answer
                else:  # an end
                    self._ended[answer["id"]] = int(answer["rc"])
                    FORKED_CPU_S[0] += float(answer.get("cpu_s", 0.0))
        return True

    def discard(self) -> None:
        """Never used: it ends now, loaded or not."""
        self._proc.kill()
        self._proc.wait()

    def close(self) -> None:
        """No more processes: the loader exits once those it started have."""
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            with contextlib.suppress(BrokenPipeError):
                self._proc.stdin.close()
        try:
            self._proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_EARLY: list[ProcessLoader] = []


def start_early(modules: tuple[str, ...] = RUN_MODULES) -> None:
    """Start this command's process loader now, before the command's own imports: it
    loads on the other CPU while they load here. ``take_loader`` hands it to the run."""
    if not _EARLY:
        _EARLY.append(ProcessLoader(modules))


def take_loader() -> ProcessLoader:
    """The loader ``start_early`` started (once), else a new one; the caller closes it."""
    return _EARLY.pop() if _EARLY else ProcessLoader()


def discard_early() -> None:
    """A loader started early and never taken (the command ended before flying) ends."""
    while _EARLY:
        _EARLY.pop().discard()
