"""``ivfm sitl``: the simulator process, as ``python -m sitl``."""

from __future__ import annotations

import argparse

from sitl.__main__ import build_parser, run


def add_arguments(p: argparse.ArgumentParser) -> None:
    build_parser(p)


def handle(args: argparse.Namespace) -> int:
    return run(args)
