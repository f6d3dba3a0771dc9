"""The autopilot as a MAVLink vehicle, driven by a pymavlink ground station over UDP.

Real processes (simulator + autopilot, real time, rigid-body plant) on real sockets.
"""

from __future__ import annotations

import json
import math
import random
import re
import socket
import time

import pytest

from contracts.airframe import PAPER, max_thrust_n
from tests.harness import GroundTool, mavutil, px4_mode, start_processes

pytestmark = pytest.mark.process
# The flights that only wait on the clock are ``groundtool`` flights; the stall and flood
# tests count what the machine's own hiccups would add to (stalls, drops), and run
# ``alone``.
REAL_TIME_FLIGHT = pytest.mark.groundtool

M = mavutil.mavlink
ACCEPTED, DENIED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED
TEMP_REJECTED, UNSUPPORTED = M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_UNSUPPORTED
OFFBOARD = px4_mode(6)
HOLD = px4_mode(4, 3)


@pytest.fixture
def vehicle(tmp_path):
    procs = start_processes(tmp_path)
    tool = GroundTool(procs.gcs_port)
    try:
        tool.connect()
        yield procs, tool
    finally:
        tool.close()
        procs.stop()


def _take_off(tool: GroundTool, altitude_m: float = 2.5) -> None:
    assert tool.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == ACCEPTED
    assert tool.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7).result == ACCEPTED
    tool.wait_type("LOCAL_POSITION_NED", 20, lambda m: abs(m.z + altitude_m) < 0.15)
    tool.wait_text("take-off complete", 10)


def _custom_mode(hb) -> tuple[int, int]:
    return (hb.custom_mode >> 16) & 0xFF, (hb.custom_mode >> 24) & 0xFF


@REAL_TIME_FLIGHT
def test_take_off_hold_land_and_auto_disarm(vehicle):
    procs, tool = vehicle
    hb = tool.heartbeat()
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4 and hb.type == M.MAV_TYPE_QUADROTOR
    _take_off(tool)
    hb = tool.heartbeat()
    assert _custom_mode(hb) == (4, 3)  # AUTO.LOITER: hold after take-off
    state = tool.wait_type("EXTENDED_SYS_STATE")
    assert state.landed_state == M.MAV_LANDED_STATE_IN_AIR
    # Disarming in the air is denied unless forced.
    assert tool.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == DENIED
    assert tool.command(M.MAV_CMD_NAV_LAND).result == ACCEPTED
    tool.wait_text("landed: disarmed", 30)
    assert not tool.armed()
    assert abs(tool.position().z) < 0.1
    # What the vehicle said is in its process log too, at its sim time, as PX4's console.
    said = re.findall(r"autopilot: t=(\d+\.\d{3}) s (\w+): (.*)", procs.autopilot_log())
    texts = [text for _, _, text in said]
    assert texts.index("take-off complete") < texts.index("landed: disarmed")
    assert all(level in ("INFO", "NOTICE", "WARNING", "ERROR", "CRITICAL")
               for _, level, _ in said)
    times = [float(t) for t, _, _ in said]
    assert times == sorted(times) and times[-1] > 3.0


@REAL_TIME_FLIGHT
def test_offboard_needs_a_stream_and_follows_setpoints(vehicle):
    procs, tool = vehicle
    _take_off(tool)
    assert tool.command(M.MAV_CMD_DO_SET_MODE, *OFFBOARD).result == TEMP_REJECTED
    stream = _streamer(tool, lambda: tool.send_position_setpoint(1.0, -0.5, -2.0))
    stream()
    tool.wait_type("HEARTBEAT", 2, also=stream)
    assert tool.command(M.MAV_CMD_DO_SET_MODE, *OFFBOARD).result == ACCEPTED
    tool.wait_type("LOCAL_POSITION_NED", 20,
                   lambda m: abs(m.x - 1.0) < 0.1 and abs(m.y + 0.5) < 0.1
                   and abs(m.z + 2.0) < 0.1, also=stream)
    assert _custom_mode(tool.wait_type("HEARTBEAT", also=stream)) == (6, 0)


