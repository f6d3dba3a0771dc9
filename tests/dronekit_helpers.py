"""DroneKit (PyPI ``dronekit2``, ``import dronekit``) against the real processes: connect
as its guide does (``wait_ready=True``), and wait for what the vehicle does."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from pymavlink import mavutil

# From the processes' start: measured 2-7 s on two loaded CPUs; a first run on a cold
# cache (the controller's compiled code) took 30 s, as MAVProxy's tests allow 40 s.
CONNECT_BUDGET_S = 45.0
EARTH_M_PER_DEG = 111_319.5  # metres per degree of latitude (and of longitude at 0 deg)


@contextmanager
def ardupilot_dialect() -> Iterator[None]:
    """DroneKit parses with pymavlink's process-wide dialect, and the harness picks common;
    ArduPilot's (a superset: EKF_STATUS_REPORT for is_armable) while DroneKit runs (the
    tests use it as the ``ardupilot_dialect`` fixture of tests/groundtools/conftest.py)."""
    mavutil.set_dialect("ardupilotmega")
    try:
        yield
    finally:
        mavutil.set_dialect("common")


def connect(port: int):
    """``dronekit.connect(wait_ready=True)`` on the test's ground port, and the seconds it
    took (DroneKit's own parameters, GPS, mode, arming and attitude all read)."""
    import dronekit

    start = time.monotonic()
    vehicle = dronekit.connect(f"udpin:127.0.0.1:{port}", wait_ready=True,
                               heartbeat_timeout=CONNECT_BUDGET_S, timeout=CONNECT_BUDGET_S)
    return vehicle, time.monotonic() - start


def wait_for(what: str, predicate: Callable[[], bool], timeout_s: float) -> float:
    """Poll until ``predicate`` holds; the seconds it took."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout_s:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)
    return time.monotonic() - start


def offset_m(home, here) -> tuple[float, float]:
    """North and east metres of ``here`` from ``home`` (flat Earth: tens of metres)."""
    north = (here.lat - home.lat) * EARTH_M_PER_DEG
    east = (here.lon - home.lon) * EARTH_M_PER_DEG * math.cos(math.radians(home.lat))
    return north, east


def location_at(home, north_m: float, east_m: float, alt_m: float):
    """A LocationGlobalRelative ``north_m`` / ``east_m`` from ``home``, ``alt_m`` above it."""
    import dronekit

    return dronekit.LocationGlobalRelative(
        home.lat + north_m / EARTH_M_PER_DEG,
        home.lon + east_m / (EARTH_M_PER_DEG * math.cos(math.radians(home.lat))), alt_m)
