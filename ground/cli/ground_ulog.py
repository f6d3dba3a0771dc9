"""``ivfm ground ulog``: a run's log written as a PX4 flight log (ULog, docs/ulog.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from contracts.airframe_file import spec_argument
from contracts.arguments import VEHICLE_ID
from ground.record.run_files import ULOG_FILE
from ground.ulog.export import export_ulog


def add_arguments(ulog: argparse.ArgumentParser) -> None:
    ulog.add_argument("log", type=Path, help="a run folder or an .mcap file")
    ulog.add_argument("--out", type=Path,
                      help=f"the .ulg (default: {ULOG_FILE} in the run folder, or the .mcap "
                           "file's name with .ulg)")
    ulog.add_argument("--vehicle", type=VEHICLE_ID, default=None,
                      help="vehicle id in the log (default: the run's, or the only one)")
    ulog.add_argument("--airframe", type=spec_argument, default=None,
                      help="the airframe it flew, shipped name or .toml file (default: the "
                           "run's, from run.json)")


def default_out(log: Path) -> Path:
    return log / ULOG_FILE if log.is_dir() else log.with_suffix(".ulg")


def handle(args: argparse.Namespace) -> int:
    print(export_ulog(args.log, args.out or default_out(args.log), vehicle=args.vehicle,
                      airframe=args.airframe))
    return 0
