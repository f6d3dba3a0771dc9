"""What several subcommands share: the usage error, the default output folder, the
airframe / model / parameter options and the CPU list of the real-time processes."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from autopilot.__main__ import param_argument
from contracts.airframe_file import spec_argument
from contracts.arguments import cpu_list


class UsageError(Exception):
    """Bad input from the command line: reported in one line, exit code 2."""


def fresh_folder(name: str, parent: Path = Path("runs")) -> Path:
    """``runs/NAME-YYYYMMDD-HHMMSS`` (and ``-2``, ``-3``... if that one exists): where a
    command writes when it is given no ``--out``, so that no run overwrites another."""
    base = parent / time.strftime(f"{name}-%Y%m%d-%H%M%S")
    folder, n = base, 1
    while folder.exists():
        n += 1
        folder = base.with_name(f"{base.name}-{n}")
    return folder


def add_vehicle_options(p: argparse.ArgumentParser) -> None:
    """The airframe, its fuzzy model and parameter overrides."""
    p.add_argument("--airframe", default="paper", type=spec_argument,
                   help="shipped airframe name or airframe .toml file")
    p.add_argument("--model", type=Path, help="fuzzy model JSON (default: the shipped one)")
    p.add_argument("--any-airframe-model", action="store_true",
                   help="fly a model identified on another airframe")
    p.add_argument("--param", type=param_argument, action="append", default=[],
                   metavar="NAME=VALUE", help="controller parameter override (repeatable)")


def add_rt_cpus(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rt-cpus", type=cpu_list, metavar="LIST",
                   help="keep the simulator and autopilot on these CPUs (with 'ivfm "
                        "shield': CPUs nothing else runs on; docs/realtime.md)")
