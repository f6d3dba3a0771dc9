"""DroneKit (PyPI ``dronekit2``) uploads, downloads and flies a mission through
``vehicle.commands`` against the real processes in the ArduPilot-Copter flavour, as its
own mission examples do against ArduPilot's SITL: home is item 0 of what it downloads,
it answers the vehicle's MISSION_REQUEST with MISSION_ITEM, and the mission flies in AUTO
after a GUIDED take-off, ``vehicle.commands.next`` following MISSION_CURRENT."""

from __future__ import annotations

import math
import time

import pytest
from dronekit import Command, VehicleMode, connect
from pymavlink import mavutil

from contracts.frames import DEFAULT_HOME
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

M = mavutil.mavlink
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT
WAYPOINTS_NE_M = ((12.0, 0.0), (12.0, 12.0))  # north, east of home [m]
ALT_M = 5.0


def _until(check, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def _mission() -> list[Command]:
    cmds = [Command(0, 0, 0, REL, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 0, ALT_M)]
    for north, east in WAYPOINTS_NE_M:
        lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north, east, 0.0)
        cmds.append(Command(0, 0, 0, REL, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, 0, 0, lat, lon,
                            ALT_M))
    return cmds


def _north_east_m(vehicle) -> tuple[float, float]:
    loc = vehicle.location.global_frame
    n, e, _ = DEFAULT_HOME.ned_from_geodetic(loc.lat, loc.lon, DEFAULT_HOME.alt_amsl_m)
    return n, e


def test_dronekit_mission_round_trip_then_flown_in_auto(tmp_path):
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle = connect(f"udpin:127.0.0.1:{procs.gcs_port}", wait_ready=False,
                          heartbeat_timeout=30)
        vehicle.wait_ready("parameters", "armed", "mode", "attitude", timeout=60)
        cmds = vehicle.commands
        cmds.download()
        cmds.wait_ready()
        assert cmds.count == 0  # an empty mission: home alone, item 0
        home = vehicle.home_location
        assert (home.lat, home.lon) == pytest.approx((DEFAULT_HOME.lat_deg,
                                                      DEFAULT_HOME.lon_deg), abs=4e-6)
        assert home.alt == pytest.approx(DEFAULT_HOME.alt_amsl_m, abs=0.01)

        cmds.clear()
        for cmd in _mission():
            cmds.add(cmd)
        cmds.upload(timeout=20)
        # Downloaded again, the vehicle's list: home, then the three items as sent.
        cmds.download()
        cmds.wait_ready()
        assert cmds.count == 3
        sent = _mission()
        for got, want in zip(cmds, sent, strict=True):
            assert (got.command, got.frame) == (want.command, want.frame)
            assert (got.x, got.y, got.z) == pytest.approx((want.x, want.y, want.z), abs=4e-6)

        vehicle.mode = VehicleMode("GUIDED")
        _until(lambda: vehicle.mode.name == "GUIDED", 10, "GUIDED")
        vehicle.armed = True
        _until(lambda: vehicle.armed, 10, "armed")
        vehicle.simple_takeoff(ALT_M)
        _until(lambda: vehicle.location.global_relative_frame.alt > ALT_M - 0.3, 30,
               "take-off altitude")
        reached = []
        vehicle.add_message_listener("MISSION_ITEM_REACHED",
                                     lambda _v, _name, msg: reached.append(msg.seq))
        vehicle.mode = VehicleMode("AUTO")
        _until(lambda: vehicle.mode.name == "AUTO", 10, "AUTO")
        nexts = set()

        def at_last_waypoint() -> bool:
            nexts.add(cmds.next)
            n, e = _north_east_m(vehicle)
            return math.hypot(n - WAYPOINTS_NE_M[-1][0], e - WAYPOINTS_NE_M[-1][1]) < 1.0 \
                and 3 in reached
        _until(at_last_waypoint, 60, "the last waypoint reached")
        assert reached[:3] == [1, 2, 3]  # numbered after home, as Copter numbers them
        assert {2, 3} <= nexts  # commands.next followed MISSION_CURRENT
        assert vehicle.location.global_relative_frame.alt == pytest.approx(ALT_M, abs=0.5)
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()
