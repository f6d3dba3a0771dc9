"""The ``ivfm`` command: run scenarios, compare controllers, identify fuzzy models.

Every argument is validated before anything is written: a bad name, file or number
gives ``ivfm: error: ...`` on stderr, exit code 2, and no output files.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


class UsageError(Exception):
    """Bad input from the command line: reported in one line, exit code 2."""


def _build_parser() -> argparse.ArgumentParser:
    from autopilot.__main__ import param_argument
    from autopilot.control.factory import CONTROLLERS
    from contracts.airframe import AIRFRAMES
    from ground.scenarios import SCENARIOS
    from sitl.dynamics import FIDELITIES

    parser = argparse.ArgumentParser(prog="ivfm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    def add_common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--airframe", default="paper", choices=sorted(AIRFRAMES))
        p.add_argument("--model", type=Path, help="fuzzy model JSON (default: the shipped one)")
        p.add_argument("--param", type=param_argument, action="append", default=[],
                       metavar="NAME=VALUE", help="controller parameter override (repeatable)")

    run = sub.add_parser("run", help="run one scenario and write metrics.json and figures")
    run.add_argument("scenario", help=f"one of: {', '.join(SCENARIOS)}")
    pace = run.add_mutually_exclusive_group()
    pace.add_argument("--inprocess", action="store_true",
                      help="plant and controller in one process (no MAVLink)")
    pace.add_argument("--realtime", action="store_true",
                      help="the two processes paced to the wall clock (default: lockstep)")
    run.add_argument("--rate-hz", type=float, default=100.0, help="control rate")
    run.add_argument("--state-source", default="odometry", choices=["odometry", "hil-state"],
                     help="what the autopilot reads its state from")
    run.add_argument("--controller", default="ivfc", choices=CONTROLLERS)
    run.add_argument("--plant", default="paper", choices=list(FIDELITIES))
    run.add_argument("--out", type=Path, required=True, help="output directory")
    run.add_argument("--no-figures", action="store_true")
    add_common(run)

    compare = sub.add_parser("compare", help="every controller on every scenario, tables+figures")
    compare.add_argument("--out", type=Path, required=True)
    compare.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    compare.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    compare.add_argument("--plants", nargs="+", default=list(FIDELITIES))
    add_common(compare)

    ident = sub.add_parser("identify", help="build the IVFM and T1FM from input-output data")
    ident.add_argument("--data", type=Path, help="dataset CSV (default: fly the excitation)")
    ident.add_argument("--out", type=Path, default=None, help="model JSON to write")
    ident.add_argument("--write-data", type=Path, help="also save the generated excitation CSV")
    ident.add_argument("--seed", type=int, default=0)
    ident.add_argument("--samples", type=int, default=4000)
    ident.add_argument("--clusters", type=int, default=None)
    ident.add_argument("--airframe", default="paper", choices=sorted(AIRFRAMES))

    from autopilot.__main__ import build_parser as autopilot_parser
    from sitl.__main__ import build_parser as sitl_parser

    sitl_parser(sub.add_parser("sitl", help="the simulator process (PX4 simulator protocol)"))
    autopilot_parser(sub.add_parser("autopilot", help="the autopilot process (MAVLink vehicle)"))
    sub.add_parser("scenarios", help="list the scenarios")
    sub.add_parser("params", help="list the controller parameters with defaults")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    from ground import commands

    try:
        handler = {
            "run": commands.run_command,
            "compare": commands.compare_command,
            "identify": commands.identify_command,
            "scenarios": commands.scenarios_command,
            "params": commands.params_command,
            "sitl": commands.sitl_command,
            "autopilot": commands.autopilot_command,
        }[args.command]
        return handler(args)
    except (UsageError, ValueError, OSError) as exc:
        print(f"ivfm: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
