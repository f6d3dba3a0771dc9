"""Setpoints as tools stream them, checked: a local NED position / velocity setpoint and an
attitude target (what SET_POSITION_TARGET_* and SET_ATTITUDE_TARGET carry, decoded by
autopilot/mavlink/). Every value is range-checked before anything changes (pure)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.refusal import RefusedError, check_finite, check_given
from contracts.frames import euler_from_quat, wrap_pi

MAX_SETPOINT_DISTANCE_M = 1000.0
MAX_SETPOINT_SPEED_MPS = 20.0
MAX_SETPOINT_ACCEL_MPS2 = 20.0
MAX_SETPOINT_YAW_RATE_RAD_S = 20.0
MAX_TILT_SETPOINT_RAD = 1.0


@dataclass
class AttitudeTarget:
    """An attitude setpoint: Euler angles, and the vertical part as the flavour reads
    SET_ATTITUDE_TARGET's thrust."""

    euler_rad: np.ndarray
    thrust_fraction: float = math.nan  # PX4: collective thrust / the airframe's maximum
    climb_rate_mps: float = 0.0  # ArduPilot (or no thrust): altitude loop at this rate
    altitude_ref_ned_m: float = math.nan  # the altitude loop's reference, integrated
    yaw_rate_rad_s: float = math.nan  # with a NaN yaw: turn at this rate (manual sticks)


def checked_position_setpoint(setpoint: Setpoint) -> Setpoint:
    """A copy of a local NED setpoint (NaN for what the tool left out) after the checks:
    per axis group a position or a velocity; everything given within range."""
    sp = Setpoint(np.array(setpoint.position_ned_m, dtype=float),
                  np.array(setpoint.velocity_ned_mps, dtype=float),
                  np.array(setpoint.accel_ned_mps2, dtype=float),
                  float(setpoint.yaw_rad), float(setpoint.yaw_rate_rad_s))
    pos, vel = sp.position_ned_m, sp.velocity_ned_mps
    if np.isnan(pos[0]) != np.isnan(pos[1]):
        raise RefusedError("setpoint gives x without y or y without x")
    for group in (slice(0, 2), slice(2, 3)):
        if np.all(np.isnan(pos[group])) and np.any(np.isnan(vel[group])):
            raise RefusedError("setpoint gives neither position nor velocity")
    check_given("setpoint position", pos, MAX_SETPOINT_DISTANCE_M)
    check_given("setpoint velocity", vel, MAX_SETPOINT_SPEED_MPS)
    check_given("setpoint acceleration", sp.accel_ned_mps2, MAX_SETPOINT_ACCEL_MPS2)
    check_given("setpoint yaw", (sp.yaw_rad,), math.inf)
    check_given("setpoint yaw rate", (sp.yaw_rate_rad_s,), MAX_SETPOINT_YAW_RATE_RAD_S)
    sp.yaw_rad = wrap_pi(sp.yaw_rad)
    return sp


def checked_attitude_target(quaternion: tuple | None, thrust: float | None, flavour: str,
                            climb_speed_mps: float) -> AttitudeTarget:
    """An attitude setpoint after the checks. Thrust as the flavour reads it: PX4, the
    collective thrust as a fraction of the maximum; ArduPilot, 0.5 holds the altitude and
    0 / 1 descend / climb at ``climb_speed_mps``. Without thrust the altitude is held."""
    if quaternion is None:
        raise RefusedError("attitude setpoint without attitude: body-rate control is not "
                           "supported")
    check_finite("attitude quaternion", quaternion, 1.01)
    q = np.array(quaternion, dtype=float)
    norm = float(np.linalg.norm(q))
    if not 0.9 < norm < 1.1:
        raise RefusedError(f"attitude quaternion norm {norm:.3f} is not 1")
    euler = euler_from_quat(q / norm)
    if max(abs(euler[0]), abs(euler[1])) > MAX_TILT_SETPOINT_RAD:
        raise RefusedError(f"attitude setpoint tilts more than {MAX_TILT_SETPOINT_RAD} rad")
    target = AttitudeTarget(euler)
    if thrust is not None:
        check_finite("thrust", (thrust,), 1.0)
        if thrust < 0.0:
            raise RefusedError(f"thrust {thrust:g} is outside [0, 1]")
        if flavour == "px4":
            target.thrust_fraction = float(thrust)
        else:
            target.climb_rate_mps = (thrust - 0.5) * 2.0 * climb_speed_mps
    return target
