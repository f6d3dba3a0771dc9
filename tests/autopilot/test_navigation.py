"""Missions, return, go-to and manual flight, flown in process on sim time (tests/flight.py).

The vehicle's navigator (autopilot/navigator/) and manual modes
(autopilot/flight_tasks/sticks.py) fly the rigid-body plant with the paper's controller;
what a tool does is called on the vehicle directly. Numbers are golden: a change in the
navigator or the shaping that moves them is a change to look at. MAVLink and real tools
are in test_mission_flight.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from autopilot.flight_tasks.sticks import Sticks, deadband, expo, sticks_from_manual_control
from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import MISSION
from autopilot.refusal import RefusedError
from contracts.frames import DEFAULT_HOME
from contracts.mavlink import mavlink
from contracts.modes import FlightMode
from ground.report.metrics import distance_to_path
from tests.flight import Flight, do_item, mission_item

M = mavlink
TAKEOFF, WAYPOINT, LAND, RTL = (M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_WAYPOINT,
                                M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
SIX = [(30, 0), (30, 30), (0, 30), (-20, 10), (10, -20), (0, 0)]
POS, VEL = slice(1, 4), slice(4, 7)


def mission_flight(items, duration_s: float, **kwargs) -> Flight:
    """Armed in AUTO.MISSION on the ground with ``items`` stored, flown ``duration_s``."""
    f = Flight(**kwargs)
    f.vehicle.mission.replace(MISSION, tuple(items))
    f.run(0.05)
    f.vehicle.set_mode(FlightMode.MISSION, f.t_s)
    f.vehicle.arm(f.t_s)
    f.run(duration_s)
    return f


def six_waypoints(last=LAND) -> list:
    items = [mission_item(0, 0, 0, 5.0, TAKEOFF)]
    items += [mission_item(i + 1, n, e, 5.0) for i, (n, e) in enumerate(SIX)]
    items.append(mission_item(len(items), 0, 0, 0.0, last))
    return items


def speed(log: np.ndarray) -> np.ndarray:
    return np.hypot(log[:, 4], log[:, 5])


def reference_speed(log: np.ndarray) -> np.ndarray:
    """The shaped reference's horizontal speed (log columns 13-30: the reference)."""
    return np.hypot(log[:, 16], log[:, 17])


def time_within(log: np.ndarray, point, radius_m: float) -> float:
    """How long the vehicle spent within ``radius_m`` of ``point``."""
    d = np.linalg.norm(log[:, POS] - np.asarray(point), axis=1)
    return float(np.count_nonzero(d <= radius_m)) * (log[1, 0] - log[0, 0])


@pytest.fixture(scope="module")
def six():
    return mission_flight(six_waypoints(), 80.0)


# -- missions --------------------------------------------------------------------------
def test_six_waypoints_at_5_mps_every_item_reached_on_the_path(six):
    v, log = six.vehicle, six.log
    assert v.reached == list(range(8))  # take-off, six waypoints, land
    assert not v.armed and v.mode == FlightMode.HOLD and v.mission.current == 0
    assert np.linalg.norm(log[-1, 1:3]) < 0.01 and log[-1, 3] == 0.0  # landed on the last
    path = np.array([(0, 0, 0), (0, 0, -5)] + [(n, e, -5) for n, e in SIX], dtype=float)
    flying = (-log[:, 3] > 4.9)
    deviation = distance_to_path(log[flying, POS], path)
    rmse = float(np.sqrt(np.mean(deviation**2)))
    # Corners are cut inside the acceptance radius (NAV_ACC_RAD 2 m), as PX4 cuts them.
    assert rmse == pytest.approx(0.0837, abs=0.002)
    assert deviation.max() == pytest.approx(0.385, abs=0.01)
    assert speed(log).max() == pytest.approx(5.0, abs=0.13)  # MPC_XY_CRUISE


