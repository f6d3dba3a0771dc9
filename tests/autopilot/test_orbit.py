"""ORBIT (MAV_CMD_DO_ORBIT), the mode added as one row and one flight task, flown in
process on sim time (tests/flight.py); the MAVSDK do_orbit flight is in
test_mavsdk_navigation.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.commander.modes import MODES
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode, mode_from_px4, px4_custom_mode
from tests.flight import Flight


def _orbit(radius_m: float, speed_mps: float, yaw: int, seconds: float = 30.0):
    f = Flight()
    f.take_off(3.0)
    f.vehicle.tasks[FlightMode.ORBIT].request(np.array([5.0, 0.0, math.nan]), radius_m,
                                              speed_mps, yaw)
    f.vehicle.set_mode(FlightMode.ORBIT, f.t_s)
    start = f.t_s
    f.run(seconds)
    return f, f.since(start + 10.0)  # after flying onto the circle


def test_an_orbit_holds_its_radius_speed_and_altitude_facing_the_centre():
    f, log = _orbit(5.0, 2.0, 0)
    pos = log[:, 1:4]
    radius = np.hypot(pos[:, 0] - 5.0, pos[:, 1])
    speed = np.hypot(log[:, 4], log[:, 5])
    assert f.vehicle.mode == FlightMode.ORBIT
    # Golden (in process, bit for bit): radius error 1.8 mm RMSE, speed 2.0007 m/s.
    assert np.sqrt(np.mean((radius - 5.0) ** 2)) == pytest.approx(0.00184, abs=0.0003)
    assert speed.mean() == pytest.approx(2.0007, abs=0.001)
    assert np.all(np.abs(pos[:, 2] + 3.0) < 0.001)
    face = np.arctan2(-pos[:, 1], 5.0 - pos[:, 0])
    # The yaw shaper has no rate feed-forward: it lags the turning bearing by 0.2 rad.
    assert np.abs(np.angle(np.exp(1j * (log[:, 9] - face)))).max() == pytest.approx(
        0.201, abs=0.01)
    assert f.vehicle.messages[-2:] == [(6, "orbit r 5.0 m at 2.0 m/s"), (6, "mode orbit")]


def test_a_negative_radius_orbits_counter_clockwise_and_speed_is_capped_by_acc_hor():
    _, log = _orbit(-5.0, 20.0, 1, seconds=25.0)
    pos, vel = log[:, 1:4], log[:, 4:7]
    rel = pos[:, 0:2] - (5.0, 0.0)
    turn = rel[:, 0] * vel[:, 1] - rel[:, 1] * vel[:, 0]  # > 0: clockwise from above (NED)
    assert np.all(turn < 0.0)
    # sqrt(0.5 MPC_ACC_HOR r) = sqrt(0.5 * 3 * 5) = 2.74 m/s, not the 20 m/s asked for.
    speed = np.hypot(vel[:, 0], vel[:, 1])[-500:]  # the last 5 s
    assert speed.mean() == pytest.approx(2.7452, abs=0.001)  # golden: 0.2 % fast
    assert speed.max() - speed.min() < 0.02  # steady within 0.6 %


@pytest.mark.parametrize("samples_arrive", [False, True])
@pytest.mark.parametrize(("lost", "golden_mm_s"), [(3, 0.70), (19, 1.11)])
def test_lost_periods_do_not_put_the_orbit_behind_the_vehicle(lost, golden_mm_s,
                                                               samples_arrive):
    """A late real-time step loses whole periods while the simulator flies on (its plant
    holding the last command). The circle moves on by sim time and the lost periods are
    shaped one by one, so the vehicle flies on as if none were lost. ``samples_arrive``:
    as the real-time loop does, every sample is taken as it arrives and the step takes
    the newest again (counted twice, the setpoints moved on a period per step whatever
    was lost: the real-time orbit slowed 29 mm/s while this test, without it, passed)."""
    f, _ = _orbit(4.0, 1.5, 0, seconds=20.0)
    f.run(0.1, samples_arrive=samples_arrive)
    orbit = f.vehicle.tasks[FlightMode.ORBIT]
    lost_at, angle = f.t_s, orbit._angle_rad
    f.lose(lost, samples_arrive=samples_arrive)
    f.run(0.01, samples_arrive=samples_arrive)
    # The point on the circle moved on by all the periods of sim time, not by one step.
    assert orbit._angle_rad - angle == pytest.approx(1.5 / 4.0 * 0.01 * (lost + 1), rel=1e-9)
    assert f.vehicle.state.step_periods == lost + 1
    f.run(3.0, samples_arrive=samples_arrive)
    speed = np.hypot(*f.since(lost_at)[:, 4:6].T)
    # Golden (in process): 3 lost, 0.70 mm/s at most, as losing none (0.71 mm/s); 19 lost
    # (200 ms between steps), 1.11 mm/s. The held command costs nothing measurable (the
    # controller run on every sample, the command held: 0.71); 3 lost shaped in one 40 ms
    # step, 4.6 mm/s; the circle moved on by one period, 39.6 mm/s; 19 lost with the step
    # capped at 50 ms (before 0.5 s), 350 mm/s.
    assert np.abs(speed - 1.5).max() == pytest.approx(golden_mm_s / 1e3, abs=0.0001)


def test_orbit_is_refused_on_the_ground_and_for_bad_circles_and_the_mode_is_unchanged():
    f = Flight()
    f.run(0.05)
    task = f.vehicle.tasks[FlightMode.ORBIT]
    task.request(np.array([5.0, 0.0, math.nan]), 5.0, 2.0, 0)
    with pytest.raises(RefusedError, match="orbit denied: not in the air"):
        f.vehicle.set_mode(FlightMode.ORBIT, f.t_s)
    assert f.vehicle.mode == FlightMode.HOLD
    for radius, speed, yaw, text in ((0.5, 1.0, 0, "radius 0.5 m is outside"),
                                     (math.inf, 1.0, 0, "finite or NaN"),
                                     (5.0, 0.0, 0, "speed 0 m/s is outside"),
                                     (5.0, 1.0, 7, "yaw behaviour 7 is unknown")):
        with pytest.raises(RefusedError, match=text):
            task.request(np.zeros(3), radius, speed, yaw)


def test_every_mode_has_a_row_and_orbit_has_px4s_number():
    assert set(MODES) == set(FlightMode)
    assert mode_from_px4(px4_custom_mode(FlightMode.ORBIT)) == FlightMode.ORBIT
    assert mode_from_px4((3 << 16) | (0 << 24)) == FlightMode.POSCTL
    assert mode_from_px4((3 << 16) | (7 << 24)) == FlightMode.POSCTL  # any other sub mode


def test_the_setpoints_advance_by_the_sim_time_between_samples():
    from autopilot.flight_tasks.task import MAX_SETPOINT_STEP_S

    state = Flight().vehicle.state
    m = np.zeros(12)
    steps = []
    # Two periods lost; the same sample again (a period ahead), made up by the next one;
    # a new simulator (the clock goes back); a stall.
    for t_s in (0.0, 0.01, 0.02, 0.05, 0.05, 0.07, 0.03, 1.0, 1.01):
        state.new_sample(t_s, m)
        state.begin_step()
        steps.append((state.step_s, state.step_periods))
    assert steps == [(0.01, 1), (0.01, 1), (0.01, 1), (0.03, 3), (0.01, 1), (0.01, 1),
                     (0.01, 1), (MAX_SETPOINT_STEP_S, 50), (0.01, 1)]
    # Samples taken between steps (real time takes each as it arrives, and the step the
    # newest again) do not count: the step moves on by the sim time since the last step.
    for t_s in (1.02, 1.03, 1.04, 1.04):
        state.new_sample(t_s, m)
    state.begin_step()
    assert (state.step_s, state.step_periods) == (0.03, 3)
    # Lockstep: exactly one period per sample, bit for bit, however long the flight.
    for k in range(2, 100_000, 997):
        state.new_sample((k - 1) * 0.01, m)
        state.begin_step()
        state.new_sample(k * 0.01, m)
        state.begin_step()
        assert (state.step_s, state.step_periods) == (0.01, 1)