@REAL_TIME_FLIGHT
def test_offboard_global_and_body_offset_setpoints(vehicle):
    """SET_POSITION_TARGET_GLOBAL_INT (altitude above home) and a one-off BODY_OFFSET_NED
    position, then a frame the vehicle does not take (refused, nothing changes)."""
    from contracts.frames import DEFAULT_HOME

    procs, tool = vehicle
    _take_off(tool)
    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(3.0, 2.0, 0.0)

    def global_target() -> None:
        tool.mav.set_position_target_global_int_send(
            0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0x9F8, round(lat * 1e7),
            round(lon * 1e7), 4.0, 0, 0, 0, 0, 0, 0, math.radians(90.0), 0)
    stream = _streamer(tool, global_target)
    tool.wait_type("HEARTBEAT", 2, also=stream)
    assert tool.command(M.MAV_CMD_DO_SET_MODE, *OFFBOARD).result == ACCEPTED
    tool.wait_type("LOCAL_POSITION_NED", 20, lambda m: abs(m.x - 3.0) < 0.05 and abs(
        m.y - 2.0) < 0.05 and abs(m.z + 4.0) < 0.05, also=stream)
    tool.wait_type("ATTITUDE", 10, lambda m: abs(m.yaw - math.radians(90.0)) < 0.02,
                   also=stream)
    # Heading east: 2 m forward and 1 m right of here is 2 m east and 1 m south.
    here = tool.position()
    goal = (here.x - 1.0, here.y + 2.0)
    tool.mav.set_position_target_local_ned_send(
        0, 1, 1, M.MAV_FRAME_BODY_OFFSET_NED, 0x9F8, 2.0, 1.0, 0.0, 0, 0, 0, 0, 0, 0,
        math.radians(90.0), 0)
    # One message only (the stream may pause 1 s): the vehicle sets off towards the goal.
    moving = tool.wait_type("LOCAL_POSITION_NED", 0.9, lambda m: math.hypot(m.vx, m.vy) > 0.3)
    heading = math.atan2(moving.vy, moving.vx)
    assert abs(heading - math.atan2(2.0, -1.0)) < math.radians(10.0)
    hold = _streamer(tool, lambda: tool.send_position_setpoint(*goal, -4.0, math.radians(90.0)))
    tool.wait_type("LOCAL_POSITION_NED", 20, lambda m: abs(m.x - goal[0]) < 0.05 and abs(
        m.y - goal[1]) < 0.05, also=hold)
    flu = _streamer(tool, lambda: tool.mav.set_position_target_local_ned_send(
        0, 1, 1, M.MAV_FRAME_LOCAL_FLU, 0x9F8, 9.0, 9.0, -9.0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert "frame 21" in tool.wait_text("setpoint refused", 5, also=flu)
    position = tool.position()
    assert abs(position.x - goal[0]) < 0.1 and abs(position.y - goal[1]) < 0.1


def _streamer(tool: GroundTool, send, rate_hz: float = 20.0):
    last = [0.0]

    def stream() -> None:
        now = time.monotonic()
        if now - last[0] >= 1.0 / rate_hz:
            last[0] = now
            send()
    return stream


@REAL_TIME_FLIGHT
def test_simulator_loss_lands_and_a_new_simulator_reconnects(vehicle):
    procs, tool = vehicle
    _take_off(tool)
    procs.sim.kill()
    procs.sim.wait()
    tool.wait_text("simulator link lost: land", 5)
    assert _custom_mode(tool.heartbeat()) == (4, 6)  # AUTO.LAND
    # The autopilot keeps serving ground tools meanwhile.
    assert tool.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result \
        == ACCEPTED
    tool.texts.clear()  # wait for new announcements, not the first link-up
    procs.start_sim()  # a new simulator: on the ground, its clock from zero
    tool.wait_text("simulator link up", 15)
    tool.wait_text("disarmed", 10)
    assert not tool.armed()
    assert tool.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == ACCEPTED


@REAL_TIME_FLIGHT
def test_killing_the_autopilot_stops_the_motors_and_a_new_one_reconnects(vehicle):
    procs, tool = vehicle
    _take_off(tool)
    procs.autopilot.kill()
    procs.autopilot.wait()
    deadline = time.monotonic() + 10
    while "motors stopped" not in procs.sim_log() and time.monotonic() < deadline:
        time.sleep(0.1)
    log = procs.sim_log()
    assert "autopilot disconnected" in log and "motors stopped" in log
    assert procs.sim.poll() is None  # still running
    tool.texts.clear()
    procs.start_autopilot()
    tool.wait_text("simulator link up", 15)
    # Nobody flies it: motors stopped, it falls to the ground (the new autopilot is disarmed).
    tool.wait_type("LOCAL_POSITION_NED", 10, lambda m: abs(m.z) < 0.05)
    assert not tool.armed()
    assert procs.sim_log().count("autopilot connected") == 2


@REAL_TIME_FLIGHT
def test_signing_ignores_unsigned_and_wrongly_signed_commands(tmp_path):
    key = bytes(range(32))
    procs = start_processes(tmp_path, autopilot_args=[
        "--signing-key", key.hex(), "--signing-state", str(tmp_path / "signing.json")])
    signed = GroundTool(procs.gcs_port, key)
    try:
        signed.connect()
        # Unsigned, then wrongly signed, arming attempts from other sockets.
        for k in (None, bytes(32)):
            other = mavutil.mavlink_connection(f"udpout:127.0.0.1:{procs.vehicle_port}",
                                               source_system=255)
            if k is not None:
                other.setup_signing(k, sign_outgoing=True)
            for _ in range(3):
                other.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0,
                                            0, 0, 0, 0)
                time.sleep(0.2)
            reply = other.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0)
            assert reply is None
            other.close()
        assert not signed.armed()
        ack = signed.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack.result == ACCEPTED and ack.get_signed()
        assert signed.armed()
    finally:
        signed.close()
        procs.stop()


