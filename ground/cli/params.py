"""``ivfm params``: the vehicle's parameters with their defaults, ranges and units."""

from __future__ import annotations

import argparse

from autopilot.parameters import PARAMETERS


def add_arguments(_p: argparse.ArgumentParser) -> None:
    pass


def handle(args: argparse.Namespace) -> int:
    for p in PARAMETERS:
        print(f"{p.name:<16} {p.default:>10g}  [{p.minimum:g}, {p.maximum:g}] {p.unit:<8}"
              f" {p.description}")
    return 0
