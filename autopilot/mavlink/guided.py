"""Copter's own requests: GUIDED requests carried in mission items (ArduPilot's GCS_MAVLINK::
handle_mission_item): a MISSION_ITEM / MISSION_ITEM_INT of the mission list with current=2
is a go-to (DroneKit's ``simple_goto``: NAV_WAYPOINT, frame GLOBAL_RELATIVE_ALT, latitude,
longitude, altitude), current=3 an altitude change. Never stored in the mission; each is
answered with a MISSION_ACK: ACCEPTED, or ERROR with the reason in a STATUSTEXT when the
vehicle refuses it (nothing changed). And the commands only Copter's flavour serves
(``copter_commands``): flight termination, CONDITION_YAW and DO_SET_ROI*.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.refusal import RefusedError
from contracts.mavlink import GLOBAL_FRAMES, mavlink

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
            vehicle.auto.guided_altitude(alt if relative
                                         else alt - vehicle.places.home.alt_amsl_m)
            return
        if msg.command != M.MAV_CMD_NAV_WAYPOINT:
            raise RefusedError(f"guided item command {msg.command} is not a waypoint")
        if abs(lat) > 90.0 or abs(lon) > 180.0:
            raise RefusedError(f"go-to latitude/longitude {lat:g}, {lon:g} is not on Earth")
        vehicle.auto.guided_go_to(vehicle.places.ned_from_global(msg.frame, lat, lon, alt))


def copter_commands(server: ServerLink, frame: Callable[[], int]) -> dict[int, Callable]:
    """The commands only Copter's flavour serves (the PX4 flavour answers them
    UNSUPPORTED, as before): flight termination, and CONDITION_YAW / DO_SET_ROI* as
    GUIDED requests. Handlers as the command protocol calls them: (link, params, now);
    ``frame`` gives the frame of the command being handled."""
    personality = server.vehicle.personality

    def terminate(link, p, now):
        """MAV_CMD_DO_FLIGHTTERMINATION: param1 above 0.5 stops the motors and disarms at
        once, in the air too; anything else is refused."""
        if not p[0] > 0.5:
            raise RefusedError(f"flight termination needs param1 1, got {p[0]:g}")
        server.vehicle.terminate()

    def yaw(link, p, now):
        """CONDITION_YAW in GUIDED: param1 angle [deg], param3 direction (-1
        counter-clockwise), param4 1 relative / 0 absolute; param2's rate is not used."""
        if p[3] not in (0.0, 1.0):
            raise RefusedError(f"yaw param4 must be 0 (absolute) or 1 (relative), got "
                               f"{p[3]:g}")
        server.vehicle.auto.guided_yaw(p[0], p[2], p[3] == 1.0)

    def roi(link, p, now):
        """DO_SET_ROI_LOCATION / DO_SET_ROI in GUIDED: latitude, longitude and altitude in
        params 5-7; latitude and longitude 0: no region of interest, as Copter reads
        them."""
        if frame() not in GLOBAL_FRAMES:
            raise RefusedError(f"region of interest frame {frame()} is not supported")
        lat, lon, alt = p[4], p[5], p[6]
        if not all(math.isfinite(v) for v in (lat, lon)):
            raise RefusedError("region of interest latitude/longitude must be finite")
        if abs(lat) > 90.0 or abs(lon) > 180.0:
            raise RefusedError(f"region of interest {lat:g}, {lon:g} is not on Earth")
        vehicle = server.vehicle
        if lat == 0.0 and lon == 0.0:
            vehicle.auto.guided_roi(None)
            return
        alt = alt if math.isfinite(alt) else 0.0
        vehicle.auto.guided_roi(vehicle.places.ned_from_global(frame(), lat, lon, alt))

    def roi_none(link, p, now):
        server.vehicle.auto.guided_roi(None)

    table: dict[int, Callable] = {}
    if personality.flight_termination:
        table[M.MAV_CMD_DO_FLIGHTTERMINATION] = terminate
    if personality.guided_requests:
        table.update({M.MAV_CMD_CONDITION_YAW: yaw, M.MAV_CMD_DO_SET_ROI: roi,
                      M.MAV_CMD_DO_SET_ROI_LOCATION: roi, M.MAV_CMD_DO_SET_ROI_NONE: roi_none})
    return table