@REAL_TIME_FLIGHT
def test_attitude_setpoints_tilt_the_vehicle_and_bad_ones_are_refused(vehicle):
    procs, tool = vehicle
    _take_off(tool)
    roll = 0.1
    q = [math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0]
    # PX4 reads thrust as the collective over the maximum: hover, tilted by the roll.
    hover = PAPER.mass_kg * PAPER.gravity_mps2 / max_thrust_n(PAPER) / math.cos(roll)

    def send(quaternion, thrust=hover):
        tool.mav.set_attitude_target_send(0, 1, 1, 0b00000111, quaternion, 0, 0, 0, thrust)

    stream = _streamer(tool, lambda: send(q))
    tool.wait_type("HEARTBEAT", 2, also=stream)
    assert tool.command(M.MAV_CMD_DO_SET_MODE, *OFFBOARD).result == ACCEPTED
    tool.wait_type("ATTITUDE", 10, lambda m: abs(m.roll - roll) < 0.01, also=stream)
    z_before = tool.position().z
    bad = _streamer(tool, lambda: send([math.nan, 0.0, 0.0, 0.0]))
    tool.wait_text("setpoint refused", 5, also=bad)
    att = tool.wait_type("ATTITUDE", 2, also=bad)
    assert abs(att.roll - roll) < 0.02  # the last good setpoint still holds
    assert abs(tool.position().z - z_before) < 0.2  # hover thrust: altitude about held
    tool.wait_text("offboard setpoints lost: hold", 5, also=bad)


@pytest.mark.alone
def test_stalled_simulator_triggers_the_link_loss_failsafe_after_its_timeout(vehicle):
    """SIGSTOP keeps the socket open: only the COM_SIM_LOSS_T watchdog can notice."""
    import signal

    procs, tool = vehicle
    _take_off(tool)
    procs.sim.send_signal(signal.SIGSTOP)
    stopped = time.monotonic()
    try:
        text = tool.wait_text("simulator link lost", 5)
        assert text == "simulator link lost: land"
        # COM_SIM_LOSS_T (0.5 s) counts from the last sample, which reached the autopilot
        # up to one 10 ms period before the SIGSTOP.
        assert time.monotonic() - stopped >= 0.5 - 0.01
    finally:
        procs.sim.send_signal(signal.SIGCONT)
    tool.texts.clear()
    tool.wait_text("simulator link up", 5)
    assert _custom_mode(tool.heartbeat()) == (4, 6)  # landing once state is back


