"""Setpoint shaping: what ground tools ask for, turned into a reference the controller can fly.

Tools send steps: a position 50 m away, a velocity out of the blue, a heading across
+-180 deg. The paper's controller tracks smooth references (its tuning is for 1 m
sinusoids), so, as PX4 puts a flight task with velocity, acceleration and jerk limits in
front of its position controller, every setpoint from a tool passes through here first.

The shaper keeps a kinematic reference (position, velocity, acceleration in NED; yaw,
yaw rate, yaw acceleration) and moves it each control period towards the setpoint.
For a position setpoint:

    position error  --braking_speed(k, braking accel, jerk)-->  velocity wanted (<= limit)
    velocity error  --sqrt_controller(4 k, jerk)-->             acceleration wanted (<= limit)
    acceleration    --at most jerk * dt per period-->           acceleration
    then integrated exactly over the period at constant jerk.

braking_speed is the speed from which a jerk-limited stop ends exactly at the target
(k * distance on the last stretch): references arrive without overshoot
(tests/autopilot/test_shaping.py). A velocity setpoint is integrated into a commanded position
and passed through a linear third-order filter (:func:`at_velocity`). Horizontal motion
is shaped as one 2-D vector, so a vehicle at rest flies to a new position on the
straight line; vertical motion has PX4's separate up / down limits; yaw goes the short
way round at MPC_YAWRAUTO_MAX.

Pure: no clocks, no I/O. The shaper's state and its step are in
autopilot/flight_tasks/shaper.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from contracts.frames import wrap_pi

# Gains of the reference's own loops (1/s). Near the target the position loop is linear
# (v = k e) and the velocity loop too (a = 4 k dv): the pair is critically damped, so
# small steps do not overshoot either. k is K_POS unless the jerk limit is too low for
# it: the exponential approach asks for a jerk of up to k * braking, so k <= jerk / braking.
K_POS = 1.5
K_VEL_PER_K_POS = 4.0
K_YAW = 2.0
K_YAW_RATE = 4.0 * K_YAW
# Braking in the position loop uses this fraction of the acceleration limit: the rest
# covers the jerk-limited build-up of the deceleration, so the reference still stops at
# the target rather than past it.
BRAKING_FRACTION = 0.7
# Peaks of the step response of w^3 / (s + w)^3 per unit step: acceleration 2 e^-2 w,
# jerk (sqrt 2 - 1) e^(sqrt 2 - 2) w^2 (at w t = 2 and 2 - sqrt 2).
PEAK_ACC_PER_OMEGA = 2.0 * math.exp(-2.0)  # 0.2707
PEAK_JERK_PER_OMEGA2 = (math.sqrt(2.0) - 1.0) * math.exp(math.sqrt(2.0) - 2.0)  # 0.2306


class ShapingLimits(NamedTuple):
    """Kinematic limits of the reference, SI units (PX4's MPC_* parameters)."""

    xy_vel_max_mps: float  # MPC_XY_VEL_MAX
    z_vel_max_up_mps: float  # MPC_Z_VEL_MAX_UP
    z_vel_max_dn_mps: float  # MPC_Z_VEL_MAX_DN
    acc_hor_mps2: float  # MPC_ACC_HOR
    acc_up_mps2: float  # MPC_ACC_UP_MAX
    acc_down_mps2: float  # MPC_ACC_DOWN_MAX
    jerk_mps3: float  # MPC_JERK_AUTO
    yaw_rate_max_rad_s: float  # MPC_YAWRAUTO_MAX, in rad/s
    yaw_acc_max_rad_s2: float  # MPC_YAWRAUTO_ACC, in rad/s^2


def limits_from_parameters(p: dict[str, float]) -> ShapingLimits:
    """The limits in SI units from the vehicle's parameters (angles there in degrees)."""
    return ShapingLimits(
        p["MPC_XY_VEL_MAX"], p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"], p["MPC_ACC_HOR"],
        p["MPC_ACC_UP_MAX"], p["MPC_ACC_DOWN_MAX"], p["MPC_JERK_AUTO"],
        math.radians(p["MPC_YAWRAUTO_MAX"]), math.radians(p["MPC_YAWRAUTO_ACC"]))


@dataclass
class Setpoint:
    """What a tool asked for, in local NED. NaN marks what it left out.

    Per axis group (horizontal x-y, vertical z): a position (with the velocity and
    acceleration as feed-forward), or else a velocity, or else nothing (stop and hold).
    Yaw: an angle, or else a rate, or else keep the heading.
    """

    position_ned_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocity_ned_mps: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    accel_ned_mps2: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    yaw_rad: float = math.nan
    yaw_rate_rad_s: float = math.nan

    def __post_init__(self) -> None:
        self.position_ned_m = np.asarray(self.position_ned_m, dtype=float)
        self.velocity_ned_mps = np.asarray(self.velocity_ned_mps, dtype=float)
        self.accel_ned_mps2 = np.asarray(self.accel_ned_mps2, dtype=float)

    def earlier(self, back_s: float) -> Setpoint:
        """Where this setpoint's own motion (its feed-forward) had it ``back_s`` ago: a
        position moves back along its velocity and acceleration, a velocity along its
        acceleration; what is left out stays left out, yaw as it is."""
        acc = np.nan_to_num(self.accel_ned_mps2, nan=0.0)
        vel = np.where(np.isnan(self.velocity_ned_mps), 0.0, self.velocity_ned_mps)
        position = self.position_ned_m - vel * back_s + acc * (0.5 * back_s * back_s)
        velocity = self.velocity_ned_mps - acc * back_s
        return Setpoint(position, velocity, self.accel_ned_mps2, self.yaw_rad,
                        self.yaw_rate_rad_s)

    @classmethod
    def hold(cls, position_ned_m, yaw_rad: float) -> Setpoint:
        return cls(position_ned_m=np.array(position_ned_m, dtype=float),
                   yaw_rad=wrap_pi(float(yaw_rad)))


@njit(cache=True)
def sqrt_controller(error: float, gain: float, second_order_limit: float) -> float:
    """The rate that closes ``error``: gain * error near zero, and beyond the point where
    the two meet, sqrt(2 a |error|) less a constant (the speed from which deceleration a
    stops exactly at zero error). Continuous, with a continuous slope."""
    if second_order_limit <= 0.0:
        return gain * error
    linear_span = second_order_limit / (gain * gain)
    if abs(error) <= linear_span:
        return gain * error
    return math.copysign(math.sqrt(2.0 * second_order_limit * (abs(error) - 0.5 * linear_span)),
                         error)


@njit(cache=True)
def _braking_junction(gain: float, braking_mps2: float, jerk_mps3: float
                      ) -> tuple[float, float, float]:
    """Where the last stretch (speed = gain * distance) meets the jerk-limited stop with
    the same slope: (lead b^2 / 2j, junction speed, the stop's distance offset)."""
    lead = braking_mps2 * braking_mps2 / (2.0 * jerk_mps3)
    junction = max(0.0, braking_mps2 / gain - lead)
    offset = junction / gain - ((junction + lead) ** 2 - lead * lead) / (2.0 * braking_mps2)
    return lead, junction, offset


@njit(cache=True)
def braking_speed(distance_m: float, gain: float, braking_mps2: float, jerk_mps3: float
                  ) -> tuple[float, float]:
    """The speed from which a jerk-limited stop ends exactly ``distance_m`` ahead, and its
    slope d(speed)/d(distance); ``gain * distance`` on the last stretch.

    The stop builds the deceleration up to ``braking`` at the jerk limit, holds it, and
    eases it off again: it needs v^2 / 2a + v a / 2j, which inverted gives the speed. The
    last stretch joins it where both have the same slope, so the deceleration the profile
    asks for (speed times slope) never jumps: a jump the reference could only follow at
    the jerk limit, braking too late and then too much, short of the target.
    """
    lead, junction, offset = _braking_junction(gain, braking_mps2, jerk_mps3)
    if gain * distance_m <= junction:
        return gain * distance_m, gain
    root = math.sqrt(lead * lead + 2.0 * braking_mps2 * (distance_m - offset))
    return root - lead, braking_mps2 / root


@njit(cache=True)
def stopping_distance(speed_mps: float, braking_mps2: float, jerk_mps3: float,
                      gain: float = K_POS) -> float:
    """Distance of the stop :func:`braking_speed` plans from ``speed_mps`` (its inverse)."""
    gain = min(gain, jerk_mps3 / braking_mps2)
    lead, junction, offset = _braking_junction(gain, braking_mps2, jerk_mps3)
    if speed_mps <= junction:
        return speed_mps / gain
    return speed_mps * speed_mps / (2.0 * braking_mps2) + speed_mps * lead / braking_mps2 \
        + offset


@njit(cache=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


@njit(cache=True)
def _norm(v: np.ndarray) -> float:
    return math.sqrt(_dot(v, v))


@njit(cache=True)
def _limit_norm(v: np.ndarray, limit: float) -> np.ndarray:
    n = _norm(v)
    return v * (limit / n) if n > limit else v.copy()


@njit(cache=True)
def _wanted_velocity(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, target: np.ndarray,
                     feed_forward: np.ndarray, speed_max: float, braking_mps2: float,
                     jerk: float, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity towards ``target`` on the straight line that can still stop there (plus
    the tool's feed-forward), and its rate of change along the reference's motion.

    The rate is the velocity loop's feed-forward: without it the loop lags the braking
    profile and the reference stops past the target. The target moves at the
    feed-forward velocity, so distances close at the velocity relative to it.
    """
    error = target - pos
    relative = vel - feed_forward
    distance = _norm(error)
    wanted = feed_forward.copy()
    wanted_rate = np.zeros_like(pos)
    if distance > 0.0:
        direction = error / distance
        # Still accelerating towards the target: that takes a / jerk to undo, and the
        # distance covered meanwhile is no longer there to brake in.
        pushing = max(0.0, _dot(acc, direction))
        unwind_s = pushing / jerk
        closing = max(0.0, _dot(relative, direction))
        ahead = closing * unwind_s + pushing * unwind_s**2 / 3.0
        # Braking harder than now takes (more - now) / jerk to build up, at about the
        # present speed: brake that much earlier, or the reference passes the curve
        # before its deceleration catches up and then stops short.
        speed, slope = braking_speed(max(0.0, distance - ahead), gain, braking_mps2, jerk)
        build_s = max(0.0, min(speed, closing) * slope - max(0.0, -_dot(acc, direction))) / jerk
        ahead += 0.5 * closing * build_s
        speed, slope = braking_speed(max(0.0, distance - ahead), gain, braking_mps2, jerk)
        if speed < speed_max:
            closing = _dot(relative, direction)
            # d/dt of speed * direction, with d(distance)/dt = -closing and the direction
            # turning by the motion across it.
            wanted_rate = (-slope * closing) * direction - (relative - closing * direction) * (
                speed / distance)
        else:
            speed = speed_max
        wanted = wanted + error * (speed / distance)
    return _limit_norm(wanted, speed_max), wanted_rate


@njit(cache=True)
def _wanted_acceleration(vel: np.ndarray, wanted_vel: np.ndarray, feed_forward: np.ndarray,
                         acc_max: float, jerk: float, gain: float) -> np.ndarray:
    """Acceleration that closes the velocity error and can still ease off at the jerk
    limit by the time it is closed, plus the feed-forward; at most ``acc_max``."""
    error = wanted_vel - vel
    n = _norm(error)
    wanted = feed_forward.copy()
    if n > 0.0:
        wanted += error * (min(acc_max, sqrt_controller(n, gain, jerk)) / n)
    return _limit_norm(wanted, acc_max)


@njit(cache=True)
def _advance(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray,
             dt: float) -> None:
    """Integrate one period exactly at constant jerk (in place)."""
    pos += vel * dt + acc * (0.5 * dt * dt) + jerk * (dt * dt * dt / 6.0)
    vel += acc * dt + jerk * (0.5 * dt * dt)
    acc += jerk * dt


@njit(cache=True)
def to_position(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, target: np.ndarray,
                ff_vel: np.ndarray, ff_acc: np.ndarray, speed_max: float, acc_max: float,
                braking: float, jerk: float, dt: float) -> None:
    """One period of the approach of a position by one axis group (in place): cruise at
    ``speed_max``, brake at ``braking``, change acceleration at most at ``jerk``."""
    gain = min(K_POS, jerk / braking)
    wanted_vel, wanted_rate = _wanted_velocity(pos, vel, acc, target, ff_vel, speed_max,
                                               braking, jerk, gain)
    wanted_acc = _wanted_acceleration(vel, wanted_vel, wanted_rate + ff_acc, acc_max, jerk,
                                      K_VEL_PER_K_POS * gain)
    _advance(pos, vel, acc, _limit_norm(wanted_acc - acc, jerk * dt) / dt, dt)


@njit(cache=True)
def at_velocity(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, commanded: np.ndarray,
                velocity: np.ndarray, omega: float, acc_max: float, jerk: float,
                dt: float) -> None:
    """One period of a velocity setpoint for one axis group (in place): the commanded
    position (its integral) through a linear, critically damped third-order filter.

    Linear on purpose: every change of velocity then takes the same time, so the
    reference ends exactly where the commanded velocities add up to, and its impulse
    response is never negative, so the reference stays inside the commanded path (a
    2 m/s box flown as four legs ends where it began). The limits bound the filter only
    as a safety net for steps beyond what ``omega`` was chosen for.
    """
    commanded += velocity * dt
    jerk_wanted = (omega**3 * (commanded - pos) - 3.0 * omega**2 * vel - 3.0 * omega * acc)
    j = _limit_norm(jerk_wanted, jerk)
    # Keep the acceleration within its limit at the end of the period.
    next_acc = _limit_norm(acc + j * dt, acc_max)
    _advance(pos, vel, acc, (next_acc - acc) / dt, dt)


@njit(cache=True)
def _finite_or_zero(values: np.ndarray) -> np.ndarray:
    out = values.copy()
    for i in range(out.shape[0]):
        if not math.isfinite(out[i]):
            out[i] = 0.0
    return out


@njit(cache=True)
def velocity_filter_omega(speed_max: float, acc_max: float, jerk_max: float) -> float:
    """The velocity filter's bandwidth [rad/s]: the largest at which starting or stopping
    at ``speed_max`` stays within the acceleration and jerk limits (the step response of
    w^3 / (s + w)^3 peaks at 0.271 w dv in acceleration and 0.231 w^2 dv in jerk)."""
    return min(acc_max / (PEAK_ACC_PER_OMEGA * speed_max),
               math.sqrt(jerk_max / (PEAK_JERK_PER_OMEGA2 * speed_max)))




@njit(cache=True)
def shape_translation(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray,
                      commanded: np.ndarray, following: np.ndarray, sp_pos: np.ndarray,
                      sp_vel: np.ndarray, sp_acc: np.ndarray, lim: ShapingLimits,
                      dt: float) -> None:
    """One period of the horizontal (x-y, one vector) and vertical (z) reference, in
    place. ``following[g]``: group g is following a velocity setpoint (its commanded
    position is live); a position setpoint clears it."""
    ff_vel, ff_acc = _finite_or_zero(sp_vel), _finite_or_zero(sp_acc)
    h, v = slice(0, 2), slice(2, 3)
    if math.isfinite(sp_pos[0]) and math.isfinite(sp_pos[1]):
        following[0] = False
        to_position(pos[h], vel[h], acc[h], sp_pos[h], ff_vel[h], ff_acc[h],
                    lim.xy_vel_max_mps, lim.acc_hor_mps2, BRAKING_FRACTION * lim.acc_hor_mps2,
                    lim.jerk_mps3, dt)
    else:
        omega = velocity_filter_omega(lim.xy_vel_max_mps, lim.acc_hor_mps2, lim.jerk_mps3)
        if not following[0]:
            # Start in the filter's steady state for the present velocity (lag 3 v / w):
            # no jump, and no coming back to where the velocity setpoint began.
            commanded[h] = pos[h] + vel[h] * (3.0 / omega)
            following[0] = True
        at_velocity(pos[h], vel[h], acc[h], commanded[h],
                    _limit_norm(ff_vel[h], lim.xy_vel_max_mps), omega, lim.acc_hor_mps2,
                    lim.jerk_mps3, dt)
    slow_acc = min(lim.acc_up_mps2, lim.acc_down_mps2)
    if math.isfinite(sp_pos[2]):
        following[1] = False
        up = sp_pos[2] < pos[2]
        to_position(pos[v], vel[v], acc[v], sp_pos[v], ff_vel[v], ff_acc[v],
                    lim.z_vel_max_up_mps if up else lim.z_vel_max_dn_mps, slow_acc,
                    BRAKING_FRACTION * slow_acc, lim.jerk_mps3, dt)
    else:
        omega = velocity_filter_omega(max(lim.z_vel_max_up_mps, lim.z_vel_max_dn_mps),
                                      slow_acc, lim.jerk_mps3)
        if not following[1]:
            commanded[v] = pos[v] + vel[v] * (3.0 / omega)
            following[1] = True
        wanted = np.empty(1)
        wanted[0] = max(-lim.z_vel_max_up_mps, min(lim.z_vel_max_dn_mps, ff_vel[2]))
        at_velocity(pos[v], vel[v], acc[v], commanded[v], wanted, omega, slow_acc,
                    lim.jerk_mps3, dt)
