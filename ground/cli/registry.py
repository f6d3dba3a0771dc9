"""The registry mechanism of ``ivfm``'s subcommands: a name, the module holding its
parser and handler, one line of help. A module is imported only when its command is
named (or for a full ``--help``)."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Sequence
from types import ModuleType
from typing import NamedTuple


class Subcommand(NamedTuple):
    name: str
    module: str  # defines add_arguments(parser) and handle(args), or SUBCOMMANDS (a group)
    help: str
    flies: bool = False  # flies runs through the processes (forked by a process loader)


def add_subcommands(parser: argparse.ArgumentParser, subcommands: Sequence[Subcommand],
                    argv: Sequence[str], depth: int = 0) -> None:
    """A subparser per subcommand; only the one ``argv`` names (at ``depth``) gets its
    arguments, so only its module is imported. Without a known name, every one does."""
    named = argv[0] if argv and argv[0] in {s.name for s in subcommands} else None
    sub = parser.add_subparsers(dest="command" if depth == 0 else "sub" * depth + "command",
                                required=True)
    for command in subcommands:
        if named is not None and named != command.name:
            sub.add_parser(command.name, help=command.help)
            continue
        module = importlib.import_module(command.module)
        p = sub.add_parser(command.name, help=command.help,
                           description=getattr(module, "DESCRIPTION", None))
        p.set_defaults(**{f"module_{depth}": module})
        if hasattr(module, "SUBCOMMANDS"):
            add_subcommands(p, module.SUBCOMMANDS, argv[1:], depth + 1)
        else:
            module.add_arguments(p)


def chosen(args: argparse.Namespace) -> ModuleType:
    """The module of the (innermost) subcommand the arguments name."""
    depth = 0
    while hasattr(args, f"module_{depth + 1}"):
        depth += 1
    return getattr(args, f"module_{depth}")
