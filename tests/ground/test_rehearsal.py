"""``ivfm rehearse``: the static checks on good and deliberately bad airframes, the
readiness profile's refusals, and the outputs (Markdown, HTML, JUnit read back by
junitparser, QGroundControl's .params) of a rehearsal that flies nothing. The flights
through the processes are in tests/ground/test_rehearsal_flights.py."""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path

import junitparser
import pytest
import tomli_w

from autopilot.parameters import default_parameters, validate_parameters
from contracts.airframe_file import AirframeError, read_airframe
from ground.check.checker import ScenarioResult
from ground.cli.main import main
from ground.rehearsal.outputs import html_page, markdown, rehearsal_json, summary_lines
from ground.rehearsal.readiness import (
    airframe_checks,
    load_profile,
    parameter_checks,
    parse_profile,
)
from ground.rehearsal.rehearse import loop_window
from ground.rehearsal.results import FlightResult, Rehearsal
from ground.scenario.expectations import Outcome
from ground.scenario.scenario_file import load_scenario

X500 = Path(__file__).parents[2] / "contracts" / "airframes" / "quad-x-500.toml"


def x500_with(tmp_path: Path, name: str, rotor: dict | None = None,
              rotor_index: int | None = None) -> Path:
    """The shipped quad X 500 with rotor fields changed (all rotors, or one)."""
    data = tomllib.loads(X500.read_text())
    data["name"] = name
    for i, r in enumerate(data["rotor"]):
        if rotor and (rotor_index is None or i == rotor_index):
            r.update(rotor)
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def by_name(outcomes):
    return {o.name: o for o in outcomes}


def static(airframe) -> dict:
    profile = load_profile()
    return by_name(airframe_checks(read_airframe(airframe, controllable=False),
                                   default_parameters(), profile.airframe_limits))


def test_the_shipped_x500_passes_every_static_check():
    checks = static("quad-x-500")
    assert all(o.passed for o in checks.values()), [o.message for o in checks.values()]
    twr = checks["thrust-to-weight"]
    # 4 rotors x 8.55e-6 x 1000^2 = 34.2 N against 2.0 kg x 9.81.
    assert twr.measured == pytest.approx(34.2 / 19.62, rel=1e-9)
    # Hover at W/Wmax = sqrt(1 / TWR) on the speed map.
    assert checks["motor command at hover"].measured == pytest.approx(
        math.sqrt(19.62 / 34.2), rel=1e-9)
    tilt = math.radians(default_parameters()["MPC_TILTMAX_AIR"])
    assert checks["thrust margin at full tilt"].measured == pytest.approx(
        1 - 19.62 / math.cos(tilt) / 34.2, rel=1e-9)


def test_thrust_to_weight_1_2_fails_thrust_and_hover_command(tmp_path):
    weak = x500_with(tmp_path, "weak", {"max_rad_s": 1000.0 * math.sqrt(1.2 / (34.2 / 19.62))})
    checks = static(weak)
    assert not checks["thrust-to-weight"].passed
    assert checks["thrust-to-weight"].measured == pytest.approx(1.2, rel=1e-6)
    assert checks["thrust-to-weight"].message.startswith("thrust-to-weight 1.2 < limit 1.5")
    assert not checks["motor command at hover"].passed  # sqrt(1 / 1.2) = 0.913
    assert checks["motor command at hover"].measured == pytest.approx(0.9129, abs=1e-4)
    assert checks["rotor spins"].passed and checks["motor time constant"].passed


def test_a_rotor_spun_the_wrong_way_fails_spins_and_hover(tmp_path):
    wrong = x500_with(tmp_path, "wrong-spin", {"spin": "ccw"}, rotor_index=3)
    with pytest.raises(AirframeError, match="1 rotor\\(s\\) spin cw and 3 ccw"):
        read_airframe(wrong)  # a flight refuses it, and says why
    checks = static(wrong)
    assert not checks["rotor spins"].passed
    assert checks["rotor spins"].message == ("rotor spins do not cancel: cw 3, ccw 1, 2, 4 "
                                             "(a quad needs two of each)")
    assert not checks["airframe"].passed
    assert "not measurable" in checks["thrust-to-weight"].message
    assert checks["motor time constant"].passed


