"""The entry-point shell of the vehicle processes (``python -m sitl``, ``python -m
autopilot``), written once.

A process module supplies its parser, its ``run(args)`` and what the process loader
loads ahead (``preload``, contracts/zygote.py); this shell parses the command line,
turns a bad value or a failed start (ValueError, OSError) into ``<process>: error: ...``
and exit code 2, and, run as a script, marks the exit on the timeline and ends without
the interpreter's teardown.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

from contracts import timeline

PROFILE_ENV = "IVFM_PROFILE"  # a folder: the process runs under cProfile
END_WITH_ENV = "IVFM_END_WITH"  # the pid of the command that started this process itself
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def end_with_command() -> None:
    """A run's process that its command started itself (``Popen``: ``--cold``, campaigns)
    rather than through the process loader: stopped (SIGTERM, its clean stop) when that
    command ends, killed or not, as the loader stops the ones it forked. Linux's
    parent-death signal; elsewhere, or without ``IVFM_END_WITH``, nothing."""
    command = os.environ.get(END_WITH_ENV)
    if not command or not sys.platform.startswith("linux"):
        return
    if not (command.isascii() and command.isdecimal()) or int(command) < 1:
        print(f"{END_WITH_ENV}={command!r} is not a process id: ignored", file=sys.stderr,
              flush=True)
        return
    import ctypes
    import signal

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if str(os.getppid()) != command:  # the command ended before the call
        os.kill(os.getpid(), signal.SIGTERM)


def ended_with_this_command(env: dict[str, str]) -> dict[str, str]:
    """``env`` for a run's process this command starts itself (``end_with_command``)."""
    return {**env, END_WITH_ENV: str(os.getpid())}


def exit_process(code: int) -> NoReturn:
    """End the process now that its work is done, its files closed and its Zenoh session
    closed: flush the standard streams and exit without the interpreter's teardown
    (numba's and Zenoh's finalizers take 0.1-0.2 s that a run's teardown would wait for)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


def run_main(process: str, build_parser: Callable[[], argparse.ArgumentParser],
             run: Callable[[argparse.Namespace], int],
             argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` (None: the command line) and run; a ValueError or OSError is the
    process's error message and exit code 2 (argparse's own errors exit 2 as usual)."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (ValueError, OSError) as exc:
        print(f"{process}: error: {exc}", file=sys.stderr)
        return 2


def start_process(process: str, main: Callable[..., int]) -> NoReturn:
    """``python -m <process>``: one run of ``main`` (under cProfile if asked); then the
    exit is marked and the process ends (``exit_process``)."""
    end_with_command()
    profile_dir = os.environ.get(PROFILE_ENV)
    code = profiled(process, main, Path(profile_dir)) if profile_dir else main()
    timeline.mark(process, "exit")
    exit_process(code)


def profiled(process: str, main: Callable[..., int], folder: Path) -> int:
    """One run under cProfile, its statistics into ``folder/PROCESS.prof`` (for the cycle
    budget in docs/mavlink.md: tests/benchmarks/profile_loops.py reads them)."""
    import cProfile

    profiler = cProfile.Profile()
    try:
        return profiler.runcall(main)
    finally:
        folder.mkdir(parents=True, exist_ok=True)
        profiler.dump_stats(folder / f"{process}.prof")


def place_process(process: str, args: argparse.Namespace) -> None:
    """Where a vehicle process's threads may run, set before Zenoh's threads start (they
    inherit it) and said on standard error: ``--rt-cpus`` pins the process; ``--handover-cpu``
    in lockstep keeps its threads off the CPU its loop will take; else nothing."""
    from contracts.realtime import keep_off_cpu, pin_to_cpus

    if args.rt_cpus is not None:
        print(f"{process}: {pin_to_cpus(args.rt_cpus)}", file=sys.stderr, flush=True)
    elif args.handover_cpu is not None and args.lockstep:
        print(f"{process}: {keep_off_cpu(args.handover_cpu)}", file=sys.stderr, flush=True)
