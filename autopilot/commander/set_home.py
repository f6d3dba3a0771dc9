"""Moving home (MAV_CMD_DO_SET_HOME, as a command or a mission item): the vehicle side.

Home moves, the local frame's origin stays (autopilot/navigator/home.py), as Copter's
set_home moves AP_AHRS's home and leaves the EKF origin; PX4's commander does the same.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from autopilot.refusal import RefusedError
from contracts.frames import Home
from contracts.vectors import MEASUREMENT

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander


def set_home(vehicle: Commander, lat_deg: float, lon_deg: float, alt_amsl_m: float,
             here: bool) -> Home:
    """Home at the given place, or where the vehicle is (``here``: DO_SET_HOME's param1
    1, or latitude and longitude 0). Refused, nothing changed, before the origin is
    known (Copter: no EKF origin; failed), and for a place not on Earth, outside a
    Home's altitude range or NaN (denied: Copter's location_from_command_t).
    Silent when it succeeds, as Copter is: HOME_POSITION tells the tools."""
    if not vehicle.home_known or vehicle.measurement is None:
        raise RefusedError("home not set: no position yet", failed=True)
    places = vehicle.places
    if here:
        lat_deg, lon_deg, alt_amsl_m = places.origin.geodetic_from_ned(
            *vehicle.measurement[MEASUREMENT.position_ned_m])
    if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_amsl_m)):
        raise RefusedError("home not set: latitude, longitude and altitude must be finite")
    try:
        home = Home.checked(lat_deg, lon_deg, alt_amsl_m)
    except ValueError as exc:
        raise RefusedError(f"home not set: {exc}") from None
    vehicle.navigator.places = places.moved_to(home)
    return home