def test_same_spins_side_by_side_fail(tmp_path):
    """Rotor 1 (front right) cw and 3 (front left) ccw, swapped with 4 and 2: two of each,
    but not diagonally opposite."""
    path = x500_with(tmp_path, "side-by-side", {"spin": "cw"}, rotor_index=0)
    data = tomllib.loads(path.read_text())
    data["rotor"][2]["spin"] = "ccw"  # front left
    path.write_text(tomli_w.dumps(data))
    checks = static(path)
    assert not checks["rotor spins"].passed
    assert "side by side" in checks["rotor spins"].message


def test_a_slow_motor_fails_the_time_constant(tmp_path):
    slow = x500_with(tmp_path, "slow", {"time_constant_s": 0.2}, rotor_index=2)
    checks = static(slow)
    lag = checks["motor time constant"]
    assert not lag.passed and lag.measured == 0.2
    assert lag.message == "motor time constant 0.2 s > limit 0.05 s (rotor 3)"
    assert all(o.passed for n, o in checks.items() if n != "motor time constant")


def test_parameters_outside_their_safe_range_fail():
    profile = load_profile()
    flown = validate_parameters({"SYS_FAILURE_EN": 1.0, "MPC_TILTMAX_AIR": 60.0})
    checks = by_name(parameter_checks(flown, profile.parameter_ranges))
    assert not checks["parameter SYS_FAILURE_EN"].passed
    assert checks["parameter MPC_TILTMAX_AIR"].message == (
        "MPC_TILTMAX_AIR = 60 outside the safe range [5, 45]")
    assert sum(not o.passed for o in checks.values()) == 2
    # A larger tilt costs thrust margin: at 60 deg the x500 needs 39.2 N of its 34.2 N.
    air = by_name(airframe_checks(read_airframe("quad-x-500"), flown, profile.airframe_limits))
    assert not air["thrust margin at full tilt"].passed


@pytest.mark.parametrize("data, message", [
    ({"colour": 1}, "unknown field"),
    ({"airframe": {"thrust_to_weight": 2}}, "unknown limit"),
    ({"airframe": {"thrust_to_weight_min": math.nan}}, "finite number"),
    ({"parameters": {"NOT_A_PARAM": [0, 1]}}, "no such parameter"),
    ({"parameters": {"MPC_TILTMAX_AIR": [50, 10]}}, "min 50 above max 10"),
    ({"parameters": {"MPC_TILTMAX_AIR": 10}}, "must be \\[min, max\\]"),
    ({"flight": [{"realtime": True}]}, "scenario must be the path"),
    ({"flight": [{"scenario": "a.toml", "realtime": "yes"}]}, "realtime must be true"),
    ({"flight": [{"scenario": "a.toml", "when": 1}]}, "unknown field"),
])
def test_bad_profiles_are_refused_with_the_field_named(data, message):
    with pytest.raises(ValueError, match=message):
        parse_profile(data, Path("mine.toml"), "profile mine.toml")


def test_the_shipped_profile_names_flights_that_load():
    from ground.scenario.scenario_file import load_scenario

    profile = load_profile()
    assert [f.scenario.stem for f in profile.flights] == [
        "takeoff-hold-land", "tracking", "wind", "weak-motor", "gps-loss", "geofence",
        "gcs-loss", "setpoint-loss", "sim-stall", "timing"]
    assert [f.realtime for f in profile.flights] == [False] * 6 + [True] * 4
    for flight in profile.flights:
        scenario = load_scenario(flight.scenario)
        assert scenario.expect.limits or scenario.expect.events, scenario.name
        assert flight.advice