def test_mission_corners_are_rounded_at_a_reduced_speed_not_stopped_at(six):
    """Each turning waypoint is passed inside its acceptance radius at the corner's
    speed (sharper turns slower); only the last one, before the landing, is stopped at."""
    log = six.log
    closest, speeds = [], []
    for north, east in SIX:
        d = np.linalg.norm(log[:, POS] - (north, east, -5.0), axis=1)
        i = int(np.argmin(d))
        closest.append(float(d[i]))
        speeds.append(float(speed(log)[i]))
    # Turns of 90, 90, 45, 90 and 162 degrees, then the landing point.
    assert closest == pytest.approx([0.479, 0.479, 0.416, 0.473, 0.302, 0.053], abs=0.01)
    assert speeds == pytest.approx([1.41, 1.41, 2.39, 1.40, 0.11, 0.05], abs=0.03)
    landed_s = log[np.argmax((log[:, 3] == 0.0) & (log[:, 0] > 10.0)), 0]
    assert landed_s == pytest.approx(61.0, abs=0.1)  # 73.6 s when it stopped at each


def test_corner_speed_follows_the_turn():
    from autopilot.navigator.mission_runner import corner_speed_mps

    assert corner_speed_mps(math.radians(90), 2.0, 3.0, 5.0) == pytest.approx(math.sqrt(3.0))
    assert corner_speed_mps(math.radians(45), 2.0, 3.0, 5.0) == pytest.approx(
        math.sqrt(3.0 / math.tan(math.radians(22.5))))
    assert corner_speed_mps(math.radians(5), 2.0, 3.0, 5.0) == 5.0  # straight on: cruise
    assert corner_speed_mps(math.radians(12), 2.0, 3.0, 5.0) == 5.0  # capped at cruise
    assert corner_speed_mps(math.pi, 2.0, 3.0, 5.0) == 0.0  # a reversal stops


def test_the_mission_is_repeated_bit_for_bit():
    first = mission_flight(six_waypoints(), 20.0).log
    second = mission_flight(six_waypoints(), 20.0).log
    assert np.array_equal(first, second)


def test_a_hold_time_keeps_the_vehicle_on_its_waypoint():
    items = [mission_item(0, 0, 0, 3.0, TAKEOFF),
             mission_item(1, 10, 0, 3.0, params=(4.0, 0.0, 0.0, math.nan)),
             mission_item(2, 10, 10, 3.0)]
    f = mission_flight(items, 25.0)
    assert f.vehicle.reached == [0, 1, 2]
    assert time_within(f.log, (10, 0, -3), 0.05) == pytest.approx(4.17, abs=0.05)
    assert f.vehicle.navigator.complete and f.vehicle.armed  # finished in the air: holds


def test_loiter_time_and_delay_wait_where_they_are():
    items = [mission_item(0, 0, 0, 3.0, TAKEOFF),
             mission_item(1, 8, 0, 3.0, M.MAV_CMD_NAV_LOITER_TIME, (3.0, 0, 0, 0)),
             do_item(2, M.MAV_CMD_NAV_DELAY, (2.0, -1, -1, -1)),
             mission_item(3, 0, 0, 3.0)]
    f = mission_flight(items, 30.0)
    assert f.vehicle.reached == [0, 1, 2, 3]
    assert time_within(f.log, (8, 0, -3), 0.05) == pytest.approx(5.33, abs=0.05)  # 3 s + 2 s


def test_do_jump_repeats_and_do_change_speed_slows():
    items = [mission_item(0, 0, 0, 3.0, TAKEOFF),
             do_item(1, M.MAV_CMD_DO_CHANGE_SPEED, (1, 2.0, -1, 0)),
             mission_item(2, 10, 0, 3.0),
             mission_item(3, 10, 5, 3.0),
             do_item(4, M.MAV_CMD_DO_JUMP, (2, 2, 0, 0)),
             mission_item(5, 0, 0, 3.0)]
    f = mission_flight(items, 60.0)
    assert f.vehicle.reached == [0, 2, 3, 2, 3, 2, 3, 5]
    assert reference_speed(f.log).max() == pytest.approx(2.0, abs=1e-9)
    assert speed(f.log).max() == pytest.approx(2.19, abs=0.01)  # the vehicle's overshoot


