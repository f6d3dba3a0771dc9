"""Frames and attitude conventions: world NED, body FRD, ZYX Euler angles, radians.

Quaternions are scalar-first ``[w, x, y, z]`` and rotate body vectors into the world
(``v_ned = R(q) v_frd``), as PX4 and MAVLink's ATTITUDE_QUATERNION use them.
All functions are numba-compiled so the plant and the controller can call them in
their inner loops; they also work from plain Python.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

GRAVITY_MPS2 = 9.81
TWO_PI = 2.0 * math.pi


@njit(cache=True)
def wrap_pi(angle_rad: float) -> float:
    """The same angle in [-pi, pi): the one wrapping every angle difference goes through.

    Angles already in range come back unchanged, bit for bit, so wrapping an error that
    never leaves the range changes no result. Any finite input is taken: [0, 2 pi),
    (-pi, pi], several turns. NaN stays NaN.
    """
    if -math.pi <= angle_rad < math.pi:
        return angle_rad
    wrapped = angle_rad - TWO_PI * math.floor((angle_rad + math.pi) / TWO_PI)
    if wrapped >= math.pi:  # rounding at the upper edge
        wrapped -= TWO_PI
    elif wrapped < -math.pi:
        wrapped += TWO_PI
    return wrapped


@njit(cache=True)
def wrap_pi_array(angles_rad: np.ndarray) -> np.ndarray:
    """:func:`wrap_pi` of every element (metrics, logs)."""
    out = np.empty_like(angles_rad)
    flat_in, flat_out = angles_rad.ravel(), out.ravel()
    for i in range(flat_in.size):
        flat_out[i] = wrap_pi(flat_in[i])
    return out


@njit(cache=True)
def quat_from_euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """Unit quaternion of the ZYX (yaw, pitch, roll) rotation body FRD -> world NED."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    q = np.empty(4)
    q[0] = cr * cp * cy + sr * sp * sy
    q[1] = sr * cp * cy - cr * sp * sy
    q[2] = cr * sp * cy + sr * cp * sy
    q[3] = cr * cp * sy - sr * sp * cy
    return q


