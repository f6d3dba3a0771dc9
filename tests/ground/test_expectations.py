"""Expectations ([expect] in scenario files), the events they look for, and the reports
of ``ivfm check`` (JUnit read back by junitparser, Markdown, baselines): logic only,
on metrics dicts and arrays; the flights are in test_check.py."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import junitparser
import numpy as np
import pytest

from contracts.modes import FlightMode
from contracts.telemetry import FLAG_ARMED, FLAG_FAILSAFE
from ground.check.checker import ScenarioResult, collect, compare_baseline
from ground.check.results import junit_xml, markdown_summary, results_table
from ground.cli.main import main
from ground.record.events import step_events
from ground.scenario.expectations import COMPLETED, evaluate, parse_expectations
from ground.scenario.scenario_file import (
    load_scenario,
    scenario_by_name,
    scenario_from_dict,
    shipped_scenarios,
)

AXES = ("x", "y", "z", "psi")


def metrics(**changes) -> dict:
    base = {
        "diverged": False,
        "axes": {"x": {"rmse": 0.02, "max_abs": 0.05}, "y": {"rmse": 0.03, "max_abs": 0.06},
                 "z": {"rmse": 1e-5, "max_abs": 3e-5}, "psi": {"rmse": 5e-4, "max_abs": 2e-3}},
        "control": {"effort_mean_sum_c2": 0.87, "chattering_per_s": 1.2,
                    "saturated_fraction": 0.01},
        "events": [{"kind": "mode", "t_s": 0.0, "mode": "REFERENCE"},
                   {"kind": "armed", "t_s": 0.0, "mode": "REFERENCE"},
                   {"kind": "statustext", "t_s": 11.05, "text": "GPS lost: dead reckoning"},
                   {"kind": "failsafe", "t_s": 12.4, "mode": "HOLD"}],
    }
    base.update(changes)
    return base


def outcome(outcomes, name):
    [found] = [o for o in outcomes if o.name == name]
    return found


# -- parsing ---------------------------------------------------------------------------------

def test_a_full_table_parses_into_limits_and_events():
    e = parse_expectations({
        "no_failsafe": True,
        "axes": {"x": {"rmse_max": 0.05, "max_abs_max": 0.2}},
        "control": {"saturated_fraction_max": 0.1},
        "event": [{"kind": "failsafe", "mode": "HOLD", "at_s": 12.0, "within_s": 1.5},
                  {"kind": "disarmed", "by_s": 40}],
    }, AXES, 60.0)
    assert [lim.name for lim in e.limits] == ["axes.x.rmse <= 0.05", "axes.x.max_abs <= 0.2",
                                              "control.saturated_fraction <= 0.1"]
    failsafe, disarmed = e.events
    assert (failsafe.after_s, failsafe.before_s, failsafe.mode) == (12.0, 13.5, "HOLD")
    assert (disarmed.after_s, disarmed.before_s) == (0.0, 40.0)
    assert e.names() == [COMPLETED, *(lim.name for lim in e.limits), "no failsafe",
                         "event failsafe HOLD in [12, 13.5] s", "event disarmed by t = 40 s"]


@pytest.mark.parametrize(("table", "message"), [
    ({"axis": {}}, "unknown field(s) axis"),
    ({"axes": {"phi": {"rmse_max": 1.0}}}, "judged on x, y, z, psi only"),
    ({"axes": {"x": {"rms_max": 1.0}}}, "unknown limit 'rms_max'"),
    ({"axes": {"x": {"rmse_max": math.nan}}}, "expect.axes.x.rmse_max must be a finite number"),
    ({"axes": {"x": {"rmse_max": math.inf}}}, "must be a finite number"),
    ({"axes": {"x": {"rmse_max": "0.1"}}}, "must be a finite number"),
    ({"axes": {"x": {"rmse_max": True}}}, "must be a finite number"),
    ({"control": {"effort_max": 1.0}}, "expect.control.effort_max: unknown limit"),
    ({"timing": {"deadline_misses": 0}}, "unknown limit"),
    ({"no_failsafe": 1}, "no_failsafe must be true or false"),
    ({"event": {"kind": "armed"}}, "array of tables"),
    ({"event": [{"kind": "crash"}]}, "kind must be one of mode, armed"),
    ({"event": [{"kind": "mode", "mode": "LOITER"}]}, "mode must be one of HOLD"),
    ({"event": [{"kind": "statustext"}]}, "needs the text"),
    ({"event": [{"kind": "armed", "text": "x"}]}, "text (a string) is for statustext"),
    ({"event": [{"kind": "armed", "at_s": 3.0}]}, "at_s goes with within_s"),
    ({"event": [{"kind": "armed", "at_s": 3.0, "within_s": 1.0, "by_s": 9.0}]},
     "at_s goes with within_s"),
    ({"event": [{"kind": "armed", "after_s": 5.0, "before_s": 4.0}]}, "ends (4 s) before"),
    ({"event": [{"kind": "armed", "after_s": 70.0}]}, "after the run ends (60 s)"),
    ({"event": [{"kind": "armed", "by_s": -1.0}]}, "must be a finite number >= 0"),
    ({"event": [{"kind": "armed", "when": 1.0}]}, "unknown field(s) when"),
])
def test_bad_tables_are_refused_with_the_field_named(table, message):
    with pytest.raises(ValueError, match=None) as err:
        parse_expectations(table, AXES, 60.0)
    assert message in str(err.value)


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


HOVER = """name = "{name}"
duration_s = 5.0
[reference]
kind = "hover"
altitude_m = 1.0
"""


def test_a_scenario_file_refuses_limits_it_cannot_measure(tmp_path):
    path = write(tmp_path, "a.toml", HOVER.format(name="a") +
                 "[expect.estimation]\nposition_rmse_m_max = 1.0\n")
    with pytest.raises(ValueError, match="does not fly on the estimator"):
        load_scenario(path)
    path = write(tmp_path, "b.toml", HOVER.format(name="b") +
                 "[expect.path]\nall_reached = true\n")
    with pytest.raises(ValueError, match=r"scenario .*b.toml: expect.path: .*no \[mission\]"):
        load_scenario(path)


def test_every_shipped_scenario_carries_expectations():
    for name, scenario in shipped_scenarios().items():
        axes_limited = {lim.path[1] for lim in scenario.expect.limits if lim.path[0] == "axes"}
        assert axes_limited == set(scenario.axes), name
        assert scenario.expect.no_failsafe, name
    assert {e.kind for e in scenario_by_name("mission-six-waypoints").expect.events} == \
        {"landed", "disarmed"}


# -- verdicts --------------------------------------------------------------------------------

def test_limits_say_measured_against_limit():
    e = parse_expectations({"axes": {"x": {"rmse_max": 0.05}, "y": {"rmse_max": 0.025}},
                            "control": {"saturated_fraction_min": 0.02}}, AXES, 20.0)
    outcomes = evaluate(e, metrics())
    assert [o.passed for o in outcomes] == [True, True, False, False]
    y = outcome(outcomes, "axes.y.rmse <= 0.025")
    assert (y.measured, y.limit) == (0.03, 0.025)
    assert y.message == "axes.y.rmse = 0.03 > limit 0.025"
    assert outcome(outcomes, "control.saturated_fraction >= 0.02").message == \
        "control.saturated_fraction = 0.01 < limit 0.02"


def test_a_limit_on_what_was_not_measured_fails_and_says_why():
    e = parse_expectations({"timing": {"deadline_misses_max": 0}}, AXES, 20.0)
    [_, timing] = evaluate(e, metrics())
    assert not timing.passed
    assert "timing is measured in real-time runs only" in timing.message
    [_, timing] = evaluate(e, metrics(timing={"deadline_misses": 0}))
    assert timing.passed


def test_a_diverged_run_fails_its_first_outcome():
    [completed] = evaluate(parse_expectations({}, AXES, 20.0), metrics(diverged=True))
    assert (completed.name, completed.passed) == (COMPLETED, False)


def test_events_in_and_out_of_their_windows():
    e = parse_expectations({"event": [
        {"kind": "failsafe", "mode": "HOLD", "at_s": 12.0, "within_s": 1.5},
        {"kind": "failsafe", "mode": "HOLD", "at_s": 10.0, "within_s": 1.5},
        {"kind": "failsafe", "mode": "LAND"},
        {"kind": "statustext", "text": "gps LOST", "by_s": 12.0},
        {"kind": "disarmed", "by_s": 40.0},
        {"kind": "failsafe", "absent": True, "before_s": 12.0},
        {"kind": "failsafe", "absent": True},
    ]}, AXES, 60.0)
    _, hold, early, land, text, disarmed, none_early, none_at_all = evaluate(e, metrics())
    assert (hold.passed, hold.measured, hold.message) == (True, 12.4, "at t = 12.400 s")
    assert not early.passed
    assert early.message.endswith("it happened at t = 12.400 s, outside the window")
    assert not land.passed and "seen instead: HOLD at 12.40 s" in land.message
    assert text.passed and text.measured == 11.05
    assert not disarmed.passed and "it did not happen" in disarmed.message
    assert none_early.passed
    assert not none_at_all.passed and none_at_all.message == "happened at t = 12.400 s"


def test_no_failsafe():
    e = parse_expectations({"no_failsafe": True}, AXES, 20.0)
    [_, verdict] = evaluate(e, metrics())
    assert not verdict.passed
    assert verdict.message == "1 failsafe(s), expected 0; first at t = 12.40 s in HOLD"
    quiet = metrics()
    quiet["events"] = [ev for ev in quiet["events"] if ev["kind"] != "failsafe"]
    assert evaluate(e, quiet)[1].passed


def test_events_need_a_log():
    """An in-process run has no events: expectations on them fail, saying so."""
    e = parse_expectations({"no_failsafe": True, "event": [{"kind": "armed"}]}, AXES, 20.0)
    in_process = metrics()
    del in_process["events"]
    _, failsafe, armed = evaluate(e, in_process)
    assert not failsafe.passed and not armed.passed
    assert "events need the processes" in armed.message


def test_step_events_from_modes_flags_and_altitude():
    modes = [FlightMode.MISSION, FlightMode.MISSION, FlightMode.RTL, FlightMode.RTL,
             FlightMode.HOLD]
    index = np.array([list(FlightMode).index(m) for m in modes])
    flags = np.array([0, FLAG_ARMED, FLAG_ARMED | FLAG_FAILSAFE, FLAG_ARMED, 0])
    altitude = np.array([0.0, 0.0, 5.0, 0.5, 0.1])
    events = step_events(np.arange(5) * 0.5, index, flags, altitude)
    assert [(e.kind, e.t_s, e.mode) for e in events] == [
        ("mode", 0.0, "MISSION"), ("armed", 0.5, "MISSION"), ("mode", 1.0, "RTL"),
        ("failsafe", 1.0, "RTL"), ("mode", 2.0, "HOLD"), ("disarmed", 2.0, "HOLD"),
        ("landed", 2.0, "HOLD")]
    # Disarmed in the air is not a landing.
    events = step_events(np.arange(2) * 0.5, index[:2], np.array([FLAG_ARMED, 0]),
                         np.array([3.0, 3.0]))
    assert [e.kind for e in events] == ["mode", "armed", "disarmed"]


# -- baselines -------------------------------------------------------------------------------

def test_a_baseline_holds_an_identical_run_and_names_drift():
    now = metrics()
    assert compare_baseline(now, copy.deepcopy(now), 0.05).passed
    then = copy.deepcopy(now)
    then["axes"]["x"]["rmse"] = 0.018  # now 0.02: +11 %
    then["axes"]["y"]["rmse"] = 0.0299  # within 5 %
    verdict = compare_baseline(now, then, 0.05)
    assert not verdict.passed
    assert verdict.message == ("1 metric(s) moved beyond 5 %: axes.x.rmse: 0.02 against "
                               "0.018 (+11.1 %)")
    assert verdict.measured == pytest.approx(0.02 / 0.018 - 1)
    missing = compare_baseline(now, None, 0.05)
    assert not missing.passed and "no run of this scenario" in missing.message


def test_a_baseline_ignores_rounding_below_its_floor():
    now, then = metrics(), metrics()
    then["axes"]["z"]["rmse"] = 1e-5 + 1e-12
    assert compare_baseline(now, then, 0.0).passed


# -- reports ---------------------------------------------------------------------------------

def results(tmp_path: Path) -> list[ScenarioResult]:
    good = scenario_from_dict({**_hover("good"), "expect": {"axes": {"x": {"rmse_max": 0.05}}}},
                              tmp_path / "good.toml", tmp_path)
    bad = scenario_from_dict({**_hover("bad"), "expect": {"axes": {"y": {"rmse_max": 0.025}}}},
                             tmp_path / "bad.toml", tmp_path)
    broken = scenario_from_dict(_hover("broken"), tmp_path / "broken.toml", tmp_path)
    return [
        ScenarioResult(good, tmp_path / "good", evaluate(good.expect, metrics()), 1.5,
                       metrics()),
        ScenarioResult(bad, tmp_path / "bad", evaluate(bad.expect, metrics()), 2.0, metrics()),
        ScenarioResult(broken, tmp_path / "broken", [], 0.5, None,
                       error="the autopilot failed (exit 2):\nautopilot: error: boom"),
    ]


def _hover(name: str) -> dict:
    return {"name": name, "duration_s": 5.0, "reference": {"kind": "hover", "altitude_m": 1.0}}


def test_junit_is_read_by_a_junit_parser(tmp_path):
    path = tmp_path / "junit.xml"
    path.write_text(junit_xml(results(tmp_path)))
    xml = junitparser.JUnitXml.fromfile(str(path))
    suites = {suite.name: suite for suite in xml}
    assert list(suites) == ["good", "bad", "broken"]
    assert (suites["good"].tests, suites["good"].failures) == (2, 0)
    assert (suites["bad"].tests, suites["bad"].failures) == (2, 1)
    assert (suites["broken"].tests, suites["broken"].errors) == (1, 1)
    cases = {case.name: case for case in suites["bad"]}
    [failure] = cases["axes.y.rmse <= 0.025"].result
    assert isinstance(failure, junitparser.Failure)
    assert failure.message == "axes.y.rmse = 0.03 > limit 0.025"
    assert f"ivfm report {tmp_path / 'bad'}" in failure.text
    assert cases[COMPLETED].is_passed
    [error] = next(iter(suites["broken"])).result
    assert isinstance(error, junitparser.Error)
    assert error.message == "the autopilot failed (exit 2):"


def test_markdown_summary_and_table(tmp_path):
    rs = results(tmp_path)
    md = markdown_summary(rs, 4.0)
    assert md.startswith("## ivfm check: 1 of 3 scenarios passed (4.0 s)\n")
    assert "| bad | ❌ fail | 1 of 2 | 2.0 s | axes.y.rmse = 0.03 > limit 0.025 |" in md
    assert f"* `{tmp_path / 'bad'}`" in md
    table = results_table(rs)
    assert "x axes.y.rmse <= 0.025: axes.y.rmse = 0.03 > limit 0.025" in table
    assert "x the flight failed: the autopilot failed (exit 2):" in table


# -- collecting scenario files ---------------------------------------------------------------

def test_collect_folders_names_and_files(tmp_path):
    write(tmp_path, "a.toml", HOVER.format(name="a"))
    (tmp_path / "sub").mkdir()
    write(tmp_path / "sub", "b.toml", HOVER.format(name="b"))
    write(tmp_path, "airframe.toml", "name = 'mine'\nmass_kg = 1.0\n")  # not a scenario
    assert [s.name for s in collect([str(tmp_path)])] == ["a", "b"]
    assert [s.name for s in collect(["position-kick", str(tmp_path / "a.toml")])] == \
        ["position-kick", "a"]
    assert len(collect([])) == len(shipped_scenarios())
    with pytest.raises(ValueError, match="given twice: a"):
        collect([str(tmp_path / "a.toml"), str(tmp_path)])
    with pytest.raises(ValueError, match="unknown scenario 'nope'"):
        collect(["nope"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no scenario file"):
        collect([str(tmp_path / "empty")])


@pytest.mark.parametrize("argv", [
    ["check", "nope"],
    ["check", "position-kick", "--jobs", "0"],
    ["check", "position-kick", "--tolerance", "-1"],
    ["check", "position-kick", "--baseline", "/nonexistent/check.json"],
])
def test_check_refuses_bad_input_before_flying(argv, tmp_path, capsys):
    try:
        code = main([*argv, "--out", str(tmp_path / "out")])
    except SystemExit as exc:  # argparse refuses an option out of its range
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("ivfm: error: ") or "ivfm check: error: argument" in err
    assert not (tmp_path / "out").exists()


def test_a_scenario_from_a_dict_reads_back_with_its_files(tmp_path):
    plan = Path(__file__).parents[2] / "ground" / "scenario" / "shipped"
    scenario = scenario_from_dict({"name": "m", "mission": {"plan": "six-waypoints.plan"},
                                   "plant": {"fidelity": "rigid-body"},
                                   "expect": {"path": {"all_reached": True}}},
                                  tmp_path / "m.toml", plan)
    assert scenario.plan == (plan / "six-waypoints.plan").resolve()
    assert load_scenario(tmp_path / "m.toml").expect == scenario.expect
    with pytest.raises(ValueError, match="unknown field"):
        scenario_from_dict({"nam": "x"}, tmp_path / "x.toml", tmp_path)
