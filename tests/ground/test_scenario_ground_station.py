"""A scenario's ``[ground_station]``: the table checked, and the ground tool it makes
(ground/scenario/ground_station.py) as a real MAVLink client on a real UDP socket, heard by a
pymavlink reader standing in the autopilot's ground-link port; and the ``sim_stall``
perturbation kind's checks. The rehearsal flights that use them run in real time
(``ivfm rehearse``; docs/rehearsal.md)."""

from __future__ import annotations

import socket
import time

import pytest

from contracts.mavlink import mavlink
from contracts.modes import PX4_MODES, FlightMode
from contracts.perturbations import parse_request
from ground.run.inprocess import run_inprocess
from ground.scenario.ground_station import GroundStation, Silence, parse_ground_station
from ground.scenario.scenario_file import load_scenario


@pytest.mark.parametrize("table, error", [
    ({"heartbeat_hz": -1}, r"heartbeat_hz must be a number in \[0, 50\]"),
    ({"heartbeat_hz": float("nan")}, r"heartbeat_hz must be a number in \[0, 50\], got nan"),
    ({"heartbeat_hz": 51}, r"heartbeat_hz must be a number in \[0, 50\], got 51"),
    ({"colour": 1}, "unknown field"),
    ({"silence": [{"what": "radio", "start_s": 1}]}, "what must be one of"),
    ({"silence": [{"what": "setpoints", "start_s": 1}]}, "give offboard_at_s"),
    ({"silence": [{"start_s": 5, "end_s": 2}]}, "end_s must be a finite number >= 5"),
    ({"silence": [{"end_s": 2}]}, "start_s is required"),
    ({"offboard_at_s": 99}, r"offboard_at_s must be a number in \[0, 20\]"),
    ({"silence": {"start_s": 1}}, "array of tables"),
])
def test_bad_ground_station_tables_are_refused_with_the_field(table, error):
    with pytest.raises(ValueError, match=error):
        parse_ground_station(table, 20.0)


def test_a_ground_station_table_and_its_defaults():
    plan = parse_ground_station({"offboard_at_s": 2, "silence": [
        {"what": "setpoints", "start_s": 6}, {"start_s": 8, "end_s": 9}]}, 12.0)
    assert plan.heartbeat_hz == 1.0 and plan.setpoint_hz == 20.0 and plan.offboard_at_s == 2
    assert plan.silences == (Silence("setpoints", 6.0, 12.0), Silence("all", 8.0, 9.0))
    assert plan.silent("setpoints", 7.0) and not plan.silent("heartbeat", 7.0)
    assert plan.silent("heartbeat", 8.5) and not plan.silent("heartbeat", 9.0)
    assert parse_ground_station(None, 12.0) is None


def test_the_shipped_link_flights_load_and_refuse_to_fly_in_one_process():
    from ground.rehearsal.readiness import load_profile

    flights = {f.scenario.stem: f for f in load_profile().flights}
    for name in ("gcs-loss", "setpoint-loss"):
        scenario = load_scenario(flights[name].scenario)
        assert flights[name].realtime and scenario.ground_station is not None
        with pytest.raises(ValueError, match="through the processes"):
            run_inprocess(scenario, "ivfc", "rigid-body", 0.01)
    stall = load_scenario(flights["sim-stall"].scenario)
    assert [(e.kind, e.params) for e in stall.perturbations] == [
        ("sim_stall", {"freeze_s": 0.3})]
    with pytest.raises(ValueError, match="sim_stall act on the simulator link"):
        run_inprocess(stall, "ivfc", "rigid-body", 0.01)


