"""Mission scenarios: a QGroundControl plan flown in AUTO.MISSION from the ground through
the processes in lockstep (``[mission] plan`` in a scenario file), with the path metrics
of ground/metrics.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ground.metrics import compute_metrics, distance_to_path
from ground.processes import RunSettings, fly
from ground.scenarios import load_scenario, scenario_by_name


@pytest.fixture(scope="module")
def six_waypoint_runs(tmp_path_factory):
    """The shipped six-waypoint mission flown twice."""
    scenario = scenario_by_name("mission-six-waypoints")
    settings = RunSettings("ivfc", scenario.plant, scenario.airframe)
    out = tmp_path_factory.mktemp("missions")
    return scenario, fly(scenario, settings, out / "a")[0], fly(scenario, settings, out / "b")[0]


@pytest.mark.process
def test_six_waypoints_at_5_mps_in_lockstep(six_waypoint_runs):
    scenario, record, _ = six_waypoint_runs
    metrics = compute_metrics(record, scenario, "paper")
    path = metrics["path"]
    assert path["all_reached"] and path["items"] == [0, 1, 2, 3, 4, 5, 6]
    # Golden: every waypoint within its acceptance radius; the corners are rounded inside
    # it (NAV_ACC_RAD 2 m) at the corner speed, as PX4 flies them, so the path leaves the
    # legs by up to 0.38 m (0.077 m when it stopped at every corner).
    assert path["cross_track_rmse_m"] == pytest.approx(0.0879, abs=0.002)
    assert path["cross_track_max_m"] == pytest.approx(0.384, abs=0.01)
    assert path["arrival_s"][1] == pytest.approx(11.93, abs=0.1)
    assert np.all(np.diff(path["arrival_s"]) > 0)
    # Landed on the last waypoint (home) and stayed there.
    assert np.linalg.norm(record.measurement[-1, 0:3]) < 0.01
    speed = np.hypot(record.measurement[:, 3], record.measurement[:, 4])
    assert speed.max() == pytest.approx(5.0, abs=0.15)  # MPC_XY_CRUISE


@pytest.mark.process
def test_a_mission_repeats_bit_for_bit_in_lockstep(six_waypoint_runs):
    _, a, b = six_waypoint_runs
    np.testing.assert_array_equal(a.measurement, b.measurement)
    np.testing.assert_array_equal(a.motor_commands, b.motor_commands)


def test_the_cross_track_of_a_path_is_the_distance_to_its_nearest_leg():
    path = np.array([(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0)])
    points = np.array([(5.0, 1.0, 0.0), (11.0, 5.0, 0.0), (12.0, -1.0, 0.0), (10.0, 0.0, 2.0)])
    assert np.allclose(distance_to_path(points, path), (1.0, 1.0, np.sqrt(5.0), 2.0))


@pytest.mark.parametrize("text, error", [
    ('[mission]\nplan = "missing.plan"\n', "missing.plan: no such file"),
    ('[mission]\nplan = 3\n', "mission.plan must be the path of a .plan file"),
    ('[mission]\nplan = "ok.plan"\nspeed = 3\n', "mission: unknown field"),
    ('[mission]\nplan = "ok.plan"\n[reference]\nkind = "hover"\n',
     "a scenario flies a [mission] or a [reference], not both"),
    ('[mission]\nplan = "empty.plan"\n', "has no mission items"),
])
def test_bad_mission_scenarios_are_refused_with_the_field(tmp_path, text, error):
    plan = {"fileType": "Plan", "version": 1, "mission": {"items": []}}
    (tmp_path / "empty.plan").write_text(json.dumps(plan))
    shipped = scenario_by_name("mission-six-waypoints").plan
    (tmp_path / "ok.plan").write_text(shipped.read_text())
    path = tmp_path / "mine.toml"
    path.write_text('name = "mine"\n' + text)
    with pytest.raises(ValueError, match=error.replace("[", r"\[").replace("]", r"\]")):
        load_scenario(path)


def test_a_mission_scenario_is_not_flown_in_process():
    from ground.inprocess import run_inprocess

    scenario = scenario_by_name("mission-six-waypoints")
    with pytest.raises(ValueError, match="flies a mission"):
        run_inprocess(scenario, "ivfc", "rigid-body", None)
