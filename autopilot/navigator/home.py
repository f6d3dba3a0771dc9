"""Home apart from the local frame's origin (the one place the two are told apart).

The local NED frame's origin is fixed once known (the simulator's first position or
``--home``): LOCAL_POSITION_NED, the simulator link and the logs stay around it. Home is
where RTL returns and what "altitude above home" is measured from; it starts at the
origin and moves only when a tool sets it (DO_SET_HOME), as Copter keeps its home apart
from the EKF origin (AP_AHRS). Latitudes and longitudes are projected around the origin
whatever home is.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from contracts.frames import Home
from contracts.mavlink import ned_from_global


class Places(NamedTuple):
    """The local frame's origin and home on Earth (equal until a tool sets home)."""

    origin: Home
    home: Home

    @classmethod
    def at(cls, origin: Home) -> Places:
        return cls(origin, origin)

    @property
    def home_ned_m(self) -> np.ndarray:
        """Home in the local frame (zeros while home is the origin)."""
        if self.home == self.origin:
            return np.zeros(3)
        return np.array(self.origin.ned_from_geodetic(*self.home), dtype=float)

    def above_home_m(self, down_m: float) -> float:
        """Altitude above home of a local NED down coordinate."""
        if self.home == self.origin:
            return -down_m
        return self.origin.alt_amsl_m - down_m - self.home.alt_amsl_m

    def local_altitude_m(self, above_home_m: float) -> float:
        """The local frame's altitude (up from the origin) of an altitude above home."""
        if self.home == self.origin:
            return above_home_m
        return above_home_m + self.home.alt_amsl_m - self.origin.alt_amsl_m

    def ned_from_global(self, frame: int, lat_deg: float, lon_deg: float,
                        alt_m: float) -> np.ndarray:
        """Local NED of a position in a global frame: projected around the origin, a
        relative altitude taken above home (NaN stays NaN, contracts.mavlink)."""
        return ned_from_global(self.origin, frame, lat_deg, lon_deg, alt_m,
                               self.home.alt_amsl_m)

    def moved_to(self, home: Home) -> Places:
        """These places with home at ``home`` (the origin stays). Copter refuses a home
        more than 50 km above or below its EKF origin (far_from_EKF_origin); a Home's
        own altitude range (contracts/frames.py) is far narrower, so that never arises."""
        return Places(self.origin, home)
