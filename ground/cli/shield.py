"""``ivfm shield``: CPUs kept for the real-time processes."""

from __future__ import annotations

import argparse

from contracts.arguments import cpu_list
from contracts.realtime import shield_cpus

DESCRIPTION = (
    "Move every user-space thread on this machine off the given CPUs (what they start "
    "later inherits it), so that the simulator and autopilot started with --rt-cpus on "
    "the same list have them to themselves. Needs root (CAP_SYS_NICE) for other users' "
    "processes. --off lifts it.")


def add_arguments(shield: argparse.ArgumentParser) -> None:
    which = shield.add_mutually_exclusive_group(required=True)
    which.add_argument("--cpus", type=cpu_list, metavar="LIST",
                       help="the CPUs to keep for the real-time processes (0, 0-1)")
    which.add_argument("--off", action="store_true", help="every CPU for everything again")


def handle(args: argparse.Namespace) -> int:
    reserved = None if args.off else args.cpus
    moved, refused = shield_cpus(reserved)
    where = ("every CPU open to every thread again" if reserved is None else
             f"CPU {','.join(map(str, sorted(reserved)))} kept for processes started with "
             f"--rt-cpus {','.join(map(str, sorted(reserved)))}")
    print(f"{where}: {moved} threads moved"
          + (f", {refused} refused (not ours to move: run as root)" if refused else ""))
    return 0