def test_an_offboard_ground_station_needs_a_hover_reference(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("[reference]\nkind = 'position-sine'\n[ground_station]\n"
                    "offboard_at_s = 1.0\n")
    with pytest.raises(ValueError, match="must be kind = \"hover\""):
        load_scenario(path)


@pytest.mark.parametrize("request_, error", [
    ({"kind": "sim_stall", "start_s": 1}, "freeze_s is required"),
    ({"kind": "sim_stall", "start_s": 1, "freeze_s": 0}, "freeze_s must be a number in"),
    ({"kind": "sim_stall", "start_s": 1, "freeze_s": 11}, "freeze_s must be a number in"),
])
def test_bad_sim_stalls_are_refused(request_, error):
    with pytest.raises(ValueError, match=error):
        parse_request(request_)


def test_the_ground_station_sends_what_its_plan_says_and_falls_silent():
    """Heartbeats at 20 Hz silenced 0.4-0.8 s; the hover setpoint at 20 Hz from the
    start; DO_SET_MODE OFFBOARD from 0.2 s, again until acknowledged (here on its second
    sending); the setpoints silenced from 1.0 s. The station's passes are driven on the
    test's clock (every 5 ms, as its thread makes them), over a real socket: on the wall
    clock, a starved thread sent fewer and the counts failed beside busy work."""
    from pymavlink import mavutil

    vehicle = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1)
    port = vehicle.port.getsockname()[1]
    plan = parse_ground_station({"heartbeat_hz": 20.0, "offboard_at_s": 0.2, "silence": [
        {"what": "heartbeat", "start_s": 0.4, "end_s": 0.8},
        {"what": "setpoints", "start_s": 1.0}]}, 10.0)
    gcs = GroundStation(plan, port, 1, (1.0, 2.0, -3.0), 0.5)
    heard: list = []
    try:
        for k in range(280):  # 0 to 1.395 s
            gcs.step(k * 0.005)
            while (msg := vehicle.recv_match(blocking=False)) is not None:
                heard.append(msg)
                if msg.get_type() == "COMMAND_LONG" and \
                        sum(m.get_type() == "COMMAND_LONG" for m in heard) == 2:
                    # the second acknowledged: the third must not come
                    vehicle.mav.command_ack_send(msg.command, mavlink.MAV_RESULT_ACCEPTED)
    finally:
        gcs.stop()
        vehicle.close()
    assert gcs.error is None
    kinds = {"heartbeat": "HEARTBEAT", "setpoints": "SET_POSITION_TARGET_LOCAL_NED",
             "set_mode": "COMMAND_LONG"}
    for kind, message in kinds.items():  # every sending arrived, nothing else of its kind
        assert sum(m.get_type() == message for m in heard) == gcs.sent[kind], kind

    def times(kind: str) -> list[float]:
        return [t for k, t in gcs.sent_at if k == kind]

    beats = times("heartbeat")
    # 0, 0.05 ... 0.35 and 0.8 ... 1.35, each within a pass of its time; none in silence
    assert len(beats) == 8 + 12
    due = [0.05 * i for i in range(8)] + [0.8 + 0.05 * i for i in range(12)]
    assert all(-1e-9 <= t - d < 0.005 + 1e-9 for t, d in zip(beats, due, strict=True))
    beat = next(m for m in heard if m.get_type() == "HEARTBEAT")
    assert beat.type == mavlink.MAV_TYPE_GCS and beat.get_srcSystem() == 255
    setpoint_times = times("setpoints")
    # from the start (the first pass sends both), 20 Hz, never after the silence begins
    assert setpoint_times[0] == beats[0] == 0.0 and len(setpoint_times) == 20
    assert all(t < 1.0 for t in setpoint_times)
    setpoints = [m for m in heard if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    # each carries its sending time: the same clock, to the millisecond
    assert [sp.time_boot_ms for sp in setpoints] == [int(t * 1000) for t in setpoint_times]
    sp = setpoints[0]
    assert (sp.x, sp.y, sp.z, sp.yaw) == pytest.approx((1.0, 2.0, -3.0, 0.5))
    assert sp.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED and sp.target_system == 1
    commands = [m for m in heard if m.get_type() == "COMMAND_LONG"]
    assert len(commands) == 2 and gcs.mode_acked
    assert commands[0].command == mavlink.MAV_CMD_DO_SET_MODE
    assert (commands[0].param2, commands[0].param3) == PX4_MODES[FlightMode.OFFBOARD]
    first, again = times("set_mode")  # never early: from 0.2 s, again 0.5 s after
    assert first == pytest.approx(0.2, abs=0.0051) and again == pytest.approx(
        first + 0.5, abs=0.0051)


def test_the_ground_station_keeps_its_plan_on_the_vehicles_clock():
    """A vehicle whose telemetry says it is 0.3 s behind the wall clock (a simulator that
    started late): the switch to OFFBOARD planned at 0.5 s comes no sooner than 0.8 s."""
    from pymavlink import mavutil

    vehicle = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1)
    port = vehicle.port.getsockname()[1]
    gcs = GroundStation(parse_ground_station({"offboard_at_s": 0.5}, 10.0), port, 1,
                        (0.0, 0.0, -2.0), 0.0)
    gcs.start()
    start = time.monotonic()
    switched = None
    try:
        while time.monotonic() - start < 5.0 and switched is None:
            msg = vehicle.recv_match(blocking=True, timeout=0.02)
            now = time.monotonic() - start
            if msg is not None and msg.get_type() == "COMMAND_LONG":
                switched = now
            vehicle.mav.attitude_send(max(0, round(1e3 * (now - 0.3))), 0, 0, 0, 0, 0, 0)
    finally:
        gcs.stop()
        vehicle.close()
    # Never before the vehicle's clock reads 0.5 s (0.8 s on the reader's); how late the
    # reader hears it depends on the machine's load, so no upper bound is pinned here.
    assert switched is not None and switched >= 0.79
    assert [t for kind, t in gcs.sent_at if kind == "set_mode"][0] >= 0.5


