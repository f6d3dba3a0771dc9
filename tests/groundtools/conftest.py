"""Fixtures of the ground-tool tests."""

from __future__ import annotations

import fcntl
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from contracts.mavlink import API_UDP_PORT
from tests import dronekit_helpers
from tests.scheduling import takes_turns


@pytest.fixture
def ardupilot_dialect() -> Iterator[None]:
    """pymavlink's dialect is ardupilotmega while the test's DroneKit runs."""
    with dronekit_helpers.ardupilot_dialect():
        yield


API_PORT_LOCK = Path(tempfile.gettempdir()) / "ivfm-sitl-udp-14540.lock"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The process tier's scheduler sends the lock's users one at a time
    (tests/scheduling.py ONE_AT_A_TIME): each must be listed there."""
    for item in items:
        if "api_port_14540" in getattr(item, "fixturenames", ()) and \
                not takes_turns(item.nodeid):
            raise pytest.UsageError(f"{item.nodeid} holds UDP port 14540: list its file in "
                                    "tests/scheduling.py ONE_AT_A_TIME")


@pytest.fixture
def api_port_14540() -> Iterator[int]:
    """MAVSDK's own examples listen on udpin 14540, a fixed port: one test at a time on
    this machine, whichever pytest worker runs it (an exclusive lock on a file; held for
    the test's whole run, released by the kernel if the worker dies). xdist's groups do
    not do it: with pytest 9 and xdist 3.8 they spread a group over the workers."""
    with open(API_PORT_LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.bind(("0.0.0.0", API_UDP_PORT))  # nothing else listens there now
            yield API_UDP_PORT
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
