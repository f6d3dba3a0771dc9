"""Setpoint shaping (autopilot/flight_tasks/shaping.py) and the one angle wrap
(contracts/frames.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.flight_tasks.shaper import SetpointShaper
from autopilot.flight_tasks.shaping import (
    Setpoint,
    ShapingLimits,
    sqrt_controller,
    velocity_filter_omega,
)
from contracts.frames import wrap_pi, wrap_pi_array
from contracts.vectors import REF_ACC, REF_EULER, REF_EULER_RATE, REF_POS, REF_VEL

DT = 0.01
DEFAULT = ShapingLimits(5.0, 3.0, 1.5, 3.0, 4.0, 3.0, 4.0, math.radians(45), math.radians(60))
BRISK = ShapingLimits(12.0, 4.0, 2.0, 5.0, 6.0, 5.0, 10.0, math.radians(90), math.radians(180))
GENTLE = ShapingLimits(2.0, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0, math.radians(20), math.radians(30))


def fly(setpoint_at, duration_s: float, limits: ShapingLimits = DEFAULT,
        start=(0.0, 0.0, 0.0), start_velocity=(0.0, 0.0, 0.0), yaw_rad: float = 0.0
        ) -> np.ndarray:
    """The reference vectors, one row per period; ``setpoint_at(t)`` gives the setpoint."""
    shaper = SetpointShaper()
    shaper.reset(np.array(start, dtype=float), np.array(start_velocity, dtype=float), yaw_rad)
    return np.array([shaper.step(setpoint_at(k * DT), limits, DT)
                     for k in range(round(duration_s / DT))])


def at(north: float, east: float, down: float, yaw_rad: float = math.nan) -> Setpoint:
    return Setpoint(np.array([north, east, down]), yaw_rad=yaw_rad)


def moving(north: float, east: float, down: float) -> Setpoint:
    return Setpoint(velocity_ned_mps=np.array([north, east, down]))


# -- wrap_pi ---------------------------------------------------------------------------
@pytest.mark.parametrize("angle, wrapped", [
    (0.0, 0.0), (1.0, 1.0), (math.pi, -math.pi), (-math.pi, -math.pi),
    (3.0 * math.pi, -math.pi), (2.0 * math.pi, 0.0), (-3.1 - 3.1, 2.0 * math.pi - 6.2),
    (math.radians(270.0), math.radians(-90.0)), (7.0 * 2.0 * math.pi + 0.5, 0.5),
])
def test_wrap_pi_maps_into_minus_pi_to_pi(angle: float, wrapped: float) -> None:
    out = wrap_pi(angle)
    assert -math.pi <= out < math.pi
    assert out == pytest.approx(wrapped, abs=1e-12)


def test_wrap_pi_leaves_angles_in_range_untouched_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    inside = rng.uniform(-math.pi, math.pi, 10_000)
    assert all(wrap_pi(a) == a for a in inside)
    assert np.array_equal(wrap_pi_array(inside), inside)
    assert math.isnan(wrap_pi(math.nan))
    outside = rng.uniform(-50.0, 50.0, 1000)
    wrapped = wrap_pi_array(outside)
    assert np.all((wrapped >= -math.pi) & (wrapped < math.pi))
    assert np.allclose(np.cos(wrapped), np.cos(outside)) and np.allclose(
        np.sin(wrapped), np.sin(outside))


def test_wrap_pi_array_is_wrap_pi_bit_for_bit() -> None:
    """The array wrap (numpy, for the reports) against the compiled scalar one the
    controller uses: every finite angle, the edges and their neighbours, several turns."""
    rng = np.random.default_rng(1)
    edges = np.array([math.pi, -math.pi, 2 * math.pi, -2 * math.pi, 3 * math.pi, 0.0, -0.0])
    angles = np.concatenate([
        rng.uniform(-1e3, 1e3, 20_000), rng.uniform(-1e12, 1e12, 1000), edges,
        np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf), [np.nan]]).reshape(-1, 2)
    wrapped = wrap_pi_array(angles)
    assert wrapped.shape == angles.shape
    expected = np.array([wrap_pi(a) for a in angles.ravel()]).reshape(angles.shape)
    assert expected.tobytes() == wrapped.tobytes()
    assert np.isnan(wrap_pi_array(np.array([np.inf, -np.inf]))).all()


# -- the sqrt controller ---------------------------------------------------------------
def test_sqrt_controller_is_linear_near_zero_and_a_braking_speed_beyond() -> None:
    gain, accel = 1.5, 2.0
    assert sqrt_controller(0.1, gain, accel) == pytest.approx(0.15)
    assert sqrt_controller(-0.1, gain, accel) == pytest.approx(-0.15)
    # Far away it is the speed from which a constant deceleration stops at the target.
    d = 40.0
    assert sqrt_controller(d, gain, accel) == pytest.approx(
        math.sqrt(2.0 * accel * (d - 0.5 * accel / gain**2)))
    # Continuous where the two parts meet.
    knee = accel / gain**2
    assert sqrt_controller(knee * (1 + 1e-9), gain, accel) == pytest.approx(
        sqrt_controller(knee, gain, accel), rel=1e-6)


# -- position setpoints ----------------------------------------------------------------
@pytest.mark.parametrize("limits", [DEFAULT, BRISK, GENTLE], ids=["default", "brisk", "gentle"])
@pytest.mark.parametrize("distance_m", [0.05, 0.5, 2.0, 7.0, 10.0, 25.0, 60.0])
def test_position_steps_arrive_without_overshoot_within_every_limit(limits, distance_m):
    ref = fly(lambda t: at(distance_m, 0.0, 0.0), 60.0, limits)
    x, v, a = ref[:, REF_POS], ref[:, REF_VEL], ref[:, REF_ACC]
    jerk = np.diff(a) / DT
    assert x.max() <= distance_m + 1e-9
    assert x[-1] == pytest.approx(distance_m, abs=1e-6)
    assert np.abs(v).max() <= limits.xy_vel_max_mps + 1e-9
    assert np.abs(a).max() <= limits.acc_hor_mps2 + 1e-9
    assert np.abs(jerk).max() <= limits.jerk_mps3 + 1e-6
    assert np.all(v >= -1e-9)  # never backs up


def test_a_long_step_cruises_at_the_speed_limit() -> None:
    ref = fly(lambda t: at(50.0, 0.0, 0.0), 25.0)
    speed = ref[:, REF_VEL]
    assert speed.max() == pytest.approx(DEFAULT.xy_vel_max_mps, rel=1e-6)
    # Golden: reaches 50 m (within 1 cm) 14.86 s after the step.
    arrival = np.argmax(ref[:, REF_POS] > 50.0 - 0.01) * DT
    assert arrival == pytest.approx(14.86, abs=0.02)


def test_horizontal_steps_fly_the_straight_line() -> None:
    ref = fly(lambda t: at(30.0, -40.0, 0.0), 30.0)
    north, east = ref[:, REF_POS], ref[:, REF_POS + 1]
    # Every point lies on the segment from the origin to (30, -40).
    assert np.abs(north * 40.0 + east * 30.0).max() / 50.0 < 1e-9
    assert np.hypot(ref[:, REF_VEL], ref[:, REF_VEL + 1]).max() == pytest.approx(5.0)
    assert np.hypot(ref[:, REF_ACC], ref[:, REF_ACC + 1]).max() <= 3.0 + 1e-9


@pytest.mark.parametrize("down_m, speed_limit", [(-10.0, 3.0), (8.0, 1.5)])
def test_vertical_steps_have_separate_climb_and_descent_limits(down_m, speed_limit):
    ref = fly(lambda t: at(0.0, 0.0, down_m), 30.0)
    z, vz, az = ref[:, REF_POS + 2], ref[:, REF_VEL + 2], ref[:, REF_ACC + 2]
    assert z[-1] == pytest.approx(down_m, abs=1e-6)
    assert (z.min() >= down_m - 1e-9) if down_m < 0 else (z.max() <= down_m + 1e-9)
    assert np.abs(vz).max() == pytest.approx(speed_limit, rel=1e-3)
    assert az.min() >= -DEFAULT.acc_up_mps2 - 1e-9 and az.max() <= DEFAULT.acc_down_mps2 + 1e-9


def test_a_moving_start_is_carried_over_and_brakes_to_the_target() -> None:
    ref = fly(lambda t: at(0.0, 0.0, 0.0), 20.0, start_velocity=(4.0, 0.0, 0.0))
    # No jump: the first reference continues the motion it was handed.
    assert ref[0, REF_VEL] == pytest.approx(4.0, abs=0.05)
    assert ref[-1, REF_POS] == pytest.approx(0.0, abs=1e-6)


def test_feed_forward_adds_to_the_approach() -> None:
    still = fly(lambda t: at(20.0, 0.0, 0.0), 3.0)
    pushed = fly(lambda t: Setpoint(np.array([20.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])), 3.0)
    assert pushed[-1, REF_POS + 1] > still[-1, REF_POS + 1] + 1.0


def test_stopping_point_is_ahead_of_a_moving_reference() -> None:
    shaper = SetpointShaper()
    shaper.reset(np.zeros(3), np.array([3.0, 0.0, 0.0]), 0.0)
    stop = shaper.stopping_point(DEFAULT)
    braking, k, lead = 0.7 * DEFAULT.acc_hor_mps2, 1.5, (0.7 * DEFAULT.acc_hor_mps2)**2 / 8.0
    # The jerk-limited stop (build-up, hold, ease-off) plus the offset where the last
    # stretch (v = k d) joins it with the same slope, at v = b / k - b^2 / 2j.
    junction = braking / k - lead
    offset = junction / k - ((junction + lead) ** 2 - lead**2) / (2 * braking)
    assert stop[0] == pytest.approx(3.0**2 / (2 * braking) + 3.0 * braking / (2 * 4.0)
                                    + offset)
    ref = fly(lambda t: Setpoint(stop), 15.0, start_velocity=(3.0, 0.0, 0.0))
    assert ref[:, REF_POS].max() <= stop[0] + 1e-9  # reachable without coming back


# -- velocity setpoints ----------------------------------------------------------------
def test_velocity_setpoints_are_flown_and_zero_holds_position() -> None:
    ref = fly(lambda t: moving(2.0, 0.0, 0.0) if t < 10.0 else moving(0.0, 0.0, 0.0), 20.0)
    k = round(9.0 / DT)
    assert ref[k, REF_VEL] == pytest.approx(2.0, abs=0.01)
    # Stops where the commanded velocity adds up to: 2 m/s x 10 s.
    assert ref[-1, REF_POS] == pytest.approx(20.0, abs=1e-3)
    assert np.abs(ref[-100:, REF_VEL]).max() < 1e-3


def test_a_velocity_box_ends_where_it_began_and_stays_inside_the_box() -> None:
    legs = [(0, 0, -2), (2, 0, 0), (-2, 0, 0), (0, -2, 0), (0, 2, 0), (0, 0, 0)]
    ref = fly(lambda t: moving(*legs[min(int(t // 4.0), 5)]), 40.0)
    p = ref[:, REF_POS:REF_POS + 3]
    assert np.linalg.norm(p[-1] - (0.0, 0.0, -8.0)) < 1e-6
    assert p[:, 0].min() >= -1e-6 and p[:, 0].max() <= 8.0
    assert p[:, 1].max() <= 1e-6 and p[:, 1].min() >= -8.0
    assert p[:, 2].min() >= -8.0 - 1e-6 and p[:, 2].max() <= 1e-6
    assert np.abs(ref[:, REF_ACC:REF_ACC + 2]).max() <= DEFAULT.acc_hor_mps2


def test_velocity_filter_bandwidth_respects_the_limits_at_full_speed() -> None:
    omega = velocity_filter_omega(5.0, 3.0, 4.0)
    ref = fly(lambda t: moving(5.0, 0.0, 0.0), 10.0)
    assert omega == pytest.approx(min(3.0 / (0.2707 * 5.0), math.sqrt(4.0 / (0.2306 * 5.0))),
                                  rel=1e-3)
    assert np.abs(ref[:, REF_ACC]).max() <= 3.0 + 1e-9
    assert np.abs(np.diff(ref[:, REF_ACC]) / DT).max() <= 4.0 + 1e-6
    assert ref[-1, REF_VEL] == pytest.approx(5.0, abs=0.01)


def test_velocity_limits_apply_to_velocity_setpoints() -> None:
    ref = fly(lambda t: moving(10.0, 10.0, -9.0), 20.0)
    assert np.hypot(ref[-1, REF_VEL], ref[-1, REF_VEL + 1]) == pytest.approx(5.0, abs=0.01)
    assert ref[-1, REF_VEL + 2] == pytest.approx(-3.0, abs=0.01)


def test_switching_between_velocity_and_position_is_continuous() -> None:
    ref = fly(lambda t: moving(3.0, 1.0, 0.0) if t < 5.0 else at(30.0, 0.0, 0.0)
              if t < 15.0 else moving(0.0, -2.0, 0.0), 25.0)
    for column in (REF_POS, REF_POS + 1, REF_VEL, REF_VEL + 1):
        assert np.abs(np.diff(ref[:, column])).max() < 0.1


# -- yaw -------------------------------------------------------------------------------
@pytest.mark.parametrize("start_deg, goal_deg", [(170, -170), (-170, 170), (10, -10),
                                                 (-177.6, 177.6), (0, 180), (90, 270)])
def test_yaw_goes_the_short_way_within_its_rate_limit(start_deg, goal_deg):
    start, goal = math.radians(start_deg), math.radians(goal_deg)
    ref = fly(lambda t: at(0.0, 0.0, 0.0, goal), 10.0, yaw_rad=start)
    yaw = ref[:, REF_EULER + 2]
    travelled = np.sum(np.abs(np.diff(np.unwrap(np.concatenate(([start], yaw))))))
    assert travelled == pytest.approx(abs(wrap_pi(goal - start)), abs=1e-6)
    assert np.abs(ref[:, REF_EULER_RATE + 2]).max() <= DEFAULT.yaw_rate_max_rad_s + 1e-9
    assert abs(wrap_pi(yaw[-1] - goal)) < 1e-6
    assert np.all((yaw >= -math.pi) & (yaw < math.pi))


def test_yaw_rate_setpoints_turn_at_that_rate() -> None:
    ref = fly(lambda t: Setpoint(np.zeros(3), yaw_rate_rad_s=0.5), 10.0)
    assert ref[-1, REF_EULER_RATE + 2] == pytest.approx(0.5)
    fast = fly(lambda t: Setpoint(np.zeros(3), yaw_rate_rad_s=5.0), 10.0)
    assert fast[-1, REF_EULER_RATE + 2] == pytest.approx(DEFAULT.yaw_rate_max_rad_s)


@pytest.mark.parametrize("speed_max", [0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0])
@pytest.mark.parametrize("acc_max, jerk", [(1.0, 1.0), (3.0, 4.0), (6.0, 4.0), (12.0, 10.0),
                                           (3.0, 40.0)])
def test_a_step_arrives_without_overshoot_and_never_turns_back(speed_max, acc_max, jerk):
    """From cruise into braking the deceleration has to build up at the jerk limit; the
    reference starts braking that much earlier. (Before, at 2-3 m/s it stopped short and
    came back at up to 0.34 m/s, at 8-12 m/s up to 2.6 m/s.)"""
    limits = DEFAULT._replace(xy_vel_max_mps=speed_max, acc_hor_mps2=acc_max, jerk_mps3=jerk)
    ref = fly(lambda t: at(40.0, 0.0, 0.0), 40.0 / speed_max + 20.0, limits=limits)
    assert ref[:, REF_POS].max() <= 40.0 + 1e-3
    assert ref[:, REF_VEL].min() >= -1e-3
    assert ref[-1, REF_POS] == pytest.approx(40.0, abs=1e-3)