def test_a_mission_without_take_off_climbs_straight_up_first():
    f = mission_flight([mission_item(0, 10, 0, 4.0)], 15.0)
    log = f.log
    below = -log[:, 3] < 3.0  # below where the first item is reached (4 - 0.8 m)
    assert np.abs(log[below, 1:3]).max() < 0.01
    assert f.vehicle.reached == [0]
    assert np.linalg.norm(log[-1, POS] - (10, 0, -4)) < 0.01


def test_a_mission_ending_in_return_lands_at_home():
    f = mission_flight(six_waypoints(last=RTL)[:3] + [do_item(3, RTL, (0, 0, 0, 0))], 60.0)
    assert f.vehicle.reached == [0, 1, 2]
    assert not f.vehicle.armed
    assert (f.vehicle.mission.current, f.vehicle.mission_state) == (0, "not started")
    assert np.hypot(*f.log[-1, 1:3]) < 0.01 and -f.log[:, 3].min() == pytest.approx(10.0,
                                                                                    abs=0.01)


def test_pause_stops_on_the_leg_and_resume_finishes_the_mission():
    f = mission_flight(six_waypoints(), 9.0)  # on the first leg, at speed
    assert f.vehicle.mission_active and f.vehicle.mission.current == 1
    f.vehicle.set_mode(FlightMode.HOLD, f.t_s)
    f.run(7.0)
    stopped = f.log[-1]
    assert np.hypot(*stopped[VEL][0:2]) < 0.01 and abs(stopped[2]) < 0.02  # on the leg
    assert not f.vehicle.mission_active and f.vehicle.navigator.runner is not None  # paused
    f.vehicle.set_mode(FlightMode.MISSION, f.t_s)
    f.run(75.0)
    assert f.vehicle.reached == list(range(8)) and not f.vehicle.armed


def test_mission_mode_needs_a_mission_and_start_checks_the_item():
    f = Flight()
    f.run(0.05)
    with pytest.raises(RefusedError, match="no mission uploaded"):
        f.vehicle.set_mode(FlightMode.MISSION, f.t_s)
    f.vehicle.mission.replace(MISSION, tuple(six_waypoints()))
    with pytest.raises(RefusedError, match="no item 8"):
        f.vehicle.auto.start_mission(8, f.t_s)
    f.vehicle.auto.start_mission(2, f.t_s)
    assert f.vehicle.mode == FlightMode.MISSION and f.vehicle.mission.current == 2


# -- return and go-to ------------------------------------------------------------------
@pytest.fixture(scope="module")
def far_away():
    """Taken off to 5 m, then gone to 50 m north."""
    f = Flight()
    f.take_off(5.0)
    f.vehicle.auto.reposition(np.array([50.0, 0.0, -5.0]), math.radians(90.0), -1.0)
    f.run(20.0)
    return f


def test_go_to_reaches_the_position_and_holds_it(far_away):
    f = far_away
    assert f.vehicle.mode == FlightMode.HOLD
    assert np.linalg.norm(f.log[-1, POS] - (50, 0, -5)) == pytest.approx(0.0012, abs=0.001)
    assert f.log[-1, 9] == pytest.approx(math.pi / 2, abs=1e-3)  # the yaw it asked for