def test_a_no_go_rehearsal_writes_every_output_and_exits_1(tmp_path, capsys):
    """An airframe that cannot hover: no flight is flown, every output says why."""
    wrong = x500_with(tmp_path, "wrong-spin", {"spin": "ccw"}, rotor_index=3)
    out = tmp_path / "rehearsal"
    assert main(["rehearse", "--airframe", str(wrong), "--out", str(out),
                 "--param", "SYS_FAILURE_EN=1"]) == 1
    printed = capsys.readouterr().out
    assert printed.startswith("rehearsal of wrong-spin: NO-GO")
    assert "x static: rotor spins do not cancel" in printed
    assert "x flights: the airframe cannot hover: no flight was flown" in printed
    md = (out / "rehearsal.md").read_text()
    assert md.startswith("# Rehearsal of wrong-spin: **NO-GO**")
    assert "| static: parameter SYS_FAILURE_EN | SYS_FAILURE_EN = 1 outside" in md
    page = (out / "rehearsal.html").read_text()
    assert "<div class='verdict nogo' id='verdict'>NO-GO</div>" in page
    assert not re.search(r"(src|href)=['\"]https?:", page)  # self-contained
    xml = junitparser.JUnitXml.fromfile(str(out / "rehearsal.xml"))
    suites = {s.name: s for s in xml}
    assert set(suites) == {"static", "timing", "takeoff-hold-land", "tracking", "wind",
                           "weak-motor", "gps-loss", "geofence", "gcs-loss",
                           "setpoint-loss", "sim-stall"}
    assert suites["static"].failures == 6 and suites["wind"].errors == 1
    rows = [line.split("\t") for line in (out / "parameters.params").read_text().splitlines()
            if not line.startswith("#")]
    values = {name: float(value) for _v, _c, name, value, kind in rows}
    assert all(r[0] == "1" and r[1] == "1" and r[4] == "9" for r in rows)
    # The airframe file's own parameter (the x500's CMDF_ACC_MAX), then the command line's.
    assert values == validate_parameters({"CMDF_ACC_MAX": 20.0, "SYS_FAILURE_EN": 1.0})


@pytest.mark.parametrize("argv, message", [
    (["--airframe", "no-such-frame"], "unknown airframe"),
    (["--airframe", "quad-x-500", "--rate-hz", "-5"], r"must be a number in \[1, 1000\] Hz"),
    (["--airframe", "quad-x-500", "--profile", "missing.toml"], "no such file"),
    (["--airframe", "quad-x-500", "--param", "MPC_TILTMAX_AIR=100"], "MPC_TILTMAX_AIR"),
])
def test_bad_input_exits_2_with_the_problem_named(tmp_path, capsys, argv, message):
    out = tmp_path / "r"
    try:
        code = main(["rehearse", *argv, "--out", str(out)])
    except SystemExit as exc:  # argparse's refusal
        code = exc.code
    assert code == 2
    assert re.search(message, capsys.readouterr().err)
    assert not (out / "rehearsal.html").exists()


def test_the_tilt_rate_metric_catches_the_x500_limit_cycle(tmp_path):
    """The shipped quad X 500 hovering on its IVFM model, kicked 0.3 rad in pitch: at the
    paper's CMDF_ACC_MAX (8 rad/s^2) roll/pitch keep swinging (the desired-angle filter
    saturates: a limit cycle), which the rehearsal's tilt_rate_rms_rad_s limit (0.5)
    fails; at the airframe file's own 20 rad/s^2 the swing dies out. In process."""
    from autopilot.control.factory import load_models
    from autopilot.parameters import airframe_parameters
    from contracts.airframe import airframe_by_name
    from ground.report.metrics import compute_metrics
    from ground.run.inprocess import run_inprocess
    from ground.scenario.scenario_file import scenario_from_dict

    assert airframe_parameters(read_airframe("quad-x-500")) == {"CMDF_ACC_MAX": 20.0}
    data = tomllib.loads((Path(__file__).parents[2] / "ground/rehearsal/profiles/flights/wind.toml")
                         .read_text())
    data["perturbation"] = [{"kind": "kick", "theta_rad": 0.3, "start_s": 5.0, "end_s": 5.5}]
    data["transient_s"] = 10.0
    scenario = scenario_from_dict(data, tmp_path / "kick.toml", tmp_path)
    models = load_models(None, read_airframe("quad-x-500"))
    rates = {}
    for acc in (8.0, 20.0):
        record = run_inprocess(scenario, "ivfc", "rigid-body", airframe_by_name("quad-x-500"),
                               models, period_s=0.01, parameters={"CMDF_ACC_MAX": acc})
        rates[acc] = compute_metrics(record, scenario, "quad-x-500")["control"][
            "tilt_rate_rms_rad_s"]
    assert rates[8.0] > 1.0  # measured 1.21 rad/s
    assert rates[20.0] < 0.01


