"""``ivfm autopilot``: the autopilot process, as ``python -m autopilot``."""

from __future__ import annotations

import argparse

from autopilot.__main__ import build_parser, run


def add_arguments(p: argparse.ArgumentParser) -> None:
    build_parser(p)


def handle(args: argparse.Namespace) -> int:
    return run(args)