@njit(cache=True)
def euler_from_quat(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles [phi, theta, psi] of a unit quaternion (pitch clipped at +-pi/2)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out = np.empty(3)
    out[0] = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = 2.0 * (w * y - z * x)
    out[1] = math.asin(min(1.0, max(-1.0, s)))
    out[2] = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return out


@njit(cache=True)
def rotation_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R with v_ned = R v_frd."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return r


def world_to_body(w: float, x: float, y: float, z: float, vx: float, vy: float,
                  vz: float) -> tuple[float, float, float]:
    """R(q)^T v: a world (NED) vector in body axes (FRD).

    :func:`rotation_from_quat` transposed, written out in plain floats for per-message
    use outside compiled loops (a numba call costs more than the arithmetic here);
    tests/test_sim_link.py checks the two agree.
    """
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y + w * z) * vy
        + 2.0 * (x * z - w * y) * vz,
        2.0 * (x * y - w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy
        + 2.0 * (y * z + w * x) * vz,
        2.0 * (x * z + w * y) * vx + 2.0 * (y * z - w * x) * vy
        + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


def body_to_world(w: float, x: float, y: float, z: float, vx: float, vy: float,
                  vz: float) -> tuple[float, float, float]:
    """R(q) v: a body (FRD) vector in world axes (NED); :func:`world_to_body` inverted."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y - w * z) * vy
        + 2.0 * (x * z + w * y) * vz,
        2.0 * (x * y + w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy
        + 2.0 * (y * z - w * x) * vz,
        2.0 * (x * z - w * y) * vx + 2.0 * (y * z + w * x) * vy
        + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


@njit(cache=True)
def euler_rates_from_body_rates(
    phi: float, theta: float, p: float, q: float, r: float
) -> np.ndarray:
    """[phi', theta', psi'] from body rates [p, q, r] (exact ZYX kinematics).

    The paper's small-angle model takes these equal; the rigid-body plant does not.
    """
    cphi, sphi = math.cos(phi), math.sin(phi)
    ctheta = math.cos(theta)
    ctheta = math.copysign(max(abs(ctheta), 1e-6), ctheta)
    ttheta = math.sin(theta) / ctheta
    out = np.empty(3)
    out[0] = p + (q * sphi + r * cphi) * ttheta
    out[1] = q * cphi - r * sphi
    out[2] = (q * sphi + r * cphi) / ctheta
    return out


@njit(cache=True)
def body_rates_from_euler_rates(
    phi: float, theta: float, phi_dot: float, theta_dot: float, psi_dot: float
) -> np.ndarray:
    """Inverse of :func:`euler_rates_from_body_rates`."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    ctheta, stheta = math.cos(theta), math.sin(theta)
    out = np.empty(3)
    out[0] = phi_dot - stheta * psi_dot
    out[1] = cphi * theta_dot + sphi * ctheta * psi_dot
    out[2] = -sphi * theta_dot + cphi * ctheta * psi_dot
    return out


def heading_to_ned(forward: float, right: float, heading_rad: float) -> tuple[float, float]:
    """(north, east) of a horizontal vector given along the vehicle's heading (forward,
    right): the "body" frame of setpoints, turned by yaw only."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return c * forward - s * right, s * forward + c * right


def altitude_m(z_ned_m):  # float or array
    """Altitude shown to people: up is positive, NED z is down."""
    return -z_ned_m


# Home of the local NED frame, reported to ground tools as the vehicle's home (PX4's
# default SITL home, Zurich). Positions map to latitude/longitude with a local flat-earth
# (equirectangular) projection, exact enough for the few kilometres a SITL flies.
HOME_LAT_DEG = 47.397742
HOME_LON_DEG = 8.545594
HOME_ALT_AMSL_M = 488.0
EARTH_RADIUS_M = 6_378_137.0
# The Earth's field at home (the world magnetic model at Zurich, 2026): what the simulated
# magnetometer measures and what the autopilot's estimator takes as north, as PX4 looks up
# the declination for its position.
HOME_MAG_DECLINATION_RAD = math.radians(3.2)
HOME_MAG_INCLINATION_RAD = math.radians(63.6)
HOME_MAG_STRENGTH_GAUSS = 0.479


def home_mag_field_ned_gauss() -> tuple[float, float, float]:
    """The field at home in NED [gauss] from its declination and inclination."""
    horizontal = HOME_MAG_STRENGTH_GAUSS * math.cos(HOME_MAG_INCLINATION_RAD)
    return (horizontal * math.cos(HOME_MAG_DECLINATION_RAD),
            horizontal * math.sin(HOME_MAG_DECLINATION_RAD),
            HOME_MAG_STRENGTH_GAUSS * math.sin(HOME_MAG_INCLINATION_RAD))


SEA_LEVEL_PRESSURE_HPA = 1013.25


def pressure_hpa(alt_amsl_m: float) -> float:
    """International standard atmosphere below 11 km: what a barometer reads."""
    return SEA_LEVEL_PRESSURE_HPA * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


def altitude_from_pressure_m(pressure_hpa_: float) -> float:
    """Altitude AMSL [m] of a pressure in the standard atmosphere (pressure_hpa inverted)."""
    return (1.0 - (pressure_hpa_ / SEA_LEVEL_PRESSURE_HPA) ** (1.0 / 5.25588)) / 2.25577e-5


def geodetic_from_ned(north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """(latitude deg, longitude deg, altitude AMSL m) of a local NED position."""
    lat = HOME_LAT_DEG + math.degrees(north_m / EARTH_RADIUS_M)
    lon = HOME_LON_DEG + math.degrees(
        east_m / (EARTH_RADIUS_M * math.cos(math.radians(HOME_LAT_DEG))))
    return lat, lon, HOME_ALT_AMSL_M - down_m


def ned_from_geodetic(lat_deg: float, lon_deg: float, alt_amsl_m: float) -> tuple[float, float,
                                                                                   float]:
    """Inverse of :func:`geodetic_from_ned`."""
    north = math.radians(lat_deg - HOME_LAT_DEG) * EARTH_RADIUS_M
    east = math.radians(lon_deg - HOME_LON_DEG) * EARTH_RADIUS_M * math.cos(
        math.radians(HOME_LAT_DEG))
    return north, east, HOME_ALT_AMSL_M - alt_amsl_m
