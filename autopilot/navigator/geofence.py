"""The geofence (pure): the uploaded fence (inclusion / exclusion polygons and circles) and
PX4's distance limits (GF_MAX_HOR_DIST, GF_MAX_VER_DIST), and whether a position breaks
them. What the vehicle does about a breach (GF_ACTION) is a failsafe
(autopilot/commander/failsafe.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import MissionItem, is_empty_circle
from contracts.frames import Home
from contracts.mavlink import mavlink

M = mavlink
INCLUSIONS = (M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION)
POLYGONS = (M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)


@dataclass(frozen=True)
class Zone:
    """A polygon (vertices north, east [m] from home) or a circle (centre and radius)."""

    inclusion: bool
    vertices: np.ndarray | None = None  # (n, 2)
    centre: tuple[float, float] | None = None
    radius_m: float = 0.0

    def contains(self, north: float, east: float) -> bool:
        if self.vertices is None:
            return (north - self.centre[0]) ** 2 + (east - self.centre[1]) ** 2 <= \
                self.radius_m ** 2
        inside = False  # ray casting along +east
        v = self.vertices
        for i in range(len(v)):
            (n1, e1), (n2, e2) = v[i - 1], v[i]
            crosses = (n1 > north) != (n2 > north)
            if crosses and east < e1 + (north - n1) * (e2 - e1) / (n2 - n1):
                inside = not inside
        return inside


def zones_from_items(items: tuple[MissionItem, ...], origin: Home) -> tuple[Zone, ...]:
    """The fence list's zones around ``home``: consecutive polygon vertices (param1 of each
    = their count), circles one item each."""
    zones, i = [], 0
    while i < len(items):
        item = items[i]
        north, east, _ = origin.ned_from_geodetic(item.x * 1e-7, item.y * 1e-7, 0.0)
        inclusion = item.command in INCLUSIONS
        if item.command in POLYGONS:
            count = int(item.params[0])
            group = items[i:i + count]
            vertices = np.array([origin.ned_from_geodetic(g.x * 1e-7, g.y * 1e-7, 0.0)[:2]
                                 for g in group])
            zones.append(Zone(inclusion, vertices=vertices))
            i += max(count, 1)
        else:
            if not is_empty_circle(item):
                zones.append(Zone(inclusion, centre=(north, east), radius_m=item.params[0]))
            i += 1
    return tuple(zones)


def breach(position_ned_m: np.ndarray, zones: tuple[Zone, ...], max_horizontal_m: float,
           max_vertical_m: float, home_ned_m: np.ndarray | None = None) -> str | None:
    """Why this position is outside the fence, or None when it is inside. A limit of 0
    is off, as in PX4; the limits are from home (``home_ned_m``, the origin if None),
    the zones in the local frame."""
    north, east, down = (float(v) for v in position_ned_m)
    from_home = position_ned_m if home_ned_m is None else position_ned_m - home_ned_m
    distance = float(np.hypot(from_home[0], from_home[1]))
    down = float(from_home[2])
    if max_horizontal_m > 0 and distance > max_horizontal_m:
        return f"{distance:.1f} m from home, beyond {max_horizontal_m:g} m"
    if max_vertical_m > 0 and -down > max_vertical_m:
        return f"{-down:.1f} m up, above {max_vertical_m:g} m"
    inclusions = [z for z in zones if z.inclusion]
    if inclusions and not any(z.contains(north, east) for z in inclusions):
        return "outside the inclusion fence"
    if any(z.contains(north, east) for z in zones if not z.inclusion):
        return "inside an exclusion zone"
    return None


class GeofenceWatch:
    """Tells a breach once, when the vehicle crosses out of its fence (as PX4 does)."""

    def __init__(self) -> None:
        self.breach: str | None = None  # why the vehicle is outside its fence
        self._fence_of: tuple | None = None  # the fence list and origin the zones are from
        self._zones: tuple = ()

    def crossed_out(self, fence: tuple, places: Places, position_ned_m: np.ndarray,
                    max_hor_m: float, max_ver_m: float) -> str | None:
        """The reason when this sample is the first outside, else None."""
        origin = places.origin
        if self._fence_of is None or fence is not self._fence_of[0] or \
                origin != self._fence_of[1]:
            self._fence_of, self._zones = (fence, origin), zones_from_items(fence, origin)
        reason = breach(position_ned_m, self._zones, max_hor_m, max_ver_m, places.home_ned_m)
        first = reason is not None and self.breach is None
        self.breach = reason
        return reason if first else None
