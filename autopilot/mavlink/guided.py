"""Copter's GUIDED requests carried in mission items (ArduPilot's GCS_MAVLINK::
handle_mission_item): a MISSION_ITEM / MISSION_ITEM_INT of the mission list with current=2
is a go-to (DroneKit's ``simple_goto``: NAV_WAYPOINT, frame GLOBAL_RELATIVE_ALT, latitude,
longitude, altitude), current=3 an altitude change. Never stored in the mission; each is
answered with a MISSION_ACK: ACCEPTED, or ERROR with the reason in a STATUSTEXT when the
vehicle refuses it (nothing changed).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from autopilot.refusal import RefusedError
from contracts.mavlink import GLOBAL_FRAMES, mavlink, ned_from_global

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink

M = mavlink
GUIDED_GO_TO, ALTITUDE_CHANGE = 2, 3  # MISSION_ITEM current


class GuidedItems:
    """Serves current=2 / 3 items for the mission protocol (mission_protocol.py's hook)."""

    def __init__(self, server: ServerLink) -> None:
        self.server = server

    def on_item(self, link: GroundLink, address, msg, now: float) -> None:
        result = M.MAV_MISSION_ACCEPTED
        try:
            self._apply(msg)
        except RefusedError as exc:
            result = M.MAV_MISSION_ERROR
            self.server.send_text(link, 4, str(exc), address)
        self.server.send(link, M.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), result, M.MAV_MISSION_TYPE_MISSION),
            address)

    def _apply(self, msg) -> None:
        vehicle = self.server.vehicle
        if msg.frame not in GLOBAL_FRAMES:
            raise RefusedError(f"guided item frame {msg.frame} is not supported")
        legacy = msg.get_type() == "MISSION_ITEM"
        lat, lon = (float(v) if legacy else v * 1e-7 for v in (msg.x, msg.y))
        alt = float(msg.z)
        if not all(math.isfinite(v) for v in (lat, lon, alt)):
            raise RefusedError("guided item position must be finite")
        relative = GLOBAL_FRAMES[msg.frame]
        if msg.current == ALTITUDE_CHANGE:
            vehicle.auto.guided_altitude(alt if relative else alt - vehicle.home.alt_amsl_m)
            return
        if msg.command != M.MAV_CMD_NAV_WAYPOINT:
            raise RefusedError(f"guided item command {msg.command} is not a waypoint")
        if abs(lat) > 90.0 or abs(lon) > 180.0:
            raise RefusedError(f"go-to latitude/longitude {lat:g}, {lon:g} is not on Earth")
        vehicle.auto.guided_go_to(ned_from_global(vehicle.home, msg.frame, lat, lon, alt))
