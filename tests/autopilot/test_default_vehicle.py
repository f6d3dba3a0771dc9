"""The vehicle ``python -m sitl`` / ``python -m autopilot`` give ground tools when no
airframe is named is PX4 SITL's: the x500-sized quad X. A script written against PX4
that holds an attitude at PX4-typical thrust (0.55 of full) stays near its altitude
(on the paper's airframe, which hovers at 22 % thrust, it climbs at about 2 g)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from tests.groundtools.test_vehicle_mavlink import ACCEPTED, OFFBOARD, M, _streamer, _take_off
from tests.harness import GroundTool, Processes, free_port

pytestmark = [pytest.mark.process, pytest.mark.groundtool]  # real time, no timing asserted


class DefaultProcesses(Processes):
    """The two processes with no --airframe: their own default."""

    def start_autopilot(self) -> None:
        log = open(self.log_dir / "autopilot.log", "a")  # noqa: SIM115 (lives with the process)
        self.autopilot = subprocess.Popen(
            [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{self.sim_port}",
             "--gcs", f"127.0.0.1:{self.gcs_port}", "--gcs-bind", str(self.vehicle_port),
             "--api", "none", "--api-bind", "0", "--realtime"],
            stdout=log, stderr=subprocess.STDOUT)


def test_the_default_vehicle_holds_altitude_at_px4_typical_thrust(tmp_path):
    procs = DefaultProcesses(free_port(socket.SOCK_STREAM), free_port(), free_port(),
                             tmp_path, ["--realtime"])
    procs.start_sim()
    procs.start_autopilot()
    tool = GroundTool(procs.gcs_port)
    try:
        tool.connect()
        _take_off(tool)
        level = [1.0, 0.0, 0.0, 0.0]

        def send() -> None:  # attitude and thrust only, as an attitude script sends them
            tool.mav.set_attitude_target_send(0, 1, 1, 0b00000111, level, 0, 0, 0, 0.55)

        stream = _streamer(tool, send)
        tool.wait_type("HEARTBEAT", 2, also=stream)
        assert tool.command(M.MAV_CMD_DO_SET_MODE, *OFFBOARD).result == ACCEPTED
        z_start, start = tool.position().z, time.monotonic()
        while time.monotonic() - start < 3.0:
            stream()
            tool.pump()
        climbed_m = z_start - tool.position().z
        print(f"3 s at thrust 0.55 on the default vehicle: climbed {climbed_m:+.2f} m")
        # x500: full torque-free thrust 34.2 N, 0.55 of it 18.8 N for a weight of 19.6 N:
        # a slow sink (about -0.4 m/s^2), not the paper airframe's 1.5 g climb (tens of m).
        assert -4.0 < climbed_m < 0.5
    finally:
        tool.close()
        procs.stop()
