"""DroneKit-Python (PyPI ``dronekit2``) flies the real processes in the ArduPilot-Copter
flavour, as its own guide's "taking off" and "going somewhere" scripts fly ArduCopter SITL:
GUIDED, arm, ``simple_takeoff``, two ``simple_goto`` (MISSION_ITEM current=2), RTL.

Each step asserts what the vehicle did (where it is, as its own telemetry says), not only
that a call returned.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import pytest

from tests.harness import start_processes

dronekit = pytest.importorskip("dronekit")

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

EARTH_M_PER_DEG = 111_319.5  # metres per degree of latitude (and of longitude at 0 deg)


def wait_for(what: str, predicate: Callable[[], bool], timeout_s: float) -> float:
    """Poll until ``predicate`` holds; the seconds it took."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout_s:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.1)
    return time.monotonic() - start


def offset_m(home, here) -> tuple[float, float]:
    """North and east metres of ``here`` from ``home`` (flat Earth: tens of metres)."""
    north = (here.lat - home.lat) * EARTH_M_PER_DEG
    east = (here.lon - home.lon) * EARTH_M_PER_DEG * math.cos(math.radians(home.lat))
    return north, east


def test_dronekit_guided_takeoff_two_gotos_rtl_and_landing(tmp_path):
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle = dronekit.connect(f"udpin:127.0.0.1:{procs.gcs_port}", wait_ready=False,
                                   heartbeat_timeout=60)
        vehicle.wait_ready("parameters", "armed", "mode", "attitude", timeout=60)
        assert vehicle.mode.name == "STABILIZE"  # Copter boots in STABILIZE
        assert not vehicle.armed
        vehicle.mode = dronekit.VehicleMode("GUIDED")
        wait_for("GUIDED", lambda: vehicle.mode.name == "GUIDED", 10)
        wait_for("a position", lambda: vehicle.location.global_frame.lat is not None, 20)
        home = vehicle.location.global_relative_frame
        # DroneKit's guide waits for is_armable (GPS_RAW_INT and EKF_STATUS_REPORT) first;
        # until the vehicle sends those, ask again while the simulator's state comes up
        # (refused meanwhile with Copter's "PreArm: Need Position Estimate").
        deadline = time.monotonic() + 40
        while not vehicle.armed:
            assert time.monotonic() < deadline, "never armed"
            vehicle.armed = True
            time.sleep(1.0)
        assert vehicle.mode.name == "GUIDED"

        vehicle.simple_takeoff(10)
        here = vehicle.location.global_relative_frame
        took = wait_for("10 m", lambda: here.alt is not None and abs(
            vehicle.location.global_relative_frame.alt - 10.0) < 0.3, 60)
        print(f"take-off to 10 m: {took:.1f} s")
        time.sleep(1.0)
        here = vehicle.location.global_relative_frame
        assert abs(here.alt - 10.0) < 0.3
        assert max(abs(v) for v in offset_m(home, here)) < 0.5  # straight up
        assert vehicle.mode.name == "GUIDED"

        # Two go-tos, each reached: 20 m north at 10 m, then 15 m east of that at 12 m.
        for north, east, alt in ((20.0, 0.0, 10.0), (20.0, 15.0, 12.0)):
            target = dronekit.LocationGlobalRelative(
                home.lat + north / EARTH_M_PER_DEG,
                home.lon + east / (EARTH_M_PER_DEG * math.cos(math.radians(home.lat))), alt)
            vehicle.simple_goto(target)

            def there(north=north, east=east, alt=alt) -> bool:
                here = vehicle.location.global_relative_frame
                n, e = offset_m(home, here)
                return math.hypot(n - north, e - east) < 0.5 and abs(here.alt - alt) < 0.3

            took = wait_for(f"{north} N {east} E {alt} m", there, 40)
            print(f"go-to {north} N {east} E {alt} m: {took:.1f} s")
            time.sleep(1.0)
            assert there(), vehicle.location.global_relative_frame  # and it stays there

        vehicle.mode = dronekit.VehicleMode("RTL")
        wait_for("RTL", lambda: vehicle.mode.name == "RTL", 10)
        took = wait_for("landed and disarmed", lambda: not vehicle.armed, 120)
        here = vehicle.location.global_relative_frame
        north, east = offset_m(home, here)
        print(f"RTL to disarmed: {took:.1f} s, {north:.2f} N {east:.2f} E of home, "
              f"{here.alt} m up")
        assert max(abs(v) for v in offset_m(home, here)) < 1.0, here  # at home
        assert here.alt < 0.2
        time.sleep(1.5)
        assert vehicle.mode.name == "RTL" and not vehicle.armed  # Copter stays in RTL
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()
