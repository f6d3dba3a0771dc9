"""Follow Me (AUTO.FOLLOW_TARGET), flown in process on sim time (tests/flight.py): a
target reporting once a second, as MAVSDK's follow-me plugin sends FOLLOW_TARGET; the
MAVSDK flight through the processes is in test_mavsdk_follow_me.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.flight_tasks.follow import TARGET_TIMEOUT_S
from autopilot.refusal import RefusedError
from contracts.mavlink import mavlink
from contracts.modes import FlightMode, mode_from_px4, px4_custom_mode
from tests.flight import Flight


def _follow(target, seconds: float, with_velocity: bool = True,
            parameters: dict[str, float] | None = None, silent=lambda t: False):
    """Take off to 3 m, enter FOLLOW_TARGET, report ``target(t)`` (relative to the start
    of following) once a second for ``seconds``; returns the flight and the start time."""
    f = Flight(parameters=parameters)
    f.take_off(3.0)
    f.vehicle.set_mode(FlightMode.FOLLOW_TARGET, f.t_s)
    start = f.t_s

    def tool(t: float) -> None:
        since = t - start
        if round(since / f.period_s) % 100 == 0 and not silent(since):
            position, velocity = target(since)
            f.vehicle.inputs.follow_target(np.array(position, dtype=float),
                                    np.array(velocity, dtype=float) if with_velocity
                                    else None)

    f.run(seconds, tool)
    return f, start


def _walking_east(since: float):
    return (5.0, 2.0 * since, 0.0), (0.0, 2.0, 0.0)


def _relative(f: Flight, start: float, target, after_s: float) -> np.ndarray:
    """The vehicle's position relative to the target, after ``after_s`` of following."""
    log = f.since(start + after_s)
    where = np.array([target(t - start)[0] for t in log[:, 0]])
    return log[:, 1:4] - where


def test_the_mode_has_px4s_numbers():
    number = px4_custom_mode(FlightMode.FOLLOW_TARGET)
    assert ((number >> 16) & 0xFF, (number >> 24) & 0xFF) == (4, 8)  # AUTO.FOLLOW_TARGET
    assert mode_from_px4(number) is FlightMode.FOLLOW_TARGET


def test_a_walking_target_is_followed_from_behind_at_the_distance_and_height():
    """FLW_TGT_DST 8 m behind (FLW_TGT_FA 180), FLW_TGT_HT 8 m above home, facing it."""
    f, start = _follow(_walking_east, 40.0)
    rel = _relative(f, start, _walking_east, 25.0)
    # Golden (in process, bit for bit): 7.96 m behind, 4 cm ahead of the station: a report
    # is stamped with the sim time of the step before it, so it is carried 10 ms too far.
    assert rel.mean(axis=0) == pytest.approx([0.0, -7.960, -8.0], abs=0.002)
    assert np.abs(rel - rel.mean(axis=0)).max() < 1e-4  # steady: the reports do not jerk it
    yaw = f.since(start + 25.0)[:, 9]
    assert np.abs(yaw - math.pi / 2).max() < 1e-3  # facing east, at the target
    assert "follow target: waiting for the target" in [t for _, t in f.vehicle.messages]


def test_positions_alone_give_the_velocity_and_the_follow_angle_is_clockwise():
    """No velocity in the reports: the last two positions give it. FLW_TGT_FA 90 is the
    target's right: south of a target walking east."""
    f, start = _follow(_walking_east, 40.0, with_velocity=False,
                       parameters={"FLW_TGT_FA": 90.0, "FLW_TGT_DST": 5.0})
    rel = _relative(f, start, _walking_east, 25.0)
    assert rel.mean(axis=0) == pytest.approx([-5.0, 0.040, -8.0], abs=0.005)


def test_the_altitude_tracks_the_target_with_flw_tgt_alt_m_2():
    def climbing(since: float):
        return (5.0, 2.0 * since, -0.2 * since), (0.0, 2.0, -0.2)

    f, start = _follow(climbing, 30.0, parameters={"FLW_TGT_ALT_M": 2.0})
    rel = _relative(f, start, climbing, 20.0)
    assert rel[:, 2].mean() == pytest.approx(-8.0, abs=0.01)  # 8 m above the target


