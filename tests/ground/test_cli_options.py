"""Every option of every command, tried as a new user would: each typed option of
``ivfm`` (and ``python -m sitl`` / ``python -m autopilot``, the same parsers) given
hostile values, fixed ones and hypothesis' (seeded, bounded). A value is either taken
(a number then finite unless the option allows infinity) or refused by argparse with
exit status 2 and a message naming the option; never a traceback, never a run.
Parse-only: nothing flies."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from contracts.arguments import DURATION_S, SEED, cpu_list, number
from ground.cli.main import build_parser, main

# A command and the positional arguments it needs to parse.
COMMANDS = (
    ["run", "attitude-sine", "--out", "x"], ["check"], ["rehearse", "--airframe", "paper"],
    ["report", "x"], ["compare", "--out", "x"], ["identify"], ["sitl"], ["autopilot"],
    ["ground", "log", "--out", "x"], ["ground", "perturb", "wind"], ["ground", "router"],
    ["ground", "tlog", "x"], ["ground", "ulog", "x"], ["ground", "certs", "--out", "x"],
    ["plan", "x"], ["scenarios"], ["params"], ["shield"],
)
HOSTILE = ("-5", "nan", "NaN", "inf", "-inf", "1e309", "", " ", "abc", "1e400", "-0",
           "99999999999999999999", "0x10", "1_000", "½", "\x00", "--", "1,2,3", "4.5.6")
# Options whose value is free text or a path (checked where the file is opened) or a
# Zenoh endpoint (checked by Zenoh when the session opens, with its own message).
UNTYPED = (str, Path, None)


def _subparser(argv: list[str]) -> argparse.ArgumentParser:
    parser = build_parser(argv)
    for name in argv:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
        if not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions):
            return parser
    return parser


def _typed_options() -> list[tuple[list[str], str, argparse.Action]]:
    out = []
    for base in COMMANDS:
        parser = _subparser(base)
        for action in parser._actions:
            if action.option_strings and action.type not in UNTYPED and action.nargs is None:
                out.append((base, action.option_strings[-1], action))
    return out


TYPED = _typed_options()


def test_the_commands_have_typed_options():
    """The fuzzing below covers what it should: the numeric options of every command."""
    names = {(tuple(base[:2]), option) for base, option, _ in TYPED}
    for expected in ((("run", "attitude-sine"), "--rate-hz"), (("run", "attitude-sine"), "--seed"),
                     (("check",), "--jobs"), (("identify",), "--samples"),
                     (("sitl",), "--port"), (("autopilot",), "--sysid"),
                     (("autopilot",), "--max-peers"), (("ground", "log"), "--flush-s"),
                     (("ground", "perturb"), "--duration"), (("plan", "x"), "--timeout")):
        assert expected in names, expected
    assert len(TYPED) >= 40


def _try(base: list[str], option: str, action: argparse.Action, value: str, capsys) -> None:
    parser = _subparser(base)
    argv = [*base[_depth(base):], f"{option}={value}"]
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        assert exc.code == 2
        err = capsys.readouterr().err
        assert f"argument {'/'.join(action.option_strings)}" in err or option in err, err
        assert "Traceback" not in err
        return
    got = getattr(args, action.dest)
    if isinstance(got, float):
        assert not math.isnan(got), (option, value)
        assert math.isfinite(got) or action.type is DURATION_S, (option, value)
    span = getattr(action.type, "range", None)
    if span is not None:  # a number option (float or whole): what it took is in its range
        for taken in got if isinstance(got, list) else [got]:  # repeatable options: each
            assert span.holds(taken), (option, value, got, span)


def test_every_number_option_says_its_range():
    """The range check above reaches the whole-number options too (ports, seeds, ids)."""
    ranged = {option for _, option, action in TYPED if hasattr(action.type, "range")}
    assert {"--seed", "--port", "--sysid", "--jobs", "--samples", "--rate-hz",
            "--duration"} <= ranged, ranged


def test_the_range_check_refuses_a_value_outside_or_of_the_wrong_kind():
    seeds = SEED.range
    assert seeds.holds(0) and seeds.holds(2**32 - 1)
    assert not seeds.holds(-1) and not seeds.holds(2**32) and not seeds.holds(3.0)


def _depth(base: list[str]) -> int:
    """How many words of ``base`` name the (sub)command."""
    return 2 if base[0] == "ground" else 1


@pytest.mark.parametrize("base, option, action", TYPED,
                         ids=[f"{' '.join(b[:_depth(b)])} {o}" for b, o, _ in TYPED])
def test_hostile_values_are_taken_or_refused_naming_the_option(base, option, action, capsys):
    for value in HOSTILE:
        _try(base, option, action, value, capsys)


@settings(max_examples=300, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(TYPED), st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers().map(str),
    st.text(max_size=12)))
def test_generated_values_are_taken_or_refused_naming_the_option(capsys, typed, value):
    base, option, action = typed
    _try(base, option, action, value, capsys)


def test_a_refused_option_runs_nothing_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["run", "attitude-sine", "--inprocess", "--rate-hz", "-5", "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --rate-hz: must be a number in [1, 1000] Hz, got '-5'" in err
    assert not out.exists()


@pytest.mark.parametrize("text, value", [("100", 100.0), ("1e3", 1000.0), ("10000", 1e4)])
def test_numbers_in_range_are_taken(text, value):
    assert number(0.0, 10_000.0, low_open=True)(text) == value


@pytest.mark.parametrize("text", ["0", "10000.5", "nan", "inf", "x"])
def test_numbers_out_of_range_are_refused_with_the_range(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be a number in \(0, 10000\]"):
        number(0.0, 10_000.0, low_open=True)(text)


@pytest.mark.parametrize("text, cpus", [("0", {0}), ("0,1", {0, 1}), ("0-1", {0, 1}),
                                        (" 1 ", {1})])
def test_cpu_lists_are_read_as_linux_writes_them(text, cpus, monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    assert cpu_list(text) == cpus


@pytest.mark.parametrize("text, message", [("2", "not on this machine (CPUs 0-1)"),
                                           ("1-0", "not on this machine"),
                                           ("-1", "not a CPU list"), ("a", "not a CPU list"),
                                           ("", "not a CPU list")])
def test_cpu_lists_the_machine_lacks_are_refused(text, message, monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(message)):
        cpu_list(text)


def test_a_run_without_out_writes_a_fresh_folder_under_runs(tmp_path, monkeypatch, capsys):
    """``ivfm run attitude-sine`` alone: a new folder under runs/ named after the scenario,
    said at the start; a second run beside it (in the same second, or not) gets its own."""
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        assert main(["run", "attitude-sine", "--inprocess", "--no-figures"]) == 0
    folders = sorted((tmp_path / "runs").iterdir())
    assert len(folders) == 2, folders
    assert all(f.name.startswith("attitude-sine-") and (f / "metrics.json").is_file()
               for f in folders)
    assert "run folder runs/attitude-sine-" in capsys.readouterr().err


def test_a_fresh_folder_never_reuses_one_that_exists(tmp_path, monkeypatch):
    from ground.cli.common import fresh_folder

    monkeypatch.setattr("time.strftime", lambda fmt: fmt.replace("%Y%m%d-%H%M%S", "T"))
    first = fresh_folder("x", tmp_path)
    assert first == tmp_path / "x-T"
    first.mkdir()
    (tmp_path / "x-T-2").mkdir()
    assert fresh_folder("x", tmp_path) == tmp_path / "x-T-3"


@pytest.mark.parametrize("base", COMMANDS, ids=[" ".join(b[:_depth(b)]) for b in COMMANDS])
def test_help_reads_as_plain_text(base):
    """No reStructuredText (``ivfm``, `name`) in what --help prints."""
    for parser in (build_parser(base), _subparser(base)):
        text = parser.format_help()
        assert "`" not in text, [line for line in text.splitlines() if "`" in line]


def test_check_jobs_are_resolved_once_the_scenarios_and_the_mode_are_known():
    """(``default_jobs`` itself: tests/ground/test_flight_slots.py.)"""
    args = build_parser(["check"]).parse_args(["check"])
    assert args.jobs is None
