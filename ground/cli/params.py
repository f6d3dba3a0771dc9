"""``ivfm params``: the vehicle's parameters with their defaults, ranges, units and PX4
types (INT32 travels byte-wise in the PX4 flavour's parameter protocol)."""

from __future__ import annotations

import argparse

from autopilot.parameters import PARAMETERS


def add_arguments(_p: argparse.ArgumentParser) -> None:
    pass


def handle(args: argparse.Namespace) -> int:
    for p in PARAMETERS:
        kind = "INT32" if p.integer else "REAL32"
        print(f"{p.name:<16} {p.default:>10g}  [{p.minimum:g}, {p.maximum:g}] {p.unit:<8}"
              f" {kind:<6} {p.description}")
    return 0