def test_return_from_50_m_lands_at_home_and_disarms(far_away):
    f = Flight()
    f.take_off(5.0)
    f.vehicle.auto.reposition(np.array([50.0, 0.0, -5.0]), math.nan, -1.0)
    f.run(20.0)
    f.vehicle.set_mode(FlightMode.RTL, f.t_s)
    start = f.t_s
    f.run(40.0)
    log = f.since(start)
    assert not f.vehicle.armed and f.vehicle.mode == FlightMode.HOLD
    assert np.hypot(*log[-1, 1:3]) == pytest.approx(0.0017, abs=0.001)  # target: <= 1 m
    assert -log[:, 3].min() == pytest.approx(10.0, abs=0.01)  # RTL_RETURN_ALT
    assert "landed: disarmed" in [text for _, text in f.vehicle.messages]


def test_return_above_the_return_altitude_keeps_its_altitude():
    f = Flight(parameters={"RTL_RETURN_ALT": 4.0, "RTL_DESCEND_ALT": 2.0})
    f.take_off(6.0)
    f.vehicle.auto.reposition(np.array([10.0, 0.0, -6.0]), math.nan, -1.0)
    f.run(8.0)
    f.vehicle.set_mode(FlightMode.RTL, f.t_s)
    f.run(25.0)
    assert -f.log[:, 3].min() == pytest.approx(6.0, abs=0.01)
    assert not f.vehicle.armed


def test_go_to_at_a_given_speed_and_refusals():
    f = Flight()
    f.run(0.05)
    with pytest.raises(RefusedError, match="not in the air"):
        f.vehicle.auto.reposition(np.array([5.0, 0.0, -5.0]), math.nan, -1.0)
    with pytest.raises(RefusedError, match="not in the air"):
        f.vehicle.set_mode(FlightMode.RTL, f.t_s)
    f.take_off(3.0)
    with pytest.raises(RefusedError, match="finite or NaN"):
        f.vehicle.auto.reposition(np.array([math.inf, 0.0, -5.0]), math.nan, -1.0)
    with pytest.raises(RefusedError, match="more than 1 km"):
        f.vehicle.auto.reposition(np.array([2000.0, 0.0, -5.0]), math.nan, -1.0)
    f.vehicle.auto.reposition(np.array([20.0, math.nan, math.nan]), math.nan, 2.0)
    f.run(15.0)
    assert reference_speed(f.log).max() == pytest.approx(2.0, abs=1e-9)
    assert speed(f.log).max() == pytest.approx(2.17, abs=0.01)
    assert np.linalg.norm(f.log[-1, POS] - (20, 0, -3)) < 0.01  # NaN kept east and altitude


@pytest.mark.parametrize("how", ["geofence", "ground station"])
def test_return_as_the_action_of_fence_and_ground_station_loss(how):
    params = ({"GF_ACTION": 3.0, "GF_MAX_HOR_DIST": 8.0} if how == "geofence"
              else {"NAV_DLL_ACT": 2.0, "COM_DL_LOSS_T": 2.0})
    f = Flight(parameters=params)
    f.vehicle.inputs.gcs_heartbeat(0.0)
    f.take_off(3.0)
    if how == "ground station":
        f.run(2.5)  # no heartbeat since t = 0
    else:
        f.vehicle.auto.reposition(np.array([15.0, 0.0, -3.0]), math.nan, -1.0)
        f.run(6.0)
    assert f.vehicle.mode == FlightMode.RTL and f.vehicle.failsafe is not None
    f.run(40.0)
    assert not f.vehicle.armed and np.hypot(*f.log[-1, 1:3]) < 0.01


# -- manual flight ---------------------------------------------------------------------
def manual_flight(mode: FlightMode, yaw_rad: float = 0.0, **parameters) -> Flight:
    f = Flight(yaw_rad=yaw_rad, parameters=parameters or None)
    f.take_off(5.0)
    f.vehicle.inputs.manual_input(f.t_s, Sticks())
    f.vehicle.set_mode(mode, f.t_s)
    return f


def sticks(f: Flight, duration_s: float, **positions) -> None:
    """Send MANUAL_CONTROL at 50 Hz (every other control period)."""
    f.run(duration_s, lambda t: f.vehicle.inputs.manual_input(t, Sticks(**positions))
          if f.steps % 2 == 0 else None)


