"""The process loader: one process loads what a run's processes load, once, and forks
each of them (``ivfm run``, ``ivfm check``, rehearsals, the test harness).

Every process of a run (the logger, the simulator, the autopilot) spends most of its
start-up loading the same things: numpy, numba and the compiled code in its cache,
pymavlink's dialect, Zenoh. Started as ``python -m contracts.zygote MODULE ...`` (for a
run: ``ground.cli sitl autopilot``), the loader imports each module's ``__main__`` and
calls its ``preload()``, once, then forks a child per request. The child then runs the
module as ``python -m MODULE ARGV`` would (``runpy``): its ``sys.argv``, its
environment and working folder, standard output and error appended to its log, standard input
from /dev/null, the default signal handlers. It never returns into the loader, so
nothing of one run reaches another: what is shared is what a fresh process would load
again. A module the loader could not import is run by ``exec`` in the child instead,
so its error lands in the run's log as a fresh process's would.

Requests come on standard input, one JSON line each::

    {"id": 1, "module": "sitl", "argv": ["--port", "4561"], "log": "/run/sitl.log",
     "env": {"IVFM_TIMELINE": "/run/timeline.raw"}, "cwd": "/home/me"}

(``env``: variables set over the loader's own; ``env`` and ``cwd`` are optional). The
loader answers on standard output, one JSON line each::

    {"id": 1, "pid": 4321}                  the child started
    {"id": 1, "rc": 0, "cpu_s": 1.25}       it ended (rc negative: the signal that ended
                                            it; cpu_s: its CPU time, user and system)
    {"id": 1, "rc": 2, "error": "..."}      a bad request: no child, nothing changed

End of input: no more children; the loader exits once its children have. The command
whose input it was has ended by then: a child still running is a run left behind by a
command that was killed or crashed, and is ended (SIGTERM, which each process takes as a
stop: the logger closes its file; SIGKILL after ``STOP_GRACE_S``), so that nothing of a run
outlives its command. The loader ignores SIGINT (a Ctrl-C in the terminal is for the
run's processes and the command); its children do not.

Forking is safe here because the loader runs no thread of its own: the idle worker
threads of the BLAS libraries numpy and scipy load are stopped and restarted across a
fork by the libraries' own fork handlers.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import json
import os
import runpy
import selectors
import signal
import sys
import time
import traceback
from typing import Any, NoReturn

# The modules a run's processes are started from, in the order a run starts them.
RUN_MODULES = ("ground.cli", "sitl", "autopilot")
# After the end of input, how long the children still running have to end on SIGTERM
# before they are killed (within the 10 s the client waits for the loader to exit).
STOP_GRACE_S = 5.0


def parse_request(line: str, modules: frozenset[str]) -> dict[str, Any]:
    """One request line, checked; ValueError says what is wrong."""
    try:
        request: Any = json.loads(line)
    except ValueError as exc:
        raise ValueError(f"a request is one JSON object per line: {exc}") from None
    if not isinstance(request, dict) or not {"id", "module", "argv", "log"} <= set(request) \
            or not set(request) <= {"id", "module", "argv", "log", "env", "cwd"}:
        raise ValueError("a request has the fields id, module, argv and log (and env, cwd)")
    if not isinstance(request["id"], int) or isinstance(request["id"], bool):
        raise ValueError("id must be an integer")
    if request["module"] not in modules:
        raise ValueError(f"module must be one of {', '.join(sorted(modules))}")
    argv = request["argv"]
    if not isinstance(argv, list) or not all(isinstance(a, str) for a in argv):
        raise ValueError("argv must be a list of strings")
    if not isinstance(request["log"], str) or not request["log"]:
        raise ValueError("log must be a file path")
    env = request.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(k, str) and isinstance(v, str) and k
                                            and "=" not in k for k, v in env.items()):
        raise ValueError("env must map variable names to strings")
    cwd = request.get("cwd")
    if cwd is not None and (not isinstance(cwd, str) or not cwd):
        raise ValueError("cwd must be a folder path")
    return request


def load(modules: list[str]) -> dict[str, bool]:
    """Import each module's ``__main__`` and call its ``preload()``: module -> whether it
    imported (a failed preload is left for the run to meet, as a fresh process would).

    The garbage collector is off meanwhile, and what is loaded is frozen without a last
    collection (the children's collections skip it): some 140,000 objects come in, and
    the collections their allocations set off, with the last one, were 0.13 s of the
    load's 0.79 s (median of eight alternated loads, 0.66 s without; the run waits for
    the loader). What that leaves frozen is about 1,300 unreachable objects."""
    loaded = {}
    gc.disable()
    try:
        for module in modules:
            try:
                entry = importlib.import_module(f"{module}.__main__")
            except Exception:  # noqa: BLE001 (the child runs it fresh and meets the error)
                loaded[module] = False
                continue
            loaded[module] = True
            with contextlib.suppress(Exception):
                preload = getattr(entry, "preload", None)
                if preload is not None:
                    preload()
        gc.freeze()  # what is loaded stays put: the children's collections skip it
    finally:
        gc.enable()
    return loaded


def serve(modules: list[str]) -> int:
    """Load ``modules``, then fork a child per request until the end of input and the
    end of every child (module docstring)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    quiet = os.open(os.devnull, os.O_RDWR)
    os.dup2(quiet, 1)  # nothing but answers goes into the answers
    os.close(quiet)
    loaded = load(modules)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # the wake-up byte is what counts
    children: dict[int, int] = {}  # pid -> request id
    selector = selectors.DefaultSelector()
    selector.register(0, selectors.EVENT_READ, "requests")
    selector.register(wake_r, selectors.EVENT_READ, "children")
    pending = b""
    reading = True
    kill_at: float | None = None  # after the end of input: when what is left is killed
    while reading or children:
        timeout = None if kill_at is None else max(0.0, kill_at - time.monotonic())
        for key, _ in selector.select(timeout):
            if key.data == "children":
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
                _reap(children, answers)
                continue
            chunk = os.read(0, 65536)
            if not chunk:
                reading = False
                selector.unregister(0)
                _reap(children, answers)
                if children:  # the command is gone (killed, crashed): so is its run
                    _signal_all(children, signal.SIGTERM)
                    kill_at = time.monotonic() + STOP_GRACE_S
                continue
            *lines, pending = (pending + chunk).split(b"\n")
            for line in lines:
                if line.strip():
                    _answer_request(line.decode(errors="replace"), loaded, children,
                                    answers, (wake_r, wake_w))
        _reap(children, answers)
        if kill_at is not None and children and time.monotonic() >= kill_at:
            _signal_all(children, signal.SIGKILL)
            kill_at = None
    return 0


