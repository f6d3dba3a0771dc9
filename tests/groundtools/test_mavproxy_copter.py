"""MAVProxy at its prompt meets Copter's mode and arming rules (autopilot/commander/
personality.py) in the ArduPilot-Copter flavour: what it prints is what ArduCopter SITL
makes it print."""

from __future__ import annotations

import time

import pytest

from tests.groundtools.test_mavproxy import Prompt
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


def test_mavproxy_sees_coppers_modes_and_arming_rules(tmp_path):
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    prompt = Prompt(procs.gcs_port, tmp_path / "mavproxy", modules="arm,mode,cmdlong,misc")
    try:
        prompt.child.expect(r"online system 1", timeout=40)
        # The position estimate first: a Copter checks it before the mode (PreArm before Arm).
        prompt.wait_for_gps_lock()
        prompt.type("status HEARTBEAT", r"custom_mode : 0,")  # STABILIZE at boot
        # RTL is selected disarmed, as Copter allows, and cannot be armed in.
        prompt.type("mode RTL", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        prompt.type("status HEARTBEAT", r"custom_mode : 6,")
        prompt.type("arm throttle", r"Got COMMAND_ACK: COMPONENT_ARM_DISARM: FAILED",
                    r"Arm: RTL mode not armable")
        # A Copter mode this vehicle does not fly, in Copter's words.
        prompt.type("mode ACRO", r"Mode change to ACRO failed: not available in this SITL")
        prompt.type("mode GUIDED", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        deadline = time.monotonic() + 20  # the simulator's first state may still be coming
        while True:
            prompt.child.sendline("arm throttle")
            index = prompt.child.expect([r"COMPONENT_ARM_DISARM: ACCEPTED",
                                         r"PreArm: Need Position Estimate"], timeout=10)
            if index == 0:
                break
            assert time.monotonic() < deadline, "never armed"
            time.sleep(1.0)
        prompt.child.expect(r"Arming motors", timeout=10)
        prompt.type("takeoff 3", r"Got COMMAND_ACK: NAV_TAKEOFF: ACCEPTED")
        deadline = time.monotonic() + 20
        while prompt.relative_altitude_m() < 2.8:
            assert time.monotonic() < deadline, "never reached 3 m"
            time.sleep(0.5)
        # In the air a second take-off fails, as Copter's does.
        prompt.type("takeoff 5", r"Got COMMAND_ACK: NAV_TAKEOFF: FAILED")
        prompt.type("mode LAND", r"Mode LAND")
        prompt.child.expect(r"Disarming motors", timeout=30)
        prompt.child.expect(r"DISARMED", timeout=10)
        assert prompt.relative_altitude_m() < 0.1
        time.sleep(1.5)
        prompt.type("status HEARTBEAT", r"custom_mode : 9,")  # still LAND, as Copter
    finally:
        prompt.close()
        procs.stop()
