"""Shared fixtures: the shipped fuzzy model, loaded once; the MAVLink station (a vehicle's
server on loopback with a client, tests/mavlink_station.py)."""

from __future__ import annotations

import pytest

from autopilot.control.factory import load_models
from autopilot.models.ts_model import FuzzyModelSet
from tests.mavlink_station import Station

# pytester for the tests of the ivfm pytest plugin (test_check.py); the process tier's
# scheduler (longest tests first, tests/scheduling.py)
pytest_plugins = ["pytester", "tests.scheduling"]


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


LOG_TAIL_LINES = 30


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    """A failed test that ran processes shows the end of their logs (the ``*.log`` files
    under its tmp_path): CI keeps no files, and a flake seen once must be explainable
    from its report alone."""
    report = yield
    tmp_path = getattr(item, "funcargs", {}).get("tmp_path")
    if report.failed and tmp_path is not None:
        for log in sorted(tmp_path.rglob("*.log"), reverse=True)[:6]:
            lines = log.read_text(errors="replace").splitlines()
            report.sections.append((f"{log.relative_to(tmp_path)} (last {LOG_TAIL_LINES} "
                                    f"lines)", "\n".join(lines[-LOG_TAIL_LINES:])))
    return report
