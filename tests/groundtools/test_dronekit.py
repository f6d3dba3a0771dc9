"""DroneKit (PyPI ``dronekit2``, ``import dronekit``) connects to the real processes as it
connects to ArduCopter SITL and to PX4 SITL: ``connect(wait_ready=True)`` completes, and
what it reads (version, armability, home, modes) is what the vehicle is.
"""

from __future__ import annotations

import time

import pytest
from pymavlink import mavutil

from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

dronekit = pytest.importorskip("dronekit")

# From the processes' start: measured 2-7 s on two loaded CPUs; a first run on a cold
# cache (the controller's compiled code) took 30 s, as MAVProxy's tests allow 40 s.
CONNECT_BUDGET_S = 45.0


@pytest.fixture
def ardupilot_dialect():
    """DroneKit parses with pymavlink's process-wide dialect; the harness picks common.
    ArduPilot's (a superset) while DroneKit runs, then back."""
    mavutil.set_dialect("ardupilotmega")
    yield
    mavutil.set_dialect("common")


def _connect(port: int):
    start = time.monotonic()
    vehicle = dronekit.connect(f"udpin:127.0.0.1:{port}", wait_ready=True,
                               heartbeat_timeout=CONNECT_BUDGET_S, timeout=CONNECT_BUDGET_S)
    return vehicle, time.monotonic() - start


def _wait(predicate, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


def test_dronekit_connects_to_the_ardupilot_flavour_reboots_and_calibrates(
        tmp_path, ardupilot_dialect):
    # Where ArduPilot's SITL and the scripts written for it are: CMAC, by name.
    procs = start_processes(tmp_path, sim_args=["--home", "CMAC"],
                            autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle, connect_s = _connect(procs.gcs_port)
        print(f"dronekit connect(wait_ready=True) to the ArduPilot flavour: {connect_s:.2f} s")
        assert connect_s < CONNECT_BUDGET_S
        _wait(lambda: vehicle.is_armable, 10.0, "is_armable")
        # AUTOPILOT_VERSION answers DroneKit's capability request on the next heartbeat.
        _wait(lambda: vehicle.version.major is not None, 5.0, "AUTOPILOT_VERSION")
        assert str(vehicle.version) == "APM:Copter-4.5.7"
        assert vehicle.capabilities.flight_termination and not vehicle.capabilities.ftp
        assert vehicle._autopilot_type == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert vehicle.gps_0.fix_type == 3 and vehicle.gps_0.satellites_visible == 10
        assert vehicle.ekf_ok and vehicle.system_status.state == "STANDBY"
        _wait(lambda: vehicle.home_location is not None, 10.0, "HOME_POSITION")
        home = vehicle.home_location
        here = vehicle.location.global_frame
        assert abs(home.lat - here.lat) < 1e-6 and abs(home.lon - here.lon) < 1e-6
        assert (home.lat, home.lon, home.alt) == (-35.363261, 149.16523, 584.0)
        assert vehicle.mode.name == "GUIDED" and not vehicle.armed

        acks: list[tuple[int, int]] = []
        vehicle.add_message_listener(
            "COMMAND_ACK", lambda _v, _n, m: acks.append((m.command, m.result)))
        for send in (vehicle.send_calibrate_gyro, vehicle.send_calibrate_accelerometer,
                     vehicle.send_calibrate_barometer):
            send()
        cal = mavutil.mavlink.MAV_CMD_PREFLIGHT_CALIBRATION
        _wait(lambda: acks.count((cal, 0)) == 3, 5.0, "three calibration ACKs")

        texts: list[str] = []
        vehicle.add_message_listener("STATUSTEXT", lambda _v, _n, m: texts.append(m.text))
        vehicle.reboot()
        reboot = mavutil.mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
        _wait(lambda: (reboot, 0) in acks, 5.0, "the reboot's ACK")
        _wait(lambda: "Frame: QUAD/X" in texts, 5.0, "the boot texts")
        assert texts[-3:] == ["rebooted", "ArduCopter V4.5.7 (ivfmsitl)", "Frame: QUAD/X"]
        # After the reboot: disarmed, still GUIDED, streams restarted by DroneKit's own
        # request, home announced again, still armable.
        _wait(lambda: vehicle.is_armable, 10.0, "is_armable after the reboot")
        assert not vehicle.armed and vehicle.mode.name == "GUIDED"
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()


def test_dronekit_connects_to_the_px4_flavour_and_reads_its_modes(tmp_path):
    procs = start_processes(tmp_path)
    vehicle = None
    try:
        vehicle, connect_s = _connect(procs.gcs_port)
        print(f"dronekit connect(wait_ready=True) to the PX4 flavour: {connect_s:.2f} s")
        assert vehicle._autopilot_type == mavutil.mavlink.MAV_AUTOPILOT_PX4
        _wait(lambda: vehicle.gps_0.fix_type == 3, 5.0, "a 3D fix in GPS_RAW_INT")
        assert vehicle.mode.name == "LOITER"  # HOLD, PX4's AUTO.LOITER
        # A PX4-mode script: arm, TAKEOFF (to MIS_TAKEOFF_ALT), then LOITER, then LAND.
        _wait(lambda: vehicle.is_armable or vehicle.gps_0.fix_type == 3, 5.0, "armable")
        vehicle.armed = True
        _wait(lambda: vehicle.armed, 5.0, "armed")
        vehicle.mode = dronekit.VehicleMode("TAKEOFF")
        _wait(lambda: vehicle.mode.name == "TAKEOFF", 5.0, "mode TAKEOFF")
        _wait(lambda: vehicle.location.global_relative_frame.alt > 2.0, 20.0, "climbing")
        _wait(lambda: vehicle.mode.name == "LOITER", 30.0, "LOITER after the take-off")
        vehicle.mode = dronekit.VehicleMode("LAND")
        _wait(lambda: vehicle.mode.name == "LAND", 5.0, "mode LAND")
        _wait(lambda: not vehicle.armed, 60.0, "landed and disarmed")
        assert vehicle.location.global_relative_frame.alt < 0.5
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()

