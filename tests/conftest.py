"""Shared fixtures: the shipped fuzzy model, loaded once."""

from __future__ import annotations

import pytest

from autopilot.control.factory import load_models
from autopilot.models.ts_model import FuzzyModelSet

pytest_plugins = ["pytester"]  # for the tests of the ivfm pytest plugin (test_check.py)


@pytest.fixture(scope="session")
def shipped_models() -> FuzzyModelSet:
    return load_models(None)


def pytest_configure(config: pytest.Config) -> None:
    """The tiers' guard (tests/tiers.py): outside the process tier no test starts a process."""
    from tests import tiers

    if not config.pluginmanager.is_registered(tiers):
        config.pluginmanager.register(tiers, "tiers")