def test_the_plan_runs_on_the_vehicles_clock_from_the_first_message():
    """Started 1.9 s after the vehicle's clock (the station's start was late beside busy
    work), the plan jumps to the vehicle's time when it first hears it; afterwards it is
    never ahead of what the vehicle last said (a vehicle that falls behind, or a message
    heard late, holds it back)."""
    gcs = GroundStation(parse_ground_station({"offboard_at_s": 2.0}, 10.0), 9, 1,
                        (0.0, 0.0, -2.0), 0.0)
    gcs._t0 = 100.0  # started at 100 s on the monotonic clock
    assert gcs.plan_time(100.1) == pytest.approx(0.1)
    gcs.hear_vehicle_time(2000, 100.1)
    assert gcs.plan_time(100.1) == pytest.approx(2.0)
    gcs.hear_vehicle_time(2100, 100.2)  # on time: nothing moves
    assert gcs.plan_time(100.2) == pytest.approx(2.1)
    gcs.hear_vehicle_time(2500, 101.1)  # the vehicle stalled: 0.5 s behind
    assert gcs.plan_time(101.1) == pytest.approx(2.5)
    gcs.hear_vehicle_time(3200, 101.2)  # never set forward again: 2.6, not 3.2
    assert gcs.plan_time(101.2) == pytest.approx(2.6)
    gcs.conn.close()


def test_a_ground_station_to_nobody_keeps_going():
    """No vehicle on the port (ICMP unreachable on loopback): the sends fail quietly and
    the thread runs on until stopped."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    gcs = GroundStation(parse_ground_station({"heartbeat_hz": 50.0}, 5.0), port, 1,
                        (0.0, 0.0, -2.0), 0.0)
    gcs.start()
    # Its thread goes on sending: 10 heartbeats (0.2 s on time; a starved thread beside
    # busy work takes longer, so the wait is for the count, not a time).
    deadline = time.monotonic() + 30.0
    while gcs.sent["heartbeat"] < 10 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert gcs._thread.is_alive()
    gcs.stop()
    assert gcs.error is None and gcs.sent["heartbeat"] >= 10
