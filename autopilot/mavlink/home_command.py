"""MAV_CMD_DO_SET_HOME as COMMAND_LONG or COMMAND_INT (both flavours): what a tool's
numbers mean, as GCS_MAVLINK::handle_command_do_set_home reads them."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from autopilot.commander.set_home import set_home
from autopilot.refusal import RefusedError
from contracts.mavlink import GLOBAL_FRAMES

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander


def do_set_home(vehicle: Commander, frame: int, p: list[float]) -> None:
    """param1 1 (or latitude and longitude both 0): home where the vehicle is; else
    params 5-7 latitude, longitude, altitude: AMSL in COMMAND_LONG (MAV_FRAME_GLOBAL),
    in COMMAND_INT as its frame says (above the current home in a relative frame)."""
    if frame not in GLOBAL_FRAMES:
        raise RefusedError(f"home not set: frame {frame} is not supported")
    lat, lon, alt = p[4], p[5], p[6]
    here = p[0] == 1.0 or (lat == 0.0 and lon == 0.0)
    if not here and math.isfinite(alt) and GLOBAL_FRAMES[frame]:
        alt += vehicle.places.home.alt_amsl_m
    set_home(vehicle, lat, lon, alt, here)