def _signal_all(children: dict[int, int], sig: int) -> None:
    for pid in children:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)


def _answer_request(line: str, loaded: dict[str, bool], children: dict[int, int],
                    answers: Any, wake: tuple[int, int]) -> None:
    try:
        request = parse_request(line, frozenset(loaded))
        log = os.open(request["log"], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    except (ValueError, OSError) as exc:
        rid = _id_of(line)
        answers.write(json.dumps({"id": rid, "rc": 2, "error": str(exc)}) + "\n")
        return
    for stream in (answers, sys.stdout, sys.stderr):  # nothing buffered is written twice
        stream.flush()
    pid = os.fork()
    if pid == 0:
        _become(request, log, loaded[request["module"]], answers.fileno(), wake)
    os.close(log)
    children[pid] = request["id"]
    answers.write(json.dumps({"id": request["id"], "pid": pid}) + "\n")


def _id_of(line: str) -> Any:
    with contextlib.suppress(ValueError, AttributeError):
        rid = json.loads(line).get("id")
        if isinstance(rid, int):
            return rid
    return None


def _reap(children: dict[int, int], answers: Any) -> None:
    while children:
        try:
            pid, status, usage = os.wait4(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        rid = children.pop(pid, None)
        if rid is not None:
            answers.write(json.dumps({"id": rid, "rc": os.waitstatus_to_exitcode(status),
                                      "cpu_s": round(usage.ru_utime + usage.ru_stime, 4)})
                          + "\n")


def _become(request: dict[str, Any], log: int, imported: bool, answers_fd: int,
            wake: tuple[int, int]) -> NoReturn:
    """In the child: become ``python -m MODULE ARGV`` with its output in ``log``."""
    try:
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for fd in (answers_fd, *wake):
            os.close(fd)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
        if request.get("cwd"):
            os.chdir(request["cwd"])
        os.environ.update(request.get("env", {}))
        module, argv = request["module"], request["argv"]
        if not imported:
            os.execv(sys.executable, [sys.executable, "-m", module, *argv])
        sys.argv = [module, *argv]  # runpy sets argv[0] to the file, as python -m does
        sys.modules.pop(f"{module}.__main__", None)  # run afresh as __main__, not reused
        runpy.run_module(module, run_name="__main__", alter_sys=True)
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if not isinstance(exc.code, int | None):
            print(exc.code, file=sys.stderr)
    except KeyboardInterrupt:
        code = 130
    except BaseException:  # noqa: BLE001 (a crash, reported as a fresh process's would be)
        traceback.print_exc()
        code = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(serve(sys.argv[1:]))
