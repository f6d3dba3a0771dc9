"""DroneKit-Python (``dronekit2``) moves home in the ArduPilot-Copter flavour as its guide
does (``vehicle.home_location = LocationGlobal(...)``: MAV_CMD_DO_SET_HOME, param1 0,
AMSL), and the vehicle's own telemetry shows it: HOME_POSITION at the new home, altitudes
above it, and an RTL that lands there. The local origin stays (docs/mavlink.md, "Home
apart from the local origin")."""

from __future__ import annotations

import pytest

from tests.dronekit_helpers import connect, location_at, offset_m, wait_for
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

NEW_NORTH_M, NEW_EAST_M, NEW_BELOW_M = 20.0, 10.0, 3.0  # home 3 m below the ground


def test_dronekit_home_location_moves_home_and_rtl_lands_there(tmp_path, ardupilot_dialect):
    import dronekit

    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle, _connect_s = connect(procs.gcs_port)
        homes: list = []
        vehicle.add_message_listener("HOME_POSITION", lambda _v, _n, msg: homes.append(msg))
        vehicle.mode = dronekit.VehicleMode("GUIDED")
        wait_for("GUIDED", lambda: vehicle.mode.name == "GUIDED", 10)
        wait_for("a position", lambda: vehicle.location.global_frame.lat is not None, 20)
        # Armable: the vehicle has its origin and a position (Copter refuses a home
        # before its EKF origin is set, FAILED).
        wait_for("is_armable", lambda: vehicle.is_armable, 20)
        vehicle.commands.download()  # as DroneKit's guide reads home_location
        vehicle.commands.wait_ready()
        old = vehicle.home_location
        assert old is not None
        start = vehicle.location.global_relative_frame
        assert abs(start.alt) < 0.2  # on the ground at the first home

        there = location_at(old, NEW_NORTH_M, NEW_EAST_M, 0.0)
        new = dronekit.LocationGlobal(there.lat, there.lon, old.alt - NEW_BELOW_M)
        vehicle.home_location = new
        # The vehicle says so: HOME_POSITION at the new place (COMMAND_LONG's float32
        # degrees: within half a metre), and altitudes above home from it.
        wait_for("HOME_POSITION at the new home", lambda: any(
            max(abs(v) for v in offset_m(new, dronekit.LocationGlobal(
                m.latitude / 1e7, m.longitude / 1e7, 0.0))) < 0.5 for m in homes), 10)
        assert abs(homes[-1].altitude / 1000 - new.alt) < 0.01
        wait_for("relative altitude from the new home", lambda: abs(
            vehicle.location.global_relative_frame.alt - NEW_BELOW_M) < 0.2, 10)
        vehicle.commands.download()
        vehicle.commands.wait_ready()
        assert max(abs(v) for v in offset_m(new, vehicle.home_location)) < 0.5  # item 0

        vehicle.armed = True
        wait_for("armed", lambda: vehicle.armed, 10)
        vehicle.simple_takeoff(10)  # 10 m above the new home: 7 m above the ground
        took = wait_for("10 m above home", lambda: abs(
            vehicle.location.global_relative_frame.alt - 10.0) < 0.3, 60)
        amsl = vehicle.location.global_frame.alt
        print(f"take-off: {took:.1f} s, {amsl - old.alt:.2f} m above the first home")
        assert abs(amsl - old.alt - (10.0 - NEW_BELOW_M)) < 0.3

        vehicle.mode = dronekit.VehicleMode("RTL")
        wait_for("RTL", lambda: vehicle.mode.name == "RTL", 10)
        took = wait_for("landed and disarmed", lambda: not vehicle.armed, 120)
        here = vehicle.location.global_relative_frame
        north, east = offset_m(new, here)
        print(f"RTL to disarmed: {took:.1f} s, {north:.2f} N {east:.2f} E of the new home, "
              f"{here.alt} m above it")
        assert max(abs(north), abs(east)) < 1.0, here  # landed at the new home
        assert abs(here.alt - NEW_BELOW_M) < 0.2  # on the ground, 3 m above home
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()
