"""The ``ivfm`` command: run scenarios, compare controllers, identify fuzzy models.

Every argument is validated before anything is written: a bad name, file or number
gives ``ivfm: error: ...`` on stderr, exit code 2, and no output files.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ground.cli.registry import Subcommand, add_subcommands, chosen
from ground.run import loader  # standard library only: it starts before the heavy imports

# In the order ``ivfm --help`` lists them. A new subcommand: its module, and a line here.
SUBCOMMANDS = (
    Subcommand("run", "ground.cli.run", "run one scenario and write metrics.json and figures",
               flies=True),
    Subcommand("check", "ground.cli.check",
               "fly scenario files and judge them by their [expect] tables", flies=True),
    Subcommand("rehearse", "ground.cli.rehearse",
               "go / no-go for a first flight of an airframe (docs/rehearsal.md)", flies=True),
    Subcommand("report", "ground.cli.report",
               "metrics.json and figures of a run folder, from its log"),
    Subcommand("compare", "ground.cli.compare",
               "every controller on every scenario, tables+figures"),
    Subcommand("identify", "ground.cli.identify",
               "build the IVFM and T1FM from input-output data"),
    Subcommand("ulog", "ground.cli.ulog", "PX4 flight logs (ULog): what one holds"),
    Subcommand("airframe", "ground.cli.airframe",
               "airframe files: a draft from a PX4 log"),
    Subcommand("sitl", "ground.cli.sitl", "the simulator process (PX4 simulator protocol)"),
    Subcommand("autopilot", "ground.cli.autopilot", "the autopilot process (MAVLink vehicle)"),
    Subcommand("ground", "ground.cli.ground_tools",
               "ground station: logger, perturbations, router, .tlog and ULog export"),
    Subcommand("plan", "ground.cli.plan",
               "upload a QGroundControl .plan file to a vehicle (docs/missions.md)"),
    Subcommand("shield", "ground.cli.shield",
               "keep CPUs for the real-time processes (docs/realtime.md)"),
    Subcommand("campaign", "ground.cli.campaign",
               "many randomized flights on Dask, summarised with statistics"),
    Subcommand("scenarios", "ground.cli.scenarios", "list the scenarios"),
    Subcommand("campaigns", "ground.cli.campaigns", "list the shipped campaign files"),
    Subcommand("params", "ground.cli.params", "list the controller parameters with defaults"),
)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``ivfm`` parser. Only the command named in ``argv`` gets its arguments (each
    command's imports load with them: ``ivfm ground log`` starts without the vehicle's
    compiled code); without a known command, every one does."""
    args = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="ivfm",
                                     description=__doc__.splitlines()[0].replace("``", ""))
    add_subcommands(parser, SUBCOMMANDS, args)
    return parser


# With one of these, a command that flies forks no process (help, in process, --cold).
NOT_FORKING = frozenset({"-h", "--help", "--inprocess", "--cold"})


def main(argv: Sequence[str] | None = None, start_loader_first: bool = False) -> int:
    """The command. ``start_loader_first`` (the command line, not a call from Python): a
    command that flies starts its process loader before anything else (ground/run/
    loader.py), so the loader loads the processes' imports and compiled code while this
    process loads its own (about 0.4 s), instead of after. A command that ends without
    flying (bad input, say) ends the loader with it."""
    args = list(sys.argv[1:] if argv is None else argv)
    if start_loader_first and args and not NOT_FORKING & set(args) and any(
            command.flies and command.name == args[0] for command in SUBCOMMANDS):
        loader.start_early()
    try:
        return _run(argv)
    finally:
        loader.discard_early()


def _run(argv: Sequence[str] | None) -> int:
    from ground.cli.common import UsageError

    args = build_parser(argv).parse_args(argv)
    try:
        return chosen(args).handle(args)
    except (UsageError, ValueError, OSError) as exc:
        print(f"ivfm: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a process of the run failed: said, exit 1
        if not isinstance(exc, loader.ProcessRunError):
            raise
        print(f"ivfm: error: {exc}", file=sys.stderr)
        return 1


def console_main() -> None:
    """The ``ivfm`` command: ``main``, then an exit without the interpreter's teardown
    (numba's, Zenoh's and matplotlib's finalizers add 0.2-0.3 s to every command; every
    file is closed by then)."""
    from contracts.process_main import exit_process

    exit_process(main(start_loader_first=True))
