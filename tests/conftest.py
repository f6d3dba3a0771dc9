"""Shared fixtures: the shipped fuzzy model, loaded once; the MAVLink station (a vehicle's
server on loopback with a client, tests/mavlink_station.py)."""

from __future__ import annotations

import pytest

from autopilot.control.factory import load_models
from autopilot.models.ts_model import FuzzyModelSet
from tests.mavlink_station import Station

pytest_plugins = ["pytester"]  # for the tests of the ivfm pytest plugin (test_check.py)


@pytest.fixture(scope="session")
def shipped_models() -> FuzzyModelSet:
    return load_models(None)


@pytest.fixture
def make_station():
    """Stations with other links or parameters (``make_station(n_links=2)``), closed after."""
    made: list[Station] = []

    def make(**options) -> Station:
        made.append(Station(**options))
        return made[-1]

    yield make
    for s in made:
        s.close()


@pytest.fixture
def station(make_station) -> Station:
    return make_station()


def pytest_configure(config: pytest.Config) -> None:
    """The tiers' guard (tests/tiers.py): outside the process tier no test starts a process."""
    from tests import tiers

    if not config.pluginmanager.is_registered(tiers):
        config.pluginmanager.register(tiers, "tiers")