def test_posctl_full_forward_stick_flies_mpc_vel_manual_and_centred_holds():
    f = manual_flight(FlightMode.POSCTL, yaw_rad=math.pi / 2)  # facing east
    sticks(f, 8.0, forward=1.0)
    v = f.log[-1, VEL]
    assert v[1] == pytest.approx(5.0, rel=0.001) and abs(v[0]) < 1e-3  # target: +-10 %
    sticks(f, 7.0)  # centred: brake to a stop
    start = f.t_s
    sticks(f, 10.0)
    held = f.since(start)[:, POS]
    drift = float(np.max(np.linalg.norm(held - held[0], axis=1)))
    assert drift == pytest.approx(0.0041, abs=0.001)  # target: <= 0.3 m
    assert abs(f.log[-1, 3] + 5.0) < 0.01  # altitude kept


def test_posctl_throttle_climbs_and_yaw_stick_turns():
    f = manual_flight(FlightMode.POSCTL)
    sticks(f, 4.0, throttle=1.0, yaw=1.0)
    log = f.log
    assert -log[-1, 6] == pytest.approx(3.0, abs=0.02)  # MPC_Z_VEL_MAX_UP
    rate = np.diff(np.unwrap(log[-50:, 9])) / f.period_s
    assert rate.mean() == pytest.approx(math.radians(45.0), rel=0.01)  # MPC_YAWRAUTO_MAX


def test_altctl_sticks_tilt_and_centred_throttle_holds_the_altitude():
    f = manual_flight(FlightMode.ALTCTL)
    sticks(f, 1.5, right=1.0)
    roll = f.log[-1, 7]
    assert roll == pytest.approx(math.radians(35.0), abs=0.01)  # MPC_MAN_TILT_MAX
    altitude = f.since(f.t_s - 1.0)[:, 3]
    assert np.abs(altitude + 5.0).max() < 0.05


def test_stabilized_centred_throttle_hovers():
    f = manual_flight(FlightMode.STABILIZED)
    sticks(f, 3.0)
    assert abs(f.log[-1, 6]) < 0.05 and abs(f.log[-1, 3] + 5.0) < 0.1


def test_manual_control_loss_returns_and_manual_modes_need_sticks():
    f = Flight()
    f.take_off(3.0)
    with pytest.raises(RefusedError, match="posctl denied: no manual control input"):
        f.vehicle.set_mode(FlightMode.POSCTL, f.t_s)
    f.vehicle.inputs.manual_input(f.t_s, Sticks())
    f.vehicle.set_mode(FlightMode.POSCTL, f.t_s)
    f.run(0.6)  # COM_RC_LOSS_T 0.5 s
    assert f.vehicle.mode == FlightMode.RTL and f.vehicle.failsafe == "manual control lost"


def test_throttle_down_lands_and_disarms_in_posctl():
    f = manual_flight(FlightMode.POSCTL)
    sticks(f, 12.0, throttle=0.0)
    assert not f.vehicle.armed


def test_sticks_are_checked_and_shaped_as_px4_reads_them():
    assert sticks_from_manual_control(1000, -500, 500, 0) == Sticks(1.0, -0.5, 0.5, 0.0)
    for bad in ((1001, 0, 500, 0), (0, 0, -1, 0), (0, 0, 500, -32768)):
        with pytest.raises(RefusedError, match="outside"):
            sticks_from_manual_control(*bad)
    assert deadband(0.1, 0.1) == 0.0 and deadband(1.0, 0.1) == 1.0
    assert deadband(0.55, 0.1) == pytest.approx(0.5)
    assert expo(1.0, 0.6) == 1.0 and expo(0.5, 0.6) == pytest.approx(0.275)


