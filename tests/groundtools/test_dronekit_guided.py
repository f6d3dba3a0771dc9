"""DroneKit-Python (PyPI ``dronekit2``) flies the real processes in the ArduPilot-Copter
flavour, as its own guide's "taking off" and "going somewhere" scripts fly ArduCopter SITL:
GUIDED, arm, ``simple_takeoff``, two ``simple_goto`` (MISSION_ITEM current=2), RTL.

Each step asserts what the vehicle did (where it is, as its own telemetry says), not only
that a call returned.
"""

from __future__ import annotations

import math
import time

import pytest

from tests.dronekit_helpers import connect, location_at, offset_m, wait_for
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


def test_dronekit_guided_takeoff_two_gotos_rtl_and_landing(tmp_path, ardupilot_dialect):
    import dronekit

    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle, _connect_s = connect(procs.gcs_port)
        assert vehicle.mode.name == "STABILIZE"  # Copter boots in STABILIZE
        assert not vehicle.armed
        vehicle.mode = dronekit.VehicleMode("GUIDED")
        wait_for("GUIDED", lambda: vehicle.mode.name == "GUIDED", 10)
        wait_for("a position", lambda: vehicle.location.global_frame.lat is not None, 20)
        home = vehicle.location.global_relative_frame
        wait_for("is_armable", lambda: vehicle.is_armable, 20)  # as DroneKit's guide does
        vehicle.armed = True
        wait_for("armed", lambda: vehicle.armed, 10)
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
            vehicle.simple_goto(location_at(home, north, east, alt))

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
