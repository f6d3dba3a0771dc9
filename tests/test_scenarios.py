"""Scenario regression: every controller finishes every scenario on both plants, the
paper's tracking targets hold for IVFC, and runs are deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.control.factory import CONTROLLERS
from contracts.airframe import PAPER
from ground.inprocess import run_inprocess
from ground.metrics import compute_metrics
from ground.scenarios import PAPER_SCENARIOS, shipped_scenarios

PLANTS = ("paper", "rigid-body")


@pytest.fixture(scope="module")
def all_metrics(shipped_models):
    out = {}
    for plant in PLANTS:
        for name in PAPER_SCENARIOS:
            scenario = shipped_scenarios()[name]
            for controller in CONTROLLERS:
                record = run_inprocess(scenario, controller, plant, PAPER, shipped_models)
                out[(plant, name, controller)] = compute_metrics(record, scenario, "paper")
    return out


def rmse(metrics, plant, scenario, controller, axis) -> float:
    return metrics[(plant, scenario, controller)]["axes"][axis]["rmse"]


def test_every_controller_finishes_every_scenario_on_both_plants(all_metrics) -> None:
    for key, m in all_metrics.items():
        assert not m["diverged"], key
        assert m["sim_time_s"] == pytest.approx(20.0), key
        for axis, values in m["axes"].items():
            limit = 0.5 if axis in ("x", "y", "z") else 0.15  # rad: attitude-hold's steps
            assert values["rmse"] < limit, (key, axis, values)


def test_ivfc_tracks_attitude_sine_within_paper_target(all_metrics) -> None:
    for axis in ("phi", "theta"):
        assert rmse(all_metrics, "paper", "attitude-sine", "ivfc", axis) <= 0.01


def test_ivfc_tracks_position_sine_within_paper_target(all_metrics) -> None:
    for axis in ("x", "y"):
        assert rmse(all_metrics, "paper", "position-sine", "ivfc", axis) <= 0.05


@pytest.mark.parametrize("scenario", ["attitude-jr-10", "attitude-jr-15", "attitude-jr-20"])
def test_ivfc_keeps_tracking_under_inertia_perturbation(all_metrics, scenario) -> None:
    """Regression threshold. The IVFC-vs-T1FC ordering (the paper's Table 4) is reported by
    `ivfm compare`, not asserted: here it holds on phi and psi but not on theta."""
    for plant in PLANTS:
        for axis in ("phi", "theta", "psi"):
            assert rmse(all_metrics, plant, scenario, "ivfc", axis) <= 0.02, (plant, axis)


def test_metrics_hold_required_fields(all_metrics) -> None:
    m = all_metrics[("paper", "position-kick", "ivfc")]
    for key in ("scenario", "controller", "plant", "sim_time_s", "wall_time_s"):
        assert key in m
    assert set(m["axes"]) == {"x", "y", "z", "psi"}
    assert m["control"]["chattering_total_variation"] > 0
    assert m["control"]["effort_mean_sum_c2"] > 0


@pytest.mark.parametrize("plant", PLANTS)
def test_runs_are_bit_for_bit_reproducible(shipped_models, plant: str) -> None:
    scenario = shipped_scenarios()["position-kick"]
    a = run_inprocess(scenario, "ivfc", plant, PAPER, shipped_models)
    b = run_inprocess(scenario, "ivfc", plant, PAPER, shipped_models)
    assert np.array_equal(a.measurement, b.measurement)
    assert np.array_equal(a.motor_commands, b.motor_commands)
    assert all(np.array_equal(x, y) for x, y in zip(a.theta_f, b.theta_f, strict=True))


def test_perturbation_window_reaches_the_plant(shipped_models) -> None:
    """attitude-jr-20 differs from attitude-sine only inside [12, 14] s and after it."""
    base = run_inprocess(shipped_scenarios()["attitude-sine"], "smc", "paper", PAPER)
    pert = run_inprocess(shipped_scenarios()["attitude-jr-20"], "smc", "paper", PAPER)
    before = base.time_s <= 12.0
    assert np.array_equal(base.measurement[before], pert.measurement[before])
    assert not np.array_equal(base.measurement[~before], pert.measurement[~before])
