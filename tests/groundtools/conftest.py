"""Fixtures of the ground-tool tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests import dronekit_helpers


@pytest.fixture
def ardupilot_dialect() -> Iterator[None]:
    """pymavlink's dialect is ardupilotmega while the test's DroneKit runs."""
    with dronekit_helpers.ardupilot_dialect():
        yield