def _timing_rehearsal(tmp_path: Path, reference: dict) -> Rehearsal:
    """A rehearsal whose timing flight missed 5 deadlines (limit 3), with the reference
    sleeper's figures beside it; nothing flown."""
    profile = load_profile()
    timing = next(f for f in profile.flights if f.scenario.stem == "timing")
    failed = Outcome("timing.deadline_misses <= 3", False, 5, 3.0,
                     "timing.deadline_misses = 5 > limit 3")
    result = ScenarioResult(load_scenario(timing.scenario), tmp_path / "timing",
                            outcomes=[failed], wall_time_s=11.0,
                            metrics={"timing": {"deadline_misses": 5,
                                                "sim_stall_steps": 7}})
    r = Rehearsal("quad-x-500", "quad-x-500", profile, 250.0, None, "shipped", {})
    r.flights.append(FlightResult(timing, result, reference))
    return r


MACHINE_MISSED = {"source": "cyclictest", "scheduling": "SCHED_FIFO priority 50",
                  "cpus": "CPU 0", "period_ms": 4.0, "note": "", "wakeups": 2490,
                  "lost_periods": 4, "late_wakeups": 2, "worst_ms": 9.125, "p99_ms": 0.081,
                  "p50_ms": 0.031, "window": "the autopilot's loop", "window_s": 10.0}


def test_a_timing_no_go_says_whether_the_machine_alone_missed_too(tmp_path):
    """The reference lost periods in the same seconds: the failed timing check says so
    before its advice, and every output carries both figures. The verdict is unchanged
    (information, not a rule)."""
    r = _timing_rehearsal(tmp_path, MACHINE_MISSED)
    assert r.verdict == "NO-GO"
    ((group, outcome, advice),) = r.failed_checks()
    assert group == "timing" and outcome.name.startswith("timing.deadline_misses")
    assert advice.startswith("In the same 10 s the reference sleeper (cyclictest) lost 4 "
                             "period(s), its worst wake-up 9.1 ms late: the machine misses "
                             "deadlines with none of our code. A faster or quieter machine")
    md = markdown(r)
    assert "## Deadlines beside the machine's own" in md
    assert ("| timing | 5 | 7 | 4 | 9.12 ms | 0.081 ms | the autopilot's loop, 10.0 s, 2490 "
            "wake-ups |") in md
    assert "| flight | autopilot deadline misses | autopilot steps held (simulator stalls) |" in md
    assert "The reference sleeper (cyclictest, SCHED_FIFO priority 50, CPU 0, every 4 ms)" in md
    page = html_page(r, tmp_path)
    assert "<table id='reference'>" in page and "<td>9.12 ms</td>" in page
    (flight,) = rehearsal_json(r)["flights"]
    assert flight["deadline_misses"] == 5 and flight["steps_held"] == 7
    assert flight["reference"]["lost_periods"] == 4
    assert flight["machine"].startswith("in the same 10 s the reference sleeper")
    assert any("the machine misses deadlines with none of our code" in line
               for line in summary_lines(r))


def test_a_timing_no_go_with_a_quiet_machine_says_it_kept_time(tmp_path):
    kept = {**MACHINE_MISSED, "lost_periods": 0, "late_wakeups": 0, "worst_ms": 0.412}
    ((_, _, advice),) = _timing_rehearsal(tmp_path, kept).failed_checks()
    assert advice.startswith("In the same 10 s the reference sleeper (cyclictest) lost none "
                             "(worst wake-up 0.41 ms late): the machine kept time. ")
    failed = _timing_rehearsal(tmp_path, {"error": "cyclictest did not run: refused"})
    assert ("| timing | 5 | 7 | not run |  |  | cyclictest did not run: refused |"
            in markdown(failed))


def test_the_loop_window_comes_from_the_runs_timeline(tmp_path):
    """The run's timeline counts from the flight's start (time.monotonic 1000 s here):
    the autopilot's first and last control steps bound the reference's count."""
    (tmp_path / "timeline.json").write_text(json.dumps({"events": [
        {"t_s": 0.0, "process": "ground", "event": "command start"},
        {"t_s": 0.8, "process": "autopilot", "event": "first control step"},
        {"t_s": 10.8, "process": "autopilot", "event": "last control step"}]}))
    assert loop_window(tmp_path, 1000.0) == (1000.8, 1010.8)
    (tmp_path / "timeline.json").write_text(json.dumps({"events": [
        {"t_s": 0.8, "process": "autopilot", "event": "first control step"}]}))
    assert loop_window(tmp_path, 1000.0) == (1000.8, math.inf)  # failed before the last
    assert loop_window(tmp_path / "none", 1000.0) is None
