"""Manual flight: MANUAL_CONTROL's sticks as PX4 reads them, turned into what the vehicle
flies in POSCTL, ALTCTL and STABILIZED (pure: no I/O).

Sticks (MANUAL_CONTROL, PX4's meaning): x forward (pitch stick), y right (roll stick),
r yaw right, each -1000..1000; z throttle 0..1000, centred at 500. Each stick passes a
deadband (MPC_HOLD_DZ, the rest rescaled to the full range) and, for velocities, an expo
curve (MPC_XY_MAN_EXPO, MPC_Z_MAN_EXPO): small deflections are gentle, a full stick is
still the full limit.

* POSCTL: sticks command a horizontal velocity (MPC_VEL_MANUAL at full stick, in the
  vehicle's heading frame), a climb rate (MPC_Z_VEL_MAX_UP / _DN) and a yaw rate
  (MPC_MAN_Y_MAX); a centred stick holds that axis where the vehicle can stop.
* ALTCTL: the roll and pitch sticks command a tilt (MPC_MAN_TILT_MAX at full stick), the
  throttle a climb rate (centred: hold the altitude), the yaw stick a yaw rate.
* STABILIZED: tilt and yaw as ALTCTL, the throttle the collective thrust, hover at centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.flight_tasks.setpoints import AttitudeTarget
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.refusal import RefusedError

STICK_FULL = 1000.0


@dataclass(frozen=True)
class Sticks:
    """Stick positions: forward, right and yaw in [-1, 1], throttle in [0, 1]."""

    forward: float = 0.0
    right: float = 0.0
    throttle: float = 0.5
    yaw: float = 0.0


def sticks_from_manual_control(x: float, y: float, z: float, r: float) -> Sticks:
    """MANUAL_CONTROL's axes, checked: x, y, r in [-1000, 1000], z in [0, 1000]."""
    for name, value, low in (("x", x, -STICK_FULL), ("y", y, -STICK_FULL),
                             ("z", z, 0.0), ("r", r, -STICK_FULL)):
        if not (math.isfinite(value) and low <= value <= STICK_FULL):
            raise RefusedError(f"manual control {name} {value:g} is outside "
                               f"[{low:g}, {STICK_FULL:g}]")
    return Sticks(x / STICK_FULL, y / STICK_FULL, z / STICK_FULL, r / STICK_FULL)


def deadband(value: float, width: float) -> float:
    """Zero within ``width`` of centre, the rest rescaled to reach +-1 at full stick."""
    if abs(value) <= width:
        return 0.0
    return math.copysign((abs(value) - width) / (1.0 - width), value)


def expo(value: float, amount: float) -> float:
    """PX4's stick expo: (1 - e) v + e v^3, linear at e = 0, full stick still 1."""
    return (1.0 - amount) * value + amount * value**3


def climb_stick(throttle: float, p: dict[str, float]) -> float:
    """The throttle stick as a climb rate [m/s, up positive]; centred (within the deadband)
    holds the altitude."""
    s = expo(deadband(2.0 * throttle - 1.0, p["MPC_HOLD_DZ"]), p["MPC_Z_MAN_EXPO"])
    return s * (p["MPC_Z_VEL_MAX_UP"] if s > 0 else p["MPC_Z_VEL_MAX_DN"])


def horizontal_velocity(sticks: Sticks, heading_rad: float, p: dict[str, float]
                        ) -> tuple[float, float] | None:
    """POSCTL: the roll / pitch sticks as a velocity north, east [m/s], None if centred
    (hold). The sticks are taken as one vector, so a diagonal full stick is still
    MPC_VEL_MANUAL."""
    forward, right = sticks.forward, sticks.right
    size = math.hypot(forward, right)
    scaled = expo(deadband(min(size, 1.0), p["MPC_HOLD_DZ"]), p["MPC_XY_MAN_EXPO"])
    if scaled == 0.0:
        return None
    speed = scaled * p["MPC_VEL_MANUAL"] / size
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return (speed * (forward * c - right * s), speed * (forward * s + right * c))


def yaw_rate(sticks: Sticks, p: dict[str, float]) -> float:
    """The yaw stick as a yaw rate [rad/s], 0 when centred."""
    return deadband(sticks.yaw, p["MPC_HOLD_DZ"]) * math.radians(p["MPC_MAN_Y_MAX"])


def tilt(sticks: Sticks, p: dict[str, float]) -> tuple[float, float]:
    """ALTCTL / STABILIZED: roll and pitch [rad] from the sticks (forward pitches the nose
    down), the pair limited to MPC_MAN_TILT_MAX."""
    limit = math.radians(p["MPC_MAN_TILT_MAX"])
    forward = deadband(sticks.forward, p["MPC_HOLD_DZ"])
    right = deadband(sticks.right, p["MPC_HOLD_DZ"])
    size = max(1.0, math.hypot(forward, right))
    return right / size * limit, -forward / size * limit


def thrust_fraction(throttle: float, hover_fraction: float) -> float:
    """STABILIZED: the throttle stick as collective thrust / maximum, hover at centre
    (PX4's MPC_THR_HOVER at mid stick), linear on either side."""
    if throttle <= 0.5:
        return hover_fraction * throttle / 0.5
    return hover_fraction + (1.0 - hover_fraction) * (throttle - 0.5) / 0.5


def position_control(setpoint: Setpoint, sticks: Sticks, heading_rad: float,
                     stopping_point: np.ndarray, held: list[bool], p: dict[str, float]
                     ) -> list[bool]:
    """POSCTL: update ``setpoint`` (in place) from the sticks, axis group by axis group: a
    deflected stick commands a velocity (or yaw rate); a stick coming back to centre
    holds where the reference can stop, and keeps holding there. ``held`` says which
    groups (horizontal, vertical, yaw) were held last period; returns it for this one."""
    velocity = horizontal_velocity(sticks, heading_rad, p)
    climb = climb_stick(sticks.throttle, p)
    rate = yaw_rate(sticks, p)
    if velocity is None:
        if not held[0]:
            setpoint.position_ned_m[0:2] = stopping_point[0:2]
            setpoint.velocity_ned_mps[0:2] = np.nan
    else:
        setpoint.position_ned_m[0:2] = np.nan
        setpoint.velocity_ned_mps[0:2] = velocity
    if climb == 0.0:
        if not held[1]:
            setpoint.position_ned_m[2], setpoint.velocity_ned_mps[2] = stopping_point[2], np.nan
    else:
        setpoint.position_ned_m[2], setpoint.velocity_ned_mps[2] = np.nan, -climb
    if rate == 0.0:
        if not held[2]:
            setpoint.yaw_rad, setpoint.yaw_rate_rad_s = heading_rad, math.nan
    else:
        setpoint.yaw_rad, setpoint.yaw_rate_rad_s = math.nan, rate
    return [velocity is None, climb == 0.0, rate == 0.0]


def attitude_control(sticks: Sticks, p: dict[str, float], hover_fraction: float | None
                     ) -> AttitudeTarget:
    """ALTCTL (``hover_fraction`` None: the throttle is a climb rate) and STABILIZED (the
    throttle is the collective thrust, hover at mid stick): the attitude target. The yaw
    stick is a yaw rate (the heading stays where it is when the stick is centred)."""
    roll, pitch = tilt(sticks, p)
    target = AttitudeTarget(np.array([roll, pitch, math.nan]),
                            yaw_rate_rad_s=yaw_rate(sticks, p))
    if hover_fraction is None:
        target.climb_rate_mps = climb_stick(sticks.throttle, p)
    else:
        target.thrust_fraction = thrust_fraction(sticks.throttle, hover_fraction)
    return target