@pytest.mark.alone
def test_a_late_simulator_is_a_counted_stall_that_holds_the_command(vehicle):
    """A simulator that goes quiet for 0.2 s (SIGSTOP, shorter than COM_SIM_LOSS_T): the
    control instants without a fresh sample hold the last command and are counted, one
    stall of about 200 ms in the timing summary, and the log says so; the link stays up."""
    import json
    import signal

    procs, tool = vehicle
    _take_off(tool)
    procs.sim.send_signal(signal.SIGSTOP)
    time.sleep(0.2)
    procs.sim.send_signal(signal.SIGCONT)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        tool.pump()
    assert not any("simulator link lost" in t for t in tool.texts)
    procs.autopilot.terminate()
    procs.autopilot.wait(5)
    log = procs.autopilot_log()
    timing = json.loads(log.split("autopilot: timing ", 1)[1].splitlines()[0])
    assert timing["sim_stalls"] == 1
    # At 100 Hz: the first 20 ms are not a stall yet, then 18 of 10 ms (OS wake-up adds
    # a little: the signals and the sleep are not instant).
    assert 15 <= timing["sim_stall_steps"] <= 30
    assert 170 <= timing["sim_stall_longest_ms"] <= 300
    (line,) = [ln for ln in log.splitlines() if "simulator late" in ln]
    assert "control step(s) held the last command" in line
    # The simulator resumes from where it stopped instead of running the lost periods in
    # a burst the autopilot has no time to answer (which timed its commands out).
    sim_log = procs.sim_log()
    assert "behind the wall clock" in sim_log and "resumed from there" in sim_log
    assert "motors stopped" not in sim_log


@pytest.mark.alone
def test_a_flooded_vehicle_answers_and_shows_its_drops(vehicle):
    """Garbage and valid heartbeats from 50 ports on the vehicle's port: the tool is
    still answered, the loss shows in SYS_STATUS and one
    STATUSTEXT, and the counters reach the log. (The timing under 100k datagrams/s is
    measured by tests/benchmarks/bench_flood.py, not here.)"""
    procs, tool = vehicle
    target = ("127.0.0.1", procs.vehicle_port)
    flood = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(50)]
    beats = [M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
             .pack(M.MAVLink(None, 100 + i, 190)) for i in range(50)]
    rng = random.Random(7)
    garbage = [rng.randbytes(rng.randint(1, 200)) for _ in range(64)]
    try:
        start = time.monotonic()
        sent = 0

        def burst() -> None:  # ~20k datagrams/s while the tool waits
            nonlocal sent
            for _ in range(200):
                i = sent % 50
                flood[i].sendto(beats[i] if sent % 2 else garbage[sent % 64], target)
                sent += 1

        tool.mav.param_request_read_send(1, 1, b"MPC_XY_VEL_MAX", -1)
        value = tool.wait(lambda m: m.get_type() == "PARAM_VALUE", 3.0, "PARAM_VALUE", burst)
        assert value.param_id == "MPC_XY_VEL_MAX"
        status = tool.wait(lambda m: m.get_type() == "SYS_STATUS" and m.drop_rate_comm > 0,
                           5.0, "SYS_STATUS with drops", burst)
        assert status.errors_comm > 0
        tool.wait_text("gcs: ", 5.0)
        ack = tool.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == ACCEPTED
        tool.wait_type("HEARTBEAT", 2.0)  # still hears the vehicle
        assert time.monotonic() - start < 15.0 and sent > 0
    finally:
        for s in flood:
            s.close()
    procs.autopilot.terminate()
    procs.autopilot.wait(10)
    line = next(ln for ln in procs.autopilot_log().splitlines()
                if ln.startswith("autopilot: ground links {"))
    gcs = json.loads(line.removeprefix("autopilot: ground links "))["gcs"]
    assert gcs["rejected"] > 0 and gcs["peers_refused"] > 0 and gcs["peers"] <= 4
    assert sum(t.startswith("gcs: ") for t in tool.texts) == 1  # once a minute at most
