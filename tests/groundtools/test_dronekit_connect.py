"""DroneKit (PyPI ``dronekit2``, ``import dronekit``) connects to the ArduPilot flavour as
it connects to ArduCopter SITL: ``connect(wait_ready=True)`` completes, and what it reads
(version, armability, home, modes) is what the vehicle is. The PX4 flavour:
test_dronekit_px4.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink import mavutil

from tests.dronekit_helpers import CONNECT_BUDGET_S, connect, wait_for
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


def test_dronekit_connects_to_the_ardupilot_flavour_reboots_and_calibrates(tmp_path,
                                                                        ardupilot_dialect):
    # Where ArduPilot's SITL and the scripts written for it are: CMAC, by name.
    procs = start_processes(tmp_path, sim_args=["--home", "CMAC"],
                            autopilot_args=["--flavour", "ardupilot"])
    vehicle = None
    try:
        vehicle, connect_s = connect(procs.gcs_port)
        print(f"dronekit connect(wait_ready=True) to the ArduPilot flavour: {connect_s:.2f} s")
        assert connect_s < CONNECT_BUDGET_S
        wait_for("is_armable", lambda: vehicle.is_armable, 10.0)
        # AUTOPILOT_VERSION answers DroneKit's capability request on the next heartbeat.
        wait_for("AUTOPILOT_VERSION", lambda: vehicle.version.major is not None, 5.0)
        assert str(vehicle.version) == "APM:Copter-4.5.7"
        assert vehicle.capabilities.flight_termination and not vehicle.capabilities.ftp
        assert vehicle._autopilot_type == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert vehicle.gps_0.fix_type == 3 and vehicle.gps_0.satellites_visible == 10
        assert vehicle.ekf_ok and vehicle.system_status.state == "STANDBY"
        # Home as DroneKit's documentation has a script read it: download the commands
        # (item 0 is home in Copter). A HOME_POSITION the vehicle sent when home was set
        # reached DroneKit only when DroneKit's socket was open before the vehicle started.
        vehicle.commands.download()
        vehicle.commands.wait_ready(timeout=10)
        home = vehicle.home_location
        here = vehicle.location.global_frame
        # Item 0 is a MISSION_ITEM (DroneKit downloads without the INT items): float32.
        assert abs(home.lat - here.lat) < 4e-6 and abs(home.lon - here.lon) < 8e-6
        assert (home.lat, home.lon, home.alt) == tuple(
            float(np.float32(v)) for v in (-35.363261, 149.16523, 584.0))
        assert vehicle.mode.name == "STABILIZE" and not vehicle.armed  # Copter boots so

        acks: list[tuple[int, int]] = []
        vehicle.add_message_listener(
            "COMMAND_ACK", lambda _v, _n, m: acks.append((m.command, m.result)))
        for send in (vehicle.send_calibrate_gyro, vehicle.send_calibrate_accelerometer,
                     vehicle.send_calibrate_barometer):
            send()
        cal = mavutil.mavlink.MAV_CMD_PREFLIGHT_CALIBRATION
        wait_for("three calibration ACKs", lambda: acks.count((cal, 0)) == 3, 5.0)

        texts: list[str] = []
        vehicle.add_message_listener("STATUSTEXT", lambda _v, _n, m: texts.append(m.text))
        vehicle.reboot()
        reboot = mavutil.mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
        wait_for("the reboot's ACK", lambda: (reboot, 0) in acks, 5.0)
        wait_for("the boot texts", lambda: "Frame: QUAD/X" in texts, 5.0)
        assert texts[-3:] == ["rebooted", "ArduCopter V4.5.7 (ivfmsitl)", "Frame: QUAD/X"]
        # After the reboot: disarmed, in STABILIZE again, streams restarted by DroneKit's own
        # request, home announced again, still armable.
        wait_for("is_armable after the reboot", lambda: vehicle.is_armable, 10.0)
        assert not vehicle.armed and vehicle.mode.name == "STABILIZE"
    finally:
        if vehicle is not None:
            vehicle.close()
        procs.stop()
