"""Copter's parameters from the ground tools ArduPilot users script with, against the
real processes in the ArduPilot flavour: DroneKit (``dronekit2``) reads, sets and
watches them and the vehicle flies by them; MAVProxy's ``param set`` changes one and
the landing follows it."""

from __future__ import annotations

import math
import time

import pytest

from autopilot.copter_parameters import ardupilot_parameters
from tests.groundtools.test_mavproxy import Prompt
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

ARDUPILOT = ["--flavour", "ardupilot"]


def _until(check, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if value := check():
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def test_dronekit_reads_sets_and_watches_copter_parameters_and_rtl_climbs_to_rtl_alt(
        tmp_path):
    from dronekit import VehicleMode, connect

    procs = start_processes(tmp_path, autopilot_args=ARDUPILOT)
    vehicle = None
    try:
        vehicle = connect(f"udpin:127.0.0.1:{procs.gcs_port}", wait_ready=False,
                          heartbeat_timeout=60, source_system=255)
        vehicle.wait_ready("parameters", "armed", "mode", "attitude", timeout=90)
        params = vehicle.parameters
        assert len(params) == len(ardupilot_parameters())
        # Copter's names and units over the vehicle's values
        assert params["WPNAV_SPEED"] == pytest.approx(500.0)  # cm/s: 5 m/s
        assert params["RTL_ALT"] == 1000.0  # cm: 10 m
        assert params["ANGLE_MAX"] == 2005.0  # centidegrees
        heard: list[tuple[str, float]] = []
        params.add_attribute_listener("RTL_ALT", lambda _, name, value:
                                      heard.append((name, value)))
        params["RTL_ALT"] = 600  # 6 m; DroneKit waits for the vehicle's PARAM_VALUE
        assert params["RTL_ALT"] == 600.0
        _until(lambda: ("RTL_ALT", 600.0) in heard, 5, "the RTL_ALT listener")
        params["WPNAV_SPEED"] = 250
        assert params["WPNAV_SPEED"] == pytest.approx(250.0)

        vehicle.mode = VehicleMode("GUIDED")
        _until(lambda: vehicle.mode.name == "GUIDED", 10, "GUIDED")
        vehicle.armed = True
        _until(lambda: vehicle.armed, 10, "armed")
        vehicle.simple_takeoff(2.0)
        _until(lambda: vehicle.location.global_relative_frame.alt > 1.9, 30, "2 m")
        vehicle.mode = VehicleMode("RTL")
        highest = 0.0
        deadline = time.monotonic() + 40
        while vehicle.armed and time.monotonic() < deadline:
            highest = max(highest, vehicle.location.global_relative_frame.alt or 0.0)
            time.sleep(0.1)
        assert not vehicle.armed, "RTL did not land and disarm"
        # RTL climbs to RTL_ALT (6 m, not the 10 m default; reached within NAV_MC_ALT_RAD
        # 0.8 m) before it returns and lands
        assert 5.2 < highest < 6.5, highest
        print(f"RTL's highest altitude with RTL_ALT 600: {highest:.2f} m")
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()


def test_mavproxy_param_set_land_speed_slows_the_landing(tmp_path):
    procs = start_processes(tmp_path, autopilot_args=ARDUPILOT)
    prompt = Prompt(procs.gcs_port, tmp_path / "mavproxy")
    try:
        prompt.child.expect(rf"Received {len(ardupilot_parameters())} parameters",
                            timeout=60)
        prompt.type("param show LAND_SPEED", r"LAND_SPEED\s+70\.0")
        prompt.type("param watch LAND_SPEED")
        prompt.type("param set LAND_SPEED 30", r"> LAND_SPEED=30\.0")  # the echo
        prompt.type("param show LAND_SPEED", r"LAND_SPEED\s+30\.0")
        # Out of what this vehicle flies: refused in Copter's units, the value kept.
        prompt.type("param set LAND_SPEED 5000",
                    r"Param write denied \(LAND_SPEED\): 5000 is outside 10\.\.300 cm/s")
        prompt.type("param show LAND_SPEED", r"LAND_SPEED\s+30\.0")
        prompt.wait_for_gps_lock()  # telemetry streams once MAVProxy has asked for them
        prompt.type("mode GUIDED", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        prompt.type("arm throttle", r"(?<!DIS)ARMED")
        prompt.type("takeoff 3", r"Got COMMAND_ACK: NAV_TAKEOFF: ACCEPTED")
        _until(lambda: prompt.relative_altitude_m() > 2.9, 30, "3 m")
        start = time.monotonic()
        prompt.type("mode LAND", r"Mode LAND")
        prompt.child.expect(r"DISARMED", timeout=40)
        landing_s = time.monotonic() - start
        # 3 m at 0.3 m/s is 10 s (at the default 0.7 m/s: 4.3 s)
        assert 9.0 < landing_s < 16.0, landing_s
        assert math.isclose(prompt.relative_altitude_m(), 0.0, abs_tol=0.1)
        print(f"landing from 3 m with LAND_SPEED 30: {landing_s:.1f} s")
    finally:
        prompt.close()
        procs.stop()