# -- the navigator alone -------------------------------------------------------------------
def test_a_jump_loop_without_a_position_ends_the_mission_instead_of_stalling():
    from autopilot.navigator.mission_runner import Event, EventKind, MissionRunner
    from autopilot.parameters import default_parameters

    items = (mission_item(0, 5, 0, 3.0), do_item(1, M.MAV_CMD_DO_JUMP, (2, -1, 0, 0)),
             do_item(2, M.MAV_CMD_DO_JUMP, (1, -1, 0, 0)))
    runner = MissionRunner(items, default_parameters(), Places.at(DEFAULT_HOME))
    runner.start(1, np.zeros(3), 0.0, False, 2.5)
    runner.step(0.0, np.zeros(3), np.zeros(3))
    assert runner.finished
    assert runner.events[-1] == Event(EventKind.FINISHED,
                                      text="mission stopped: DO_JUMP loop without a position")


def test_local_ned_items_are_metres_from_home():
    from autopilot.navigator.mission_runner import item_position_ned
    from autopilot.navigator.mission_store import MissionItem

    item = MissionItem(0, M.MAV_FRAME_LOCAL_NED, WAYPOINT, 0, 1, (0, 0, 0, math.nan),
                       4.0, -3.0, -6.0)
    at_home = Places.at(DEFAULT_HOME)
    assert np.array_equal(item_position_ned(item, np.zeros(3), at_home), (4.0, -3.0, -6.0))
    # GLOBAL_INT: the altitude is AMSL (home is 488 m).
    amsl = dataclasses.replace(mission_item(0, 10.0, 20.0, 0.0), frame=M.MAV_FRAME_GLOBAL_INT,
                               z=498.0)
    assert np.allclose(item_position_ned(amsl, np.zeros(3), at_home), (10.0, 20.0, -10.0),
                       atol=0.01)


def test_loiter_unlimited_holds_and_payload_items_are_passed_over():
    items = [mission_item(0, 0, 0, 3.0, TAKEOFF),
             do_item(1, M.MAV_CMD_IMAGE_START_CAPTURE, (0, 1, 0, 0)),
             mission_item(2, 6, 0, 3.0, M.MAV_CMD_NAV_LOITER_UNLIM, (0, 0, 0, math.nan)),
             mission_item(3, 0, 0, 3.0)]
    f = mission_flight(items, 30.0)
    assert f.vehicle.reached == [0, 2] and f.vehicle.mission.current == 2
    assert np.linalg.norm(f.log[-1, POS] - (6, 0, -3)) < 0.01


def test_change_speed_in_flight_sets_the_mission_speed():
    f = mission_flight(six_waypoints(), 6.0)
    with pytest.raises(RefusedError, match="outside"):
        f.vehicle.auto.change_speed(0.0)
    f.vehicle.auto.change_speed(2.0)
    start = f.t_s
    f.run(10.0)
    # On cruise; leaving a rounded corner, the reference turns its acceleration at the
    # jerk limit and passes the speed by a little (here 0.004 %, below: 2.4 %).
    assert reference_speed(f.since(start + 3.0)).max() == pytest.approx(2.0000754, abs=1e-6)


def test_a_mission_uploaded_in_flight_is_flown_and_a_cleared_one_holds():
    f = mission_flight(six_waypoints(), 8.0)
    f.vehicle.mission.replace(MISSION, (mission_item(0, -5, -5, 4.0),))
    f.run(15.0)
    assert f.vehicle.reached[-1] == 0 and f.vehicle.navigator.complete
    assert np.linalg.norm(f.log[-1, POS] - (-5, -5, -4)) < 0.01
    f.vehicle.mission.clear(MISSION)
    f.run(0.02)
    assert f.vehicle.mode == FlightMode.HOLD and f.vehicle.armed
    assert "mission cleared: holding" in [text for _, text in f.vehicle.messages]


