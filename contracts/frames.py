"""Frames and attitude conventions: world NED, body FRD, ZYX Euler angles, radians.

Quaternions are scalar-first ``[w, x, y, z]`` and rotate body vectors into the world
(``v_ned = R(q) v_frd``), as PX4 and MAVLink's ATTITUDE_QUATERNION use them.
The functions the plant and the controller call in their inner loops are numba-compiled;
they also work from plain Python. The array wrap the ground's reports use is numpy.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

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


def wrap_pi_array(angles_rad: np.ndarray) -> np.ndarray:
    """:func:`wrap_pi` of every element (metrics, logs), the same operations in numpy: the
    same bits for every finite angle (tests/autopilot/test_shaping.py), and no compiled
    code, whose first call in a process loads numba's registries (0.3-0.5 s of a
    report). An infinity gives NaN."""
    angles = np.asarray(angles_rad, dtype=np.float64)
    out = angles.copy()
    outside = ~((angles >= -math.pi) & (angles < math.pi))  # NaN too: it stays NaN
    if outside.any():
        a = angles[outside]
        with np.errstate(invalid="ignore"):  # an infinity: NaN, as no wrap is right
            wrapped = a - TWO_PI * np.floor((a + math.pi) / TWO_PI)
        wrapped[wrapped >= math.pi] -= TWO_PI  # rounding at the upper edge
        wrapped[wrapped < -math.pi] += TWO_PI
        out[outside] = wrapped
    return out


@njit(cache=True)
def vector_norm(v: np.ndarray) -> float:
    """The Euclidean norm, summed in order: the one the simulator link's compiled code
    and its Python decoders share (numpy's and numba's ``dot`` call a BLAS, whose thread
    pool has no place in a real-time loop)."""
    total = 0.0
    for i in range(v.size):
        total += v[i] * v[i]
    return math.sqrt(total)


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
    tests/sitl/test_sim_link.py checks the two agree.
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


EARTH_RADIUS_M = 6_378_137.0
# The world magnetic model is evaluated at this date (decimal year), not today's: a run's
# field must not depend on the day it is flown.
MAG_MODEL_YEAR = 2026.5
MAG_MODEL_FILE = "wmm/WMM_2025.COF"  # pygeomag's World Magnetic Model 2025 (2025-2030)
HOME_MAX_ABS_LAT_DEG = 89.0  # north and east lose their meaning at the poles
HOME_ALT_RANGE_M = (-500.0, 9000.0)  # the standard atmosphere of ``pressure_hpa`` holds


def geodetic_from_ned(lat0_deg: float, lon0_deg: float, alt0_amsl_m: float,
                      north_m: float, east_m: float, down_m: float
                      ) -> tuple[float, float, float]:
    """(latitude deg, longitude deg in [-180, 180), altitude AMSL m) of a local NED
    position around the origin (lat0, lon0, alt0): ``Home.geodetic_from_ned``, and in
    compiled code ``geodetic_from_ned_compiled`` (the same source, the same bits)."""
    lat0 = math.radians(lat0_deg)
    x, y = north_m / EARTH_RADIUS_M, east_m / EARTH_RADIUS_M
    c = math.sqrt(x * x + y * y)
    if c == 0.0:
        return lat0_deg, lon0_deg, alt0_amsl_m - down_m
    sin_c, cos_c = math.sin(c), math.cos(c)
    lat = math.asin(cos_c * math.sin(lat0) + x * sin_c * math.cos(lat0) / c)
    dlon = math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
    lon = (lon0_deg + math.degrees(dlon) + 180.0) % 360.0 - 180.0
    return math.degrees(lat), lon, alt0_amsl_m - down_m


geodetic_from_ned_compiled = njit(cache=True)(geodetic_from_ned)


def ned_from_geodetic(lat0_deg: float, lon0_deg: float, alt0_amsl_m: float, lat_deg: float,
                      lon_deg: float, alt_amsl_m: float) -> tuple[float, float, float]:
    """Inverse of :func:`geodetic_from_ned` (``Home.ned_from_geodetic``; compiled:
    ``ned_from_geodetic_compiled``)."""
    lat0, lat = math.radians(lat0_deg), math.radians(lat_deg)
    dlon = math.radians(lon_deg - lon0_deg)
    cos_arc = (math.sin(lat0) * math.sin(lat)
               + math.cos(lat0) * math.cos(lat) * math.cos(dlon))
    c = math.acos(min(1.0, max(-1.0, cos_arc)))
    k = 1.0 if c < 1e-12 else c / math.sin(c)
    north = k * (math.cos(lat0) * math.sin(lat)
                 - math.sin(lat0) * math.cos(lat) * math.cos(dlon)) * EARTH_RADIUS_M
    east = k * math.cos(lat) * math.sin(dlon) * EARTH_RADIUS_M
    return north, east, alt0_amsl_m - alt_amsl_m


ned_from_geodetic_compiled = njit(cache=True)(ned_from_geodetic)


class Home(NamedTuple):
    """The origin of the local NED frame on Earth, reported to ground tools as the
    vehicle's home.

    Positions map to latitude and longitude by the azimuthal equidistant projection on a
    sphere, as PX4's map projection does: distances and bearings from home are exact at
    any latitude, and longitudes wrap across the antimeridian.
    """

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    @classmethod
    def checked(cls, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Home:
        """A home, or ValueError naming what is out of range (NaN included)."""
        if not abs(lat_deg) <= HOME_MAX_ABS_LAT_DEG:
            raise ValueError(f"home latitude {lat_deg!r} deg is outside "
                             f"[-{HOME_MAX_ABS_LAT_DEG:g}, {HOME_MAX_ABS_LAT_DEG:g}]")
        if not abs(lon_deg) <= 180.0:
            raise ValueError(f"home longitude {lon_deg!r} deg is outside [-180, 180]")
        low, high = HOME_ALT_RANGE_M
        if not low <= alt_amsl_m <= high:
            raise ValueError(f"home altitude {alt_amsl_m!r} m AMSL is outside "
                             f"[{low:g}, {high:g}]")
        return cls(float(lat_deg), float(lon_deg), float(alt_amsl_m))

    @classmethod
    def parse(cls, text: str) -> Home:
        """``LAT,LON,ALT`` (degrees, degrees, metres AMSL), as ``--home`` takes it."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 3:
            raise ValueError(f"home {text!r} is not LAT,LON,ALT (three numbers)")
        return cls.checked(*values)

    def geodetic_from_ned(self, north_m: float, east_m: float, down_m: float
                          ) -> tuple[float, float, float]:
        """(latitude deg, longitude deg in [-180, 180), altitude AMSL m) of a local NED
        position."""
        return geodetic_from_ned(self.lat_deg, self.lon_deg, self.alt_amsl_m, north_m,
                                 east_m, down_m)

    def ned_from_geodetic(self, lat_deg: float, lon_deg: float, alt_amsl_m: float
                          ) -> tuple[float, float, float]:
        """Inverse of :meth:`geodetic_from_ned`."""
        return ned_from_geodetic(self.lat_deg, self.lon_deg, self.alt_amsl_m, lat_deg,
                                 lon_deg, alt_amsl_m)

    def mag_field_ned_gauss(self) -> tuple[float, float, float]:
        """The Earth's field at home in NED [gauss] from the world magnetic model: what
        the simulated magnetometer measures and what the estimator takes as north (PX4
        looks its declination up in a table of the same model)."""
        return _mag_field_ned_gauss(self.lat_deg, self.lon_deg, self.alt_amsl_m)

    def mag_declination_rad(self) -> float:
        north, east, _ = self.mag_field_ned_gauss()
        return math.atan2(east, north)