def test_a_turning_target_is_swung_round_at_flw_tgt_max_vel():
    """The target turns from east to north at 10 s: the station swings a quarter circle
    round it at no more than FLW_TGT_MAX_VEL (1 m/s here), so it takes at least
    8 m * pi/2 / 1 m/s = 12.6 s, and ends behind it again."""
    def turning(since: float):
        if since < 10.0:
            return (0.0, 2.0 * since, 0.0), (0.0, 2.0, 0.0)
        return (2.0 * (since - 10.0), 20.0, 0.0), (2.0, 0.0, 0.0)

    f, start = _follow(turning, 45.0, parameters={"FLW_TGT_MAX_VEL": 1.0})
    task = f.vehicle.tasks[FlightMode.FOLLOW_TARGET]
    assert task.course_rad == pytest.approx(0.0)  # north
    rel = _relative(f, start, turning, 38.0)
    assert rel.mean(axis=0)[0:2] == pytest.approx([-7.96, 0.0], abs=0.01)  # behind: south
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    assert np.all(np.abs(np.angle(np.exp(1j * (bearing - math.pi)))) < 0.01)
    mid = _relative(f, start, turning, 16.0)[:100]  # 6 s after the turn: still swinging
    assert np.all(np.abs(np.arctan2(mid[:, 1], mid[:, 0])) > 2.0)


def test_a_lost_target_holds_and_a_regained_one_is_followed_again():
    f, start = _follow(_walking_east, 40.0, silent=lambda since: 15.0 < since < 25.0)
    texts = [t for _, t in f.vehicle.messages]
    assert f"follow target: target lost for {TARGET_TIMEOUT_S:g} s: holding" in texts
    assert "follow target: target regained" in texts
    log = f.since(start + 15.0 + TARGET_TIMEOUT_S + 4.0)[:300]  # stopped, held while lost
    assert np.ptp(log[:, 2]) < 0.05
    rel = _relative(f, start, _walking_east, 38.0)
    assert rel.mean(axis=0) == pytest.approx([0.0, -7.96, -8.0], abs=0.01)
    assert f.vehicle.mode is FlightMode.FOLLOW_TARGET


def test_follow_target_needs_the_air_and_bad_reports_change_nothing():
    f = Flight()
    f.run(0.1)
    with pytest.raises(RefusedError, match="follow target denied: not in the air"):
        f.vehicle.set_mode(FlightMode.FOLLOW_TARGET, f.t_s)
    task = f.vehicle.tasks[FlightMode.FOLLOW_TARGET]
    for position, velocity in (((math.nan, 0, 0), None), ((2e4, 0, 0), None),
                               ((0, 0, 0), (math.inf, 0, 0)), ((0, 0, 0), (200.0, 0, 0))):
        with pytest.raises(RefusedError, match="follow target"):
            f.vehicle.inputs.follow_target(np.array(position, dtype=float),
                                    None if velocity is None else np.array(velocity))
    assert task.target_ned_m is None


def test_follow_target_messages_are_read_and_bad_ones_refused_with_a_reason():
    """The MAVLink side: FOLLOW_TARGET as MAVSDK packs it (position bit only, the
    caller's velocity), and a report off the Earth refused in a STATUSTEXT."""
    from autopilot.mavlink.server import MavlinkServer

    f = Flight()
    f.run(0.1)
    server = MavlinkServer(f.vehicle, [])
    home = f.vehicle.places.origin
    lat, lon, alt = home.geodetic_from_ned(10.0, -4.0, -2.0)
    sent = []
    server.send_text = lambda link, severity, text, address=None: sent.append(text)

    def report(lat_deg: float, lon_deg: float, alt_m: float, vel=(1.0, 0.5, 0.0)):
        msg = mavlink.MAVLink_follow_target_message(
            0, 1, round(lat_deg * 1e7), round(lon_deg * 1e7), alt_m, list(vel),
            [math.nan] * 3, [1.0, math.nan, math.nan, math.nan], [math.nan] * 3,
            [math.nan] * 3, 0)
        server.setpoints.on_follow_target(None, None, msg, f.t_s)

    report(lat, lon, alt)
    task = f.vehicle.tasks[FlightMode.FOLLOW_TARGET]
    assert task.target_ned_m == pytest.approx([10.0, -4.0, -2.0], abs=0.01)
    assert task.target_velocity_ned_mps == pytest.approx([1.0, 0.5, 0.0])
    report(95.0, lon, alt)
    assert sent and "is not a position on Earth" in sent[-1]
    assert task.target_ned_m == pytest.approx([10.0, -4.0, -2.0], abs=0.01)  # unchanged