def test_setting_the_current_item_in_flight_goes_on_from_there():
    f = mission_flight(six_waypoints(), 9.0)  # on the leg to item 1
    f.vehicle.mission.set_current(4)  # MISSION_SET_CURRENT
    f.run(25.0)
    assert f.vehicle.reached[:3] == [0, 4, 5]


def test_parameters_changed_in_a_mission_apply_at_once_and_a_new_upload_is_not_started():
    f = mission_flight(six_waypoints(), 6.0)
    f.vehicle.set_parameter("MPC_XY_CRUISE", 2.0)
    start = f.t_s
    f.run(8.0)
    assert reference_speed(f.since(start + 2.0)).max() == pytest.approx(2.04743, abs=1e-5)
    f.vehicle.set_mode(FlightMode.HOLD, f.t_s)
    assert f.vehicle.mission_state == "paused"
    f.vehicle.mission.replace(MISSION, tuple(six_waypoints()))
    assert f.vehicle.mission_state == "not started"


def test_a_loiter_time_cross_track_flag_is_not_a_heading():
    items = [mission_item(0, 0, 0, 3.0, TAKEOFF),
             mission_item(1, 0, 8, 3.0, M.MAV_CMD_NAV_LOITER_TIME, (1.0, 0, 0, 0.0))]
    f = mission_flight(items, 15.0)
    assert f.log[-1, 9] == pytest.approx(math.pi / 2, abs=1e-3)  # faced the item (east)


def test_altctl_yaw_stick_turns_and_stops_when_centred():
    f = manual_flight(FlightMode.ALTCTL)
    sticks(f, 2.0, yaw=1.0)
    turned = f.log[-1, 9]
    sticks(f, 3.0)
    after = float(np.unwrap(f.since(f.t_s - 3.0)[:, 9])[-1])
    assert turned == pytest.approx(math.radians(72.0), abs=0.05)  # 45 deg/s after 0.4 s
    # Then only the braking: 45 deg/s stopped at MPC_YAWRAUTO_ACC 60 deg/s^2 is 17 deg.
    assert after - turned == pytest.approx(0.31, abs=0.02)


def test_path_metrics_of_a_flight_along_the_planned_legs():
    """The six-waypoint plan flown exactly along its legs: every item reached, no
    cross-track error (the planned legs are placed around the scenario's home)."""
    from autopilot.navigator.mission_runner import WAYPOINT_COMMANDS, item_position_ned
    from ground.record.run_files import RunRecord
    from ground.report.metrics import path_metrics
    from ground.scenario.scenario_file import scenario_by_name

    scenario = scenario_by_name("mission-six-waypoints")
    corners = [np.zeros(3)]
    for item in scenario.mission_items:
        if item.command in (M.MAV_CMD_NAV_TAKEOFF, *WAYPOINT_COMMANDS):
            corners.append(item_position_ned(item, corners[-1], Places.at(scenario.home)))
    path = np.concatenate([np.linspace(a, b, 200, endpoint=False)
                           for a, b in zip(corners[:-1], corners[1:], strict=True)]
                          + [corners[-1][None, :]])
    n = len(path)
    state = np.zeros((n, 12))
    state[:, 0:3] = path
    record = RunRecord("mission-six-waypoints", "ivfc", "rigid-body", 0.01,
                       np.arange(n) * 0.01, state, np.zeros((n, 18)), np.zeros((n, 2)),
                       np.zeros((n, 4)), np.zeros((n, 6, 10)), np.zeros((n, 6)), [], 0.0,
                       False)
    metrics = path_metrics(record, scenario)
    assert metrics["all_reached"]
    assert len(metrics["items"]) == len(corners) - 1
    assert metrics["cross_track_max_m"] < 1e-9
    # Each corner is reached on its way in, inside the acceptance radius before the corner.
    assert all(a is not None for a in metrics["arrival_s"])
    assert metrics["arrival_s"] == sorted(metrics["arrival_s"])
