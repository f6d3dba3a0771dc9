"""The setpoint shaper's state: the kinematic reference a flight task moves each control
period towards its setpoint (the shaping laws are in autopilot/flight_tasks/shaping.py).

Pure: no clocks, no I/O; a flight task calls :meth:`SetpointShaper.step` once per control
period with the period length.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.control.command_filter import command_filter_step
from autopilot.flight_tasks.shaping import (
    BRAKING_FRACTION,
    K_YAW,
    K_YAW_RATE,
    Setpoint,
    ShapingLimits,
    shape_translation,
    sqrt_controller,
    stopping_distance,
)
from contracts.frames import wrap_pi
from contracts.vectors import (
    REF_ACC,
    REF_EULER,
    REF_EULER_ACC,
    REF_EULER_RATE,
    REF_POS,
    REF_SIZE,
    REF_VEL,
)


class SetpointShaper:
    """The reference state and its update. ``reset`` starts it from the vehicle's state."""

    def __init__(self) -> None:
        self.position_ned_m = np.zeros(3)
        self.velocity_ned_mps = np.zeros(3)
        self.accel_ned_mps2 = np.zeros(3)
        self._commanded = np.zeros(3)  # a velocity setpoint's integral, per group
        self._following = np.zeros(2, dtype=np.bool_)  # horizontal, vertical
        self.yaw_rad = 0.0
        self.yaw_rate_rad_s = 0.0
        self.yaw_acc_rad_s2 = 0.0
        self._tilt = np.zeros((2, 2))  # attitude setpoints: roll, pitch filter (angle, rate)

    def reset(self, position_ned_m, velocity_ned_mps, yaw_rad: float) -> None:
        """Start from where the vehicle is and how it moves (bumpless hand-over)."""
        self.position_ned_m[:] = position_ned_m
        self.velocity_ned_mps[:] = velocity_ned_mps
        self.accel_ned_mps2[:] = 0.0
        self._following[:] = False
        self.yaw_rad = wrap_pi(float(yaw_rad))
        self.yaw_rate_rad_s = 0.0
        self.yaw_acc_rad_s2 = 0.0

    def stopping_point(self, limits: ShapingLimits) -> np.ndarray:
        """Where the reference comes to rest if it brakes now (a hold begins there)."""
        out = self.position_ned_m.copy()
        v = self.velocity_ned_mps
        speed = math.hypot(v[0], v[1])
        if speed > 0.0:
            out[0:2] += v[0:2] * (stopping_distance(
                speed, BRAKING_FRACTION * limits.acc_hor_mps2, limits.jerk_mps3) / speed)
        braking_z = BRAKING_FRACTION * min(limits.acc_up_mps2, limits.acc_down_mps2)
        out[2] += math.copysign(stopping_distance(abs(v[2]), braking_z, limits.jerk_mps3), v[2])
        return out

    def step(self, setpoint: Setpoint, limits: ShapingLimits, dt: float) -> np.ndarray:
        """Advance one period towards ``setpoint``; returns the reference vector."""
        shape_translation(self.position_ned_m, self.velocity_ned_mps, self.accel_ned_mps2,
                          self._commanded, self._following, setpoint.position_ned_m,
                          setpoint.velocity_ned_mps, setpoint.accel_ned_mps2, limits, dt)
        self._step_yaw(setpoint, limits, dt)
        ref = np.zeros(REF_SIZE)
        ref[REF_POS:REF_POS + 3] = self.position_ned_m
        ref[REF_VEL:REF_VEL + 3] = self.velocity_ned_mps
        ref[REF_ACC:REF_ACC + 3] = self.accel_ned_mps2
        ref[REF_EULER + 2] = self.yaw_rad
        ref[REF_EULER_RATE + 2] = self.yaw_rate_rad_s
        ref[REF_EULER_ACC + 2] = self.yaw_acc_rad_s2
        return ref

    def reset_attitude(self, euler_rad, euler_rate_rad_s) -> None:
        """Start attitude shaping from the vehicle's attitude and its rates."""
        self._tilt[:, 0] = euler_rad[0:2]
        self._tilt[:, 1] = euler_rate_rad_s[0:2]
        self.yaw_rad = wrap_pi(float(euler_rad[2]))
        self.yaw_rate_rad_s = float(euler_rate_rad_s[2])
        self.yaw_acc_rad_s2 = 0.0

    def step_attitude(self, euler_rad: np.ndarray, limits: ShapingLimits,
                      tilt_filter: np.ndarray, dt: float,
                      yaw_rate_rad_s: float = math.nan) -> np.ndarray:
        """Attitude setpoints: roll and pitch through the controller's command filter
        (``tilt_filter`` = omega, zeta, rate and acceleration limits), yaw the short way
        within MPC_YAWRAUTO_* (or, for a NaN yaw, at ``yaw_rate_rad_s``). Returns a
        reference vector holding the Euler part."""
        ref = np.zeros(REF_SIZE)
        omega, zeta, rate_max, acc_max = tilt_filter
        for k in range(2):
            ref[REF_EULER + k], ref[REF_EULER_RATE + k], ref[REF_EULER_ACC + k] = \
                command_filter_step(self._tilt[k], float(euler_rad[k]), dt, omega, zeta,
                                    rate_max, acc_max)
        self._step_yaw(Setpoint(yaw_rad=float(euler_rad[2]), yaw_rate_rad_s=yaw_rate_rad_s),
                       limits, dt)
        ref[REF_EULER + 2] = self.yaw_rad
        ref[REF_EULER_RATE + 2] = self.yaw_rate_rad_s
        ref[REF_EULER_ACC + 2] = self.yaw_acc_rad_s2
        return ref

    def _step_yaw(self, sp: Setpoint, lim: ShapingLimits, dt: float) -> None:
        rate_max, acc_max = lim.yaw_rate_max_rad_s, lim.yaw_acc_max_rad_s2
        if math.isfinite(sp.yaw_rad):
            # The short way round: the error is wrapped, so +170 -> -170 deg is +20 deg.
            error = wrap_pi(sp.yaw_rad - self.yaw_rad)
            wanted_rate = max(-rate_max, min(rate_max, sqrt_controller(
                error, K_YAW, BRAKING_FRACTION * acc_max)))
        elif math.isfinite(sp.yaw_rate_rad_s):
            wanted_rate = max(-rate_max, min(rate_max, sp.yaw_rate_rad_s))
        else:
            wanted_rate = 0.0
        acc = max(-acc_max, min(acc_max, K_YAW_RATE * (wanted_rate - self.yaw_rate_rad_s)))
        self.yaw_rad = wrap_pi(self.yaw_rad + self.yaw_rate_rad_s * dt + 0.5 * acc * dt * dt)
        self.yaw_rate_rad_s += acc * dt
        self.yaw_acc_rad_s2 = acc



def warm_up(limits: ShapingLimits, dt: float) -> None:
    """Run every compiled path once. The first call of each loads it from numba's cache
    (or compiles it, seconds on a fresh install): a process calls this before its loop,
    so that the first shaped control step is not the one that pays."""
    shaper = SetpointShaper()
    shaper.reset(np.zeros(3), np.zeros(3), 0.0)
    shaper.step(Setpoint(np.array([1.0, 1.0, -1.0]), np.zeros(3), np.zeros(3), 0.5), limits, dt)
    shaper.step(Setpoint(velocity_ned_mps=np.ones(3), yaw_rate_rad_s=0.1), limits, dt)
    shaper.stopping_point(limits)
    shaper.reset_attitude(np.zeros(3), np.zeros(3))
    shaper.step_attitude(np.array([0.1, -0.1, 3.0]), limits, (10.0, 1.0, 2.0, 8.0), dt)
