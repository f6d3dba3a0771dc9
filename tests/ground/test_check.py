"""``ivfm check`` and the pytest plugin as users run them: real processes, a folder of
scenario files, a JUnit file read back by junitparser, a baseline, a failure's run folder
opened again by ``ivfm report``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import junitparser
import pytest

from tests.lockstep_fingerprint import log_digests

pytestmark = pytest.mark.process

SCENARIO = """name = "{name}"
duration_s = 4.0
axes = ["x", "y", "z", "psi"]
transient_s = 1.0

[reference]
kind = "position-sine"
altitude_m = 1.0
yaw_rad = 0.2

[expect]
no_failsafe = true

[expect.axes]
x = {{ rmse_max = {x_rmse_max} }}
z = {{ max_abs_max = 0.001 }}

[[expect.event]]
kind = "armed"
by_s = 0.5
"""


def ivfm(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ground.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def first_check(tmp_path_factory):
    """A folder of two scenarios, one whose x limit is broken on purpose, checked with
    two at a time."""
    root = tmp_path_factory.mktemp("check")
    scenarios = root / "scenarios"
    scenarios.mkdir()
    (scenarios / "holds.toml").write_text(SCENARIO.format(name="holds", x_rmse_max=0.5))
    (scenarios / "broken.toml").write_text(SCENARIO.format(name="broken", x_rmse_max=1e-4))
    done = ivfm("check", str(scenarios), "--out", str(root / "out"), "--junit",
                str(root / "junit.xml"), "--summary", str(root / "summary.md"), "-j", "2",
                cwd=root)
    return root, done


def test_check_exits_1_and_junit_names_measured_and_limit(first_check):
    root, done = first_check
    assert done.returncode == 1, done.stderr
    xml = junitparser.JUnitXml.fromfile(str(root / "junit.xml"))
    suites = {suite.name: suite for suite in xml}
    assert set(suites) == {"holds", "broken"}
    assert (suites["holds"].tests, suites["holds"].failures) == (5, 0)
    assert (suites["broken"].tests, suites["broken"].failures) == (5, 1)
    [failed] = [case for case in suites["broken"] if not case.is_passed]
    assert failed.name == "axes.x.rmse <= 0.0001"
    [failure] = failed.result
    measured = json.loads((root / "out" / "check.json").read_text())[
        "scenarios"]["broken"]["metrics"]["axes"]["x"]["rmse"]
    assert failure.message == f"axes.x.rmse = {measured:.6g} > limit 0.0001"
    assert re.search(r"^broken +FAIL +4/5 ", done.stdout, re.MULTILINE)
    assert re.search(r"^holds +PASS +5/5 ", done.stdout, re.MULTILINE)
    assert "1 of 2 passed" in done.stdout
    assert "| broken | ❌ fail | 4 of 5 |" in (root / "summary.md").read_text()


def test_failed_run_folders_are_kept_and_report_again(first_check):
    root, _ = first_check
    assert not (root / "out" / "holds").exists()
    kept = root / "out" / "broken"
    assert (kept / "run.json").is_file() and list(kept.glob("*.mcap"))
    before = json.loads((kept / "metrics.json").read_text())
    (kept / "metrics.json").unlink()
    again = ivfm("report", str(kept), "--no-figures", cwd=root)
    assert again.returncode == 0, again.stderr
    after = json.loads((kept / "metrics.json").read_text())
    assert after["axes"] == before["axes"] and after["events"] == before["events"]
    assert {"kind": "armed", "t_s": 0.0, "mode": "REFERENCE"} in after["events"]


def test_a_baseline_catches_drift(first_check):
    """The same scenario again is bit for bit the same: within 0 % of its baseline; a
    baseline whose x error was 20 % larger is drift."""
    root, _ = first_check
    baseline = json.loads((root / "out" / "check.json").read_text())
    x = baseline["scenarios"]["holds"]["metrics"]["axes"]["x"]
    x["rmse"] *= 1.2
    (root / "drifted.json").write_text(json.dumps(baseline))
    done = ivfm("check", str(root / "scenarios" / "holds.toml"), "--out", str(root / "again"),
                "--baseline", str(root / "out"), "--tolerance", "0", "--junit",
                str(root / "same.xml"), cwd=root)
    assert done.returncode == 0, done.stdout + done.stderr
    done = ivfm("check", str(root / "scenarios" / "holds.toml"), "--out",
                str(root / "drift"), "--baseline", str(root / "drifted.json"), cwd=root)
    assert done.returncode == 1
    assert "axes.x.rmse: " in done.stdout and "(-16.7 %)" in done.stdout


PLUGIN_TEST = '''
def test_a_dict_flies(ivfm_flight):
    flight = ivfm_flight({"name": "dict-hover", "duration_s": 3.0,
                          "reference": {"kind": "hover", "altitude_m": 1.0},
                          "expect": {"axes": {"z": {"rmse_max": 0.01}}}})
    flight.assert_expectations()
    assert flight.metrics["sim_time_s"] == 3.0
    assert [e["kind"] for e in flight.events][:2] == ["mode", "armed"]
'''


def test_pytest_collects_scenario_files_and_the_fixture_flies(pytester):
    """A user's suite: a folder with a scenario file (an expectation broken on purpose)
    and a test using the fixture; the plugin comes from the installed entry point."""
    pytester.makefile(".toml", broken=SCENARIO.format(name="broken", x_rmse_max=1e-4))
    pytester.makepyfile(test_flights=PLUGIN_TEST)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-q", "--junitxml",
                                           "junit.xml")
    result.assert_outcomes(passed=5, failed=1)
    result.stdout.fnmatch_lines(["*broken.toml::axes.x.rmse <= 0.0001*",
                                 "axes.x.rmse = * > limit 0.0001"])
    xml = junitparser.JUnitXml.fromfile(str(pytester.path / "junit.xml"))
    names = sorted(case.name for suite in xml for case in suite)
    assert "axes.x.rmse <= 0.0001" in names and "test_a_dict_flies" in names


def test_runs_in_progress_together_fly_one_per_place(tmp_path):
    """Three at a time: a run's processes start and reports are written while others
    fly, but no more loops run at once than there are places to fly (one per CPU), and
    every run flies as it would alone."""
    from ground.check.checker import flights_at_once

    for name in ("one", "two", "three"):
        (tmp_path / f"{name}.toml").write_text(SCENARIO.format(name=name, x_rmse_max=0.5))
    done = ivfm("check", *(str(tmp_path / f"{n}.toml") for n in ("one", "two", "three")),
                "--out", str(tmp_path / "out"), "--keep", "-j", "3", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"3 at a time, {flights_at_once(3)} flying" in done.stderr
    loops, digests = [], set()
    for name in ("one", "two", "three"):
        timeline = json.loads((tmp_path / "out" / name / "timeline.json").read_text())
        at = {(e["process"], e["event"]): e["t_s"] for e in timeline["events"]}
        origin = timeline["origin_monotonic_s"]
        loops.append((origin + at["autopilot", "first control step"],
                      origin + at["autopilot", "last control step"]))
        assert timeline["phases_s"]["waiting to fly"] >= 0.0
        digests.add(json.dumps(log_digests(tmp_path / "out" / name)))
    most = max(sum(start <= t < end for start, end in loops) for t, _ in loops)
    assert 1 <= most <= flights_at_once(3), loops
    assert len(digests) == 1  # the same scenario: the same records, however it waited


def test_forked_runs_are_bit_identical_to_a_fresh_process_run(tmp_path):
    """A simulator, autopilot and logger forked by one process loader fly position-kick
    after another scenario: the log's records are the same bytes as a run of fresh
    processes, and every run had processes of its own."""
    from ground.run.flights import fly_processes, plan_flight
    from ground.run.loader import ProcessLoader
    from ground.scenario.scenario_file import scenario_by_name
    from tests.lockstep_fingerprint import log_digests

    kick = plan_flight(scenario_by_name("position-kick"))
    loader = ProcessLoader()
    try:
        fly_processes(plan_flight(scenario_by_name("attitude-jr-20")), tmp_path / "first",
                      figures=False, quiet=True, loader=loader)
        forked_metrics = fly_processes(kick, tmp_path / "forked", figures=False, quiet=True,
                                       loader=loader)
    finally:
        loader.close()
    assert loader.alive is False
    cold_metrics = fly_processes(kick, tmp_path / "cold", figures=False, quiet=True)
    assert log_digests(tmp_path / "forked") == log_digests(tmp_path / "cold")
    assert forked_metrics["axes"] == cold_metrics["axes"]
    assert forked_metrics["events"] == cold_metrics["events"]
    modules = [module for module, _ in loader.started]
    assert modules == ["ground.cli", "sitl", "autopilot"] * 2
    assert len({pid for _, pid in loader.started}) == 6  # new processes for each run
