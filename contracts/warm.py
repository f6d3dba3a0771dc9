"""Warm processes: one process runs its command again and again (``ivfm check``).

A process started with ``--warm`` as its only argument (``python -m sitl --warm``,
``python -m autopilot --warm``, ``python -m ground.cli --warm``) imports everything once,
then reads run requests from its standard input, one JSON line each:

    {"argv": ["--port", "4561", ...], "log": "/path/to/run/sitl.log"}

(and optionally ``"timeline": FILE``, where the run's timeline marks go)

and for each one runs its ``main(argv)`` exactly as a fresh process would, its output
going to ``log``, then answers one JSON line on its standard output: ``{"rc": 0}``. A
run builds every object anew from its arguments: what carries over is what a fresh
process would load again (imports, compiled code, parsed model files), which is what a
run's start-up costs. Signals work as for a fresh process (SIGINT or SIGTERM end the
run, not the warm process). End of input ends the process; so does its parent's death.
A bad request is answered ``{"rc": 2, "error": "..."}`` and changes nothing.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from contracts import timeline

WARM_FLAG = "--warm"


def exit_process(code: int) -> None:
    """End the process now that its work is done, its files closed and its Zenoh session
    closed: flush the standard streams and exit without the interpreter's teardown
    (numba's and Zenoh's finalizers take 0.1-0.2 s that a run's teardown would wait for)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


def parse_request(line: str) -> tuple[list[str], str, str | None]:
    """(argv, log path, timeline path or None) of one request line; ValueError says what
    is wrong."""
    try:
        request: Any = json.loads(line)
    except ValueError as exc:
        raise ValueError(f"a run request is one JSON object per line: {exc}") from None
    if not isinstance(request, dict) or not {"argv", "log"} <= set(request) or \
            not set(request) <= {"argv", "log", "timeline"}:
        raise ValueError("a run request has the fields argv and log (and timeline)")
    argv, log = request["argv"], request["log"]
    if not isinstance(argv, list) or not all(isinstance(a, str) for a in argv):
        raise ValueError("argv must be a list of strings")
    if not isinstance(log, str) or not log:
        raise ValueError("log must be a file path")
    marks = request.get("timeline")
    if marks is not None and (not isinstance(marks, str) or not marks):
        raise ValueError("timeline must be a file path")
    return argv, log, marks


def serve(main: Callable[[Sequence[str]], int],
          preload: Callable[[], None] | None = None) -> int:
    """Run ``main`` once per request line on standard input (module docstring).
    ``preload`` imports what a run needs before the first request comes, so a process
    started ahead of its run (``ivfm run``) is ready when the run is."""
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    quiet = os.open(os.devnull, os.O_WRONLY)
    os.dup2(quiet, 1)  # between runs nothing may write into the answers
    if preload is not None:
        try:
            preload()
        except Exception:  # the run that needs it fails as a fresh process would
            traceback.print_exc()
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            argv, log, marks = parse_request(line)
            out = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except (ValueError, OSError) as exc:
            answers.write(json.dumps({"rc": 2, "error": str(exc)}) + "\n")
            continue
        if marks:  # the run's timeline marks (contracts/timeline.py) go there
            os.environ[timeline.ENV] = marks
        else:
            os.environ.pop(timeline.ENV, None)
        rc = _run_once(main, argv, out)
        os.close(out)
        answers.write(json.dumps({"rc": rc}) + "\n")
        # What the run left goes before the next one (after the answer: not its cost).
        gc.unfreeze()
        gc.collect()
    return 0


def _run_once(main: Callable[[Sequence[str]], int], argv: list[str], out: int) -> int:
    sys.stdout.flush()
    sys.stderr.flush()
    saved_err = os.dup(2)
    os.dup2(out, 1)
    os.dup2(out, 2)
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse and friends exit as in a fresh process
        rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except KeyboardInterrupt:
        rc = 130
    except Exception:  # a crash of this run, reported in its log as a fresh one would be
        traceback.print_exc()
        rc = 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        quiet = os.open(os.devnull, os.O_WRONLY)
        os.dup2(quiet, 1)
        os.close(quiet)
        os.dup2(saved_err, 2)
        os.close(saved_err)
        # What the run set up for itself goes with it.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return int(rc)
