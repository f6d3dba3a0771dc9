"""``ivfm ground tlog``: the MAVLink mirror of a log exported as a .tlog."""

from __future__ import annotations

import argparse
from pathlib import Path

from ground.telemetry.tlog import export_tlog


def add_arguments(tlog: argparse.ArgumentParser) -> None:
    tlog.add_argument("log", type=Path, help="an .mcap file or a run folder")
    tlog.add_argument("--out", type=Path, help="the .tlog (default beside the log)")


def handle(args: argparse.Namespace) -> int:
    out = args.out or (args.log.with_suffix(".tlog") if args.log.is_file()
                       else args.log / "telemetry.tlog")
    count = export_tlog(args.log, out)
    print(f"wrote {count} MAVLink frames to {out}")
    return 0
