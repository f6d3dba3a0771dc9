"""``ivfm ulog info FILE``: what a PX4 log holds for identification."""

from __future__ import annotations

import argparse
from pathlib import Path

from contracts.airframe_file import Envelope, spec_argument
from ground.cli.identify import envelope_argument, trim_argument
from ground.ulog.clock import DEFAULT_TRIM_S
from ground.ulog.info import format_info, log_info

DESCRIPTION = (
    "Print what a PX4 flight log (ULog) holds for identification: the firmware (PX4 "
    "version), the vehicle (type, rotor count), how long it was armed and airborne, where "
    "each signal is and at what rate, how far the flight reached (against the airframe's "
    "envelope with --airframe, else the raw ranges), and what it lacks for `ivfm identify "
    "--ulog` and `ivfm airframe from-ulog` (docs/px4-logs.md).")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", type=Path, help="the PX4 log (.ulg)")
    p.add_argument("--airframe", type=spec_argument, default=None,
                   help="judge the reach against this airframe's [envelope] (a shipped "
                        "name or an airframe .toml file)")
    p.add_argument("--envelope", type=envelope_argument, default=None,
                   metavar="ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S]",
                   help="judge the reach against this envelope instead")
    p.add_argument("--trim-s", type=trim_argument, default=DEFAULT_TRIM_S,
                   metavar="START[,END]",
                   help="seconds left out at the start and (before a landing) the end of "
                        "each airborne span "
                        f"(default {DEFAULT_TRIM_S[0]:g},{DEFAULT_TRIM_S[1]:g})")


def handle(args: argparse.Namespace) -> int:
    envelope = Envelope(*args.envelope) if args.envelope else None
    print(format_info(log_info(args.file, args.airframe, envelope, args.trim_s)))
    return 0
