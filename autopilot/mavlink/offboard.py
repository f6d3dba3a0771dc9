"""Offboard setpoints from MAVLink: type_mask and coordinate frame -> a local NED Setpoint.

What PX4 accepts in SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT,
read the way MAVLink defines the frames (docs/mavlink.md has the table):

| frame | position | velocity, acceleration |
|---|---|---|
| LOCAL_NED (1) | NED from home | NED |
| LOCAL_OFFSET_NED (7) | NED offset from the vehicle | NED |
| BODY_NED (8) | NED from home | heading frame |
| BODY_OFFSET_NED (9), BODY_FRD (12) | heading-frame offset from the vehicle | heading frame |
| LOCAL_FRD (20) | heading frame from home | heading frame |
| GLOBAL(_INT) (0, 5) | lat, lon, altitude AMSL | NED |
| GLOBAL_RELATIVE_ALT(_INT) (3, 6) | lat, lon, altitude above home | NED |

The heading frame is forward-right-down turned by the vehicle's yaw only, as PX4 and
ArduPilot read "body" setpoints: forward stays horizontal however the vehicle is tilted.
Yaw is always a heading in NED. Fields the type_mask leaves out become NaN; fields it
uses must be finite. Pure: the vehicle's position and heading come in as arguments.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.navigator.home import Places
from autopilot.refusal import RefusedError
from contracts.frames import heading_to_ned
from contracts.mavlink import GLOBAL_FRAMES, mavlink

# POSITION_TARGET_TYPEMASK bits.
X_IGNORE, Y_IGNORE, Z_IGNORE = 1 << 0, 1 << 1, 1 << 2
VX_IGNORE, VY_IGNORE, VZ_IGNORE = 1 << 3, 1 << 4, 1 << 5
AX_IGNORE, AY_IGNORE, AZ_IGNORE = 1 << 6, 1 << 7, 1 << 8
FORCE_SET = 1 << 9
YAW_IGNORE = 1 << 10
YAW_RATE_IGNORE = 1 << 11
POSITION_BITS = (X_IGNORE, Y_IGNORE, Z_IGNORE)
VELOCITY_BITS = (VX_IGNORE, VY_IGNORE, VZ_IGNORE)
ACCEL_BITS = (AX_IGNORE, AY_IGNORE, AZ_IGNORE)

# How each local frame places positions and turns vectors:
# (position is an offset from the vehicle, position in the heading frame, vectors in it).
LOCAL_FRAMES: dict[int, tuple[bool, bool, bool]] = {
    mavlink.MAV_FRAME_LOCAL_NED: (False, False, False),
    mavlink.MAV_FRAME_LOCAL_OFFSET_NED: (True, False, False),
    mavlink.MAV_FRAME_BODY_NED: (False, False, True),
    mavlink.MAV_FRAME_BODY_OFFSET_NED: (True, True, True),
    mavlink.MAV_FRAME_BODY_FRD: (True, True, True),
    mavlink.MAV_FRAME_LOCAL_FRD: (False, True, True),
}


def _masked(type_mask: int, bits: tuple[int, int, int], values, what: str) -> np.ndarray:
    """The three values with NaN where the mask leaves them out; used ones must be finite."""
    out = np.full(3, np.nan)
    for i, (bit, value) in enumerate(zip(bits, values, strict=True)):
        if not type_mask & bit:
            if not math.isfinite(value):
                raise RefusedError(f"setpoint {what} holds NaN or infinity")
            out[i] = float(value)
    return out


def _yaw(type_mask: int, yaw: float, yaw_rate: float) -> tuple[float, float]:
    """(yaw, yaw rate) with NaN for what is not used; a yaw wins over a rate."""
    if not type_mask & YAW_IGNORE:
        if not math.isfinite(yaw):
            raise RefusedError("setpoint yaw holds NaN or infinity")
        return float(yaw), math.nan
    if not type_mask & YAW_RATE_IGNORE:
        if not math.isfinite(yaw_rate):
            raise RefusedError("setpoint yaw rate holds NaN or infinity")
        return math.nan, float(yaw_rate)
    return math.nan, math.nan


def _refuse_force(type_mask: int) -> None:
    """Force setpoints are refused, but the force bit means nothing while every
    acceleration is masked: DroneKit's examples send 0x0FF8 (position only, force bit on)."""
    if type_mask & FORCE_SET and not all(type_mask & bit for bit in ACCEL_BITS):
        raise RefusedError("force setpoints are not supported")


def _turn(vector: np.ndarray, heading_rad: float) -> np.ndarray:
    """Heading frame -> NED for the horizontal part (NaN stays NaN)."""
    out = vector.copy()
    out[0], out[1] = heading_to_ned(vector[0], vector[1], heading_rad)
    return out


def local_setpoint(frame: int, type_mask: int, position, velocity, accel, yaw: float,
                   yaw_rate: float, here_ned_m: np.ndarray, heading_rad: float) -> Setpoint:
    """SET_POSITION_TARGET_LOCAL_NED -> Setpoint in local NED."""
    if frame not in LOCAL_FRAMES:
        raise RefusedError(f"setpoint frame {frame} is not supported")
    _refuse_force(type_mask)
    offset, position_turned, vectors_turned = LOCAL_FRAMES[frame]
    pos = _masked(type_mask, POSITION_BITS, position, "position")
    vel = _masked(type_mask, VELOCITY_BITS, velocity, "velocity")
    acc = _masked(type_mask, ACCEL_BITS, accel, "acceleration")
    if position_turned:
        pos = _turn(pos, heading_rad)
    if offset:
        pos = pos + np.asarray(here_ned_m, dtype=float)
    if vectors_turned:
        vel, acc = _turn(vel, heading_rad), _turn(acc, heading_rad)
    return Setpoint(pos, vel, acc, *_yaw(type_mask, yaw, yaw_rate))


def global_setpoint(places: Places, frame: int, type_mask: int, lat_int: int, lon_int: int,
                    alt_m: float, velocity, accel, yaw: float, yaw_rate: float) -> Setpoint:
    """SET_POSITION_TARGET_GLOBAL_INT -> Setpoint in local NED (around the origin, a
    relative altitude above home)."""
    if frame not in GLOBAL_FRAMES:
        raise RefusedError(f"setpoint frame {frame} is not supported (no terrain data)")
    _refuse_force(type_mask)
    given = _masked(type_mask, POSITION_BITS, (lat_int * 1e-7, lon_int * 1e-7, alt_m),
                    "position")
    lat, lon, alt = given
    if abs(lat) > 90.0 or abs(lon) > 180.0:  # False for NaN: left out
        raise RefusedError(f"setpoint latitude/longitude {lat:g}, {lon:g} is not on Earth")
    pos = places.ned_from_global(frame, lat, lon, alt)
    vel = _masked(type_mask, VELOCITY_BITS, velocity, "velocity")
    acc = _masked(type_mask, ACCEL_BITS, accel, "acceleration")
    return Setpoint(pos, vel, acc, *_yaw(type_mask, yaw, yaw_rate))
