"""DroneKit (PyPI ``dronekit2``) flies the PX4 flavour as it flies PX4 SITL: PX4 mode
names (``vehicle.mode = "TAKEOFF"``, ``"OFFBOARD"``, ``"LAND"``), arming through
``vehicle.armed`` and offboard setpoints sent with its message factory.
"""

from __future__ import annotations

import threading
import time

import pytest
from dronekit import VehicleMode
from pymavlink import mavutil

from tests.dronekit_helpers import CONNECT_BUDGET_S, connect, wait_for
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


def _until(check, timeout_s: float, what: str) -> None:
    wait_for(what, check, timeout_s)


def _stream_setpoints(vehicle, target: list[float], stop: threading.Event) -> None:
    """SET_POSITION_TARGET_LOCAL_NED at 20 Hz, as a DroneKit offboard script sends it."""
    while not stop.is_set():
        vehicle.send_mavlink(vehicle.message_factory.set_position_target_local_ned_encode(
            0, 0, 0, mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000,
            *target, 0, 0, 0, 0, 0, 0, 0, 0))
        time.sleep(0.05)


def test_a_dronekit_px4_script_takes_off_flies_offboard_and_lands(tmp_path):
    procs = start_processes(tmp_path)
    vehicle = None
    stop = threading.Event()
    try:
        vehicle, connect_s = connect(procs.gcs_port)
        print(f"dronekit connect(wait_ready=True) to the PX4 flavour: {connect_s:.2f} s")
        assert connect_s < CONNECT_BUDGET_S
        assert vehicle._autopilot_type == mavutil.mavlink.MAV_AUTOPILOT_PX4
        assert vehicle.mode.name == "LOITER"  # HOLD is PX4's AUTO.LOITER
        _until(lambda: vehicle.gps_0.fix_type == 3, 5, "a 3D fix in GPS_RAW_INT")
        # No is_armable: DroneKit reads it from ArduPilot's EKF_STATUS_REPORT, which PX4
        # does not send (PX4 SITL reads False there too).

        vehicle.armed = True
        _until(lambda: vehicle.armed, 10, "armed")
        vehicle.mode = VehicleMode("TAKEOFF")
        _until(lambda: vehicle.mode.name == "TAKEOFF", 5, "TAKEOFF mode")
        # MIS_TAKEOFF_ALT (2.5 m); PX4 holds (LOITER) at the top.
        _until(lambda: vehicle.location.global_relative_frame.alt > 2.3, 20, "2.3 m")
        _until(lambda: vehicle.mode.name == "LOITER", 15, "LOITER after take-off")
        assert abs(vehicle.location.global_relative_frame.alt - 2.5) < 0.15

        target = [3.0, -2.0, -3.0]
        streamer = threading.Thread(target=_stream_setpoints, args=(vehicle, target, stop),
                                    daemon=True)
        streamer.start()
        time.sleep(0.5)  # PX4 takes OFFBOARD only once setpoints stream
        vehicle.mode = VehicleMode("OFFBOARD")
        _until(lambda: vehicle.mode.name == "OFFBOARD", 5, "OFFBOARD mode")

        def near(north: float, east: float, down: float) -> bool:
            here = vehicle.location.local_frame
            return (here.north is not None and abs(here.north - north) < 0.15
                    and abs(here.east - east) < 0.15 and abs(here.down - down) < 0.15)

        _until(lambda: near(*target), 25, f"offboard setpoint {target}")

        vehicle.mode = VehicleMode("LAND")
        _until(lambda: vehicle.mode.name == "LAND", 5, "LAND mode")
        stop.set()
        _until(lambda: not vehicle.armed, 40, "disarmed after landing")
        here = vehicle.location.local_frame
        assert abs(here.north - 3.0) < 0.3 and abs(here.east + 2.0) < 0.3
        assert vehicle.location.global_relative_frame.alt < 0.2
    finally:
        stop.set()
        if vehicle is not None:
            vehicle.close()
        procs.stop()
