"""``ivfm plan``: a QGroundControl .plan file uploaded to a running vehicle."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pymavlink import mavutil

from autopilot.navigator.plan_file import read_plan
from contracts.arguments import TIMEOUT_S
from ground.cli.common import UsageError
from ground.uplink.plan import upload

DESCRIPTION = "Read a .plan file (every item checked first), wait for a vehicle, upload it."


def add_arguments(plan: argparse.ArgumentParser) -> None:
    plan.add_argument("file", type=Path, help="the .plan file")
    plan.add_argument("--connect", default="udpin:0.0.0.0:14550",
                      help="where the vehicle's ground link arrives (default: "
                           "udpin:0.0.0.0:14550, where QGroundControl listens)")
    plan.add_argument("--timeout", type=TIMEOUT_S, default=30.0,
                      help="seconds to wait for the vehicle's heartbeat")


def handle(args: argparse.Namespace) -> int:
    lists = read_plan(args.file)
    conn = mavutil.mavlink_connection(args.connect, source_system=255, source_component=190)
    try:
        print(f"ivfm: waiting for a vehicle on {args.connect}", file=sys.stderr)
        if conn.wait_heartbeat(timeout=args.timeout) is None:
            raise UsageError(f"no vehicle heard on {args.connect} within {args.timeout:g} s")
        upload(conn, lists)
    finally:
        conn.close()
    return 0
