"""``ivfm ground log``: the logger, every telemetry record into MCAP (and, with
``--view``, the live view). Imports nothing of the vehicle: it starts fast."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from contracts.arguments import cpu_number, number
from contracts.realtime import any_cpu, keep_off_cpu
from contracts.telemetry import DEFAULT_GROUND_ENDPOINT
from contracts.zenoh_link import add_zenoh_arguments, zenoh_options_from_args
from ground.telemetry.live_view import (
    DEFAULT_VIEW_PORT,
    LiveView,
    add_view_arguments,
    view_address,
)
from ground.telemetry.logger import Logger, LoggerConfig


def add_arguments(log: argparse.ArgumentParser) -> None:
    log.add_argument("--out", type=Path, required=True, help="folder for the .mcap files")
    log.add_argument("--name", default="logger", help="logger name (status key, token)")
    log.add_argument("--prefix", default="telemetry", help="file name prefix")
    log.add_argument("--chunk-kib", type=number(1, 65536, integer=True), default=256,
                     help="MCAP chunk size [KiB], 1-65536")
    log.add_argument("--flush-s", type=number(0.01, 60.0, "s"), default=0.25,
                     help="close a chunk at least this often [s], 0.01-60")
    log.add_argument("--rotate-mib", type=number(1, 1_000_000, integer=True), default=512,
                     help="start a new file past this [MiB]")
    log.add_argument("--rotate-chunks", type=number(16, 10_000_000, integer=True),
                     default=512,
                     help="... or past this many chunks (bounds the logger's memory)")
    log.add_argument("--compression", default="zstd", choices=["zstd", "lz4", "none"])
    log.add_argument("--view", type=view_address, metavar="[HOST:]PORT",
                     help="also serve the flight live to Foxglove on this WebSocket port "
                          f"(e.g. {DEFAULT_VIEW_PORT})")
    add_view_arguments(log)
    log.add_argument("--no-foxglove", action="store_true",
                     help="write only the records, not what Foxglove draws beside them")
    log.add_argument("--off-cpu", type=cpu_number, metavar="CPU",
                     help="keep off this CPU (a lockstep run's hand-over CPU: scenario "
                          "runs pass it)")
    add_zenoh_arguments(log, [DEFAULT_GROUND_ENDPOINT], [])


def handle(args: argparse.Namespace) -> int:
    config = LoggerConfig(args.out, zenoh_options_from_args(args), name=args.name,
                          prefix=args.prefix, chunk_bytes=args.chunk_kib * 1024,
                          flush_period_s=args.flush_s, rotate_bytes=args.rotate_mib * 2**20,
                          rotate_chunks=args.rotate_chunks,
                          compression=args.compression, foxglove=not args.no_foxglove,
                          view_rate_hz=args.view_rate_hz)
    if args.off_cpu is not None:
        print(f"logger: {keep_off_cpu(args.off_cpu)}", file=sys.stderr, flush=True)
    live = None
    try:
        if args.view is None:
            return Logger(config).run()
        live = LiveView(*args.view)
        print(f"logger: serving the live view on {live.url}", file=sys.stderr, flush=True)
        return Logger(config, live=live.publish).run()
    finally:
        if live is not None:
            live.close()
        if args.off_cpu is not None:
            any_cpu()
