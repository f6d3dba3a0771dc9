"""One scenario flown through the processes with home at four places on Earth (Zurich,
the equator, 60 N, 45 S across the antimeridian) tracks the same in the local frame."""

from __future__ import annotations

import pytest

from contracts.frames import Home

pytestmark = pytest.mark.process

HOMES = {"zurich": Home(47.397742, 8.545594, 488.0), "equator": Home(0.0, 0.0, 0.0),
         "60N": Home(60.0, 10.0, 100.0), "45S-antimeridian": Home(-45.0, 179.9999, 50.0)}


def _fly_everywhere(tmp_path, state_source: str) -> dict[str, dict]:
    from ground.run.flights import Overrides, fly_processes, plan_flight
    from ground.run.loader import ProcessLoader
    from ground.scenario.scenario_file import scenario_by_name

    scenario = scenario_by_name("position-kick")
    loader = ProcessLoader()
    try:
        return {place: fly_processes(
            plan_flight(scenario, Overrides(home=home, state_source=state_source)),
            tmp_path / f"{state_source}-{place}", figures=False, quiet=True, loader=loader)
            for place, home in HOMES.items()}
    finally:
        loader.close()


def test_the_same_flight_anywhere_on_earth(tmp_path):
    """On ODOMETRY (local NED, as our simulator sends it) the tracking figures are the
    same at every place, to 1e-6 m (and rad)."""
    import json

    metrics = _fly_everywhere(tmp_path, "odometry")
    zurich = metrics["zurich"]["axes"]
    for place, m in metrics.items():
        run = json.loads((tmp_path / f"odometry-{place}" / "run.json").read_text())
        assert run["home"] == list(HOMES[place])
        for axis, figures in m["axes"].items():
            assert figures["rmse"] == pytest.approx(zurich[axis]["rmse"], abs=1e-6), (place,
                                                                                     axis)
            assert figures["max_abs"] == pytest.approx(zurich[axis]["max_abs"], abs=1e-6)