def named_home(text: str) -> Home:
    """``--home``'s value: a name of NAMED_HOMES (any case) or ``LAT,LON,ALT``; a word
    that is neither is refused with the names."""
    if "," not in text:
        for name, home in NAMED_HOMES.items():
            if name.lower() == text.strip().lower():
                return home
        raise ValueError(f"home {text!r} is neither LAT,LON,ALT nor a named home "
                         f"({', '.join(NAMED_HOMES)})")
    return Home.parse(text)


def home_argument(text: str) -> Home:
    """argparse type of ``--home NAME`` or ``--home LAT,LON,ALT``: a clear message for a
    bad one."""
    import argparse

    try:
        return named_home(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


@functools.lru_cache(maxsize=64)
def _mag_field_ned_gauss(lat_deg: float, lon_deg: float, alt_amsl_m: float
                         ) -> tuple[float, float, float]:
    from pygeomag import GeoMag

    field = GeoMag(coefficients_file=MAG_MODEL_FILE).calculate(
        glat=lat_deg, glon=lon_deg, alt=alt_amsl_m / 1000.0, time=MAG_MODEL_YEAR)
    nt_to_gauss = 1e-5
    return field.x * nt_to_gauss, field.y * nt_to_gauss, field.z * nt_to_gauss


# PX4's default SITL home (Zurich): where a run is when nothing else is said.
DEFAULT_HOME = Home(47.397742, 8.545594, 488.0)
# Homes by name (``--home CMAC``): PX4's default and a few of ArduPilot's
# Tools/autotest/locations.txt, where scripts written for their SITLs expect to be.
# locations.txt's fourth field, the heading, is not taken: the simulator starts facing
# north (docs/mavlink.md).
NAMED_HOMES: dict[str, Home] = {
    "PX4": DEFAULT_HOME,
    "CMAC": Home(-35.363261, 149.165230, 584.0),  # ArduPilot SITL's default (sim_vehicle.py)
    "ARDUCOPTER_AUTOTEST": Home(-35.362938, 149.165085, 584.0),
    "CMAC2": Home(-35.362889, 149.165221, 584.0),
    "KSFO": Home(37.619373, -122.376637, 5.3),
    "OSRF0": Home(37.4003371, -122.0800351, 0.0),
    "Kingaroy": Home(-26.583528, 151.840440, 444.0),
    "Ballarat": Home(-37.598705, 143.881744, 485.0),
}


SEA_LEVEL_PRESSURE_HPA = 1013.25


def pressure_hpa(alt_amsl_m: float) -> float:
    """International standard atmosphere below 11 km: what a barometer reads."""
    return SEA_LEVEL_PRESSURE_HPA * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


pressure_hpa_compiled = njit(cache=True)(pressure_hpa)  # the same source, the same bits


def altitude_from_pressure_m(pressure_hpa_: float) -> float:
    """Altitude AMSL [m] of a pressure in the standard atmosphere (pressure_hpa inverted)."""
    return (1.0 - (pressure_hpa_ / SEA_LEVEL_PRESSURE_HPA) ** (1.0 / 5.25588)) / 2.25577e-5


altitude_from_pressure_m_compiled = njit(cache=True)(altitude_from_pressure_m)
