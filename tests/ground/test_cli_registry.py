"""The ``ivfm`` subcommand registry (ground/cli/registry.py): a subcommand is its module
and one line; only the module of the command named is imported."""

from __future__ import annotations

import argparse
import sys
import types

import pytest

from ground.cli.registry import Subcommand, add_subcommands, chosen


@pytest.fixture
def modules(monkeypatch):
    """Two subcommand modules and a group, as sys.modules entries."""
    def module(name: str, **attrs) -> types.ModuleType:
        m = types.ModuleType(name)
        m.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, m)
        return m

    hello = module("fake_cli.hello", DESCRIPTION="Say hello.",
                   add_arguments=lambda p: p.add_argument("--to", default="world"),
                   handle=lambda args: f"hello {args.to}")
    tick = module("fake_cli.tick", add_arguments=lambda p: p.add_argument("n", type=int),
                  handle=lambda args: args.n)
    module("fake_cli.group", SUBCOMMANDS=(Subcommand("tick", "fake_cli.tick", "tick"),))
    return hello, tick


REGISTRY = (Subcommand("hello", "fake_cli.hello", "say hello"),
            Subcommand("group", "fake_cli.group", "a group"),
            Subcommand("absent", "fake_cli.not_a_module", "never imported unless named"))


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="fake")
    add_subcommands(parser, REGISTRY, argv)
    return parser.parse_args(argv)


def test_the_named_command_runs_its_module_and_no_other_module_is_imported(modules):
    args = _parse(["hello", "--to", "pilot"])  # fake_cli.not_a_module would raise
    assert chosen(args).handle(args) == "hello pilot"


def test_a_group_hands_over_to_its_own_subcommands(modules):
    args = _parse(["group", "tick", "7"])
    assert chosen(args) is modules[1] and chosen(args).handle(args) == 7


def test_without_a_known_command_every_module_is_needed(modules):
    with pytest.raises(ModuleNotFoundError, match="fake_cli"):
        _parse(["--help"])


def test_every_shipped_subcommand_module_has_its_parser_and_handler():
    import importlib

    from ground.cli.ground_tools import SUBCOMMANDS as GROUND
    from ground.cli.main import SUBCOMMANDS

    for command in (*SUBCOMMANDS, *GROUND):
        module = importlib.import_module(command.module)
        assert hasattr(module, "SUBCOMMANDS") or (
            callable(module.add_arguments) and callable(module.handle)), command.name
        assert module.__doc__, command.module
