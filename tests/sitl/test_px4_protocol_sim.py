"""The autopilot driven by a simulator of PX4's protocol that is not ours
(tests/px4_protocol_sim.py): a quad X in PX4's motor order that waits for the autopilot's
HEARTBEAT, runs at 250 Hz from an arbitrary clock origin and sends only HIL_SENSOR and
HIL_STATE_QUATERNION. With no option but the airframe, the autopilot takes off, holds and
lands it, answering every sample."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.harness import GroundTool, free_port, mavutil
from tests.px4_protocol_sim import Px4ProtocolSim

pytestmark = pytest.mark.process

M = mavutil.mavlink


def test_a_px4_protocol_simulator_that_waits_for_heartbeat_is_flown_on_hil_messages(tmp_path):
    sim_port, gcs_port, vehicle_port = free_port(socket.SOCK_STREAM), free_port(), free_port()
    sim = Px4ProtocolSim(sim_port, rate_hz=250.0, start_time_us=7_123_456_789)
    sim.start()
    log = open(tmp_path / "autopilot.log", "w")  # noqa: SIM115 (lives with the process)
    autopilot = subprocess.Popen(
        [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{sim_port}", "--gcs",
         f"127.0.0.1:{gcs_port}", "--gcs-bind", str(vehicle_port), "--api", "none",
         "--api-bind", "0", "--no-zenoh", "--airframe", "quad-x-500"],
        stdout=log, stderr=subprocess.STDOUT)
    tool = GroundTool(gcs_port)
    try:
        tool.connect()
        tool.wait(lambda _msg: sim.samples > 50, 20, "samples flowing")
        assert sim.heartbeat_first
        assert tool.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        assert tool.command(M.MAV_CMD_NAV_TAKEOFF, *[float("nan")] * 7).result == \
            M.MAV_RESULT_ACCEPTED
        tool.wait_text("take-off complete", 30)
        # Hold: 2 s of wall time (several times that in lockstep sim time).
        held = []
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            msg = tool.pump()
            if msg is not None and msg.get_type() == "LOCAL_POSITION_NED":
                held.append((msg.x, msg.y, msg.z))
        held = np.array(held)
        assert len(held) > 10
        assert np.max(np.abs(held[:, 2] + 2.5)) < 0.1, held[:, 2]  # MIS_TAKEOFF_ALT
        assert np.max(np.hypot(held[:, 0], held[:, 1])) < 0.1
        assert np.max(np.abs(sim.body.position_ned[:2])) < 0.1  # the simulator agrees
        assert tool.command(M.MAV_CMD_NAV_LAND).result == M.MAV_RESULT_ACCEPTED
        tool.wait_text("landed: disarmed", 60)
        assert abs(sim.body.position_ned[2]) < 0.02
        # Lockstep: every sample answered, and the autopilot refused nothing.
        assert sim.answers == sim.samples or sim.answers == sim.samples - 1
        assert sim.error is None, sim.error
        assert "refused simulator data" not in (tmp_path / "autopilot.log").read_text()
        assert "HEARTBEAT" in sim.other_messages  # 1 Hz on the simulator link
    finally:
        tool.close()
        sim.stop()
        autopilot.terminate()
        autopilot.wait(10)
        log.close()
