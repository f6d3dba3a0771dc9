"""Shared fixtures: the shipped fuzzy model, loaded once."""

from __future__ import annotations

import pytest

from autopilot.identification.ts_model import FuzzyModelSet
from ground.commands import load_models


@pytest.fixture(scope="session")
def shipped_models() -> FuzzyModelSet:
    return load_models(None)
