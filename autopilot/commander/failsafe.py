"""Failsafes: what the loss of a link or a fence breach does (PX4's parameters).

* timed on the link clock: the ground station's heartbeat (COM_DL_LOSS_T / NAV_DLL_ACT),
  and the input stream a mode flies on: offboard setpoints (COM_OF_LOSS_T / COM_OBL_ACT)
  or manual control (COM_RC_LOSS_T / NAV_RCL_ACT);
* the geofence (GF_ACTION), on sim time.
Pure: the commander calls it with the link clock and carries out the action it names.
"""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING

from autopilot.navigator.geofence import GeofenceWatch
from autopilot.navigator.mission_store import FENCE
from contracts.modes import FlightMode
from contracts.vectors import MEASUREMENT

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander


class Stream(enum.Enum):
    """An input stream a mode flies on: entering it needs the stream, losing it is a
    failsafe."""

    SETPOINTS = "setpoint stream"  # SET_POSITION_TARGET_* / SET_ATTITUDE_TARGET
    MANUAL = "manual control input"  # MANUAL_CONTROL


# GF_ACTION -> the mode a breach puts the vehicle in (None: a warning only).
GEOFENCE_ACTIONS = {0: None, 1: None, 2: FlightMode.HOLD, 3: FlightMode.RTL,
                    5: FlightMode.LAND}

# NAV_DLL_ACT: what ground-station loss does (PX4's numbers).
GCS_LOSS_ACTIONS: dict[int, FlightMode | None] = {0: None, 1: FlightMode.HOLD,
                                                  2: FlightMode.RTL, 3: FlightMode.LAND}


# NAV_RCL_ACT: what the loss of manual control does in a manual mode.
MANUAL_LOSS_ACTIONS: dict[int, FlightMode] = {1: FlightMode.HOLD, 2: FlightMode.RTL,
                                              3: FlightMode.LAND}


def offboard_loss_action(com_obl_act: float) -> FlightMode:
    """COM_OBL_ACT: 0 lands, otherwise hold."""
    return FlightMode.LAND if com_obl_act == 0 else FlightMode.HOLD


def stream_loss(stream: Stream, p: dict[str, float]) -> tuple[str, FlightMode]:
    """What the failsafe says and does when ``stream`` stops in flight."""
    if stream is Stream.SETPOINTS:
        return "offboard setpoints lost", offboard_loss_action(p["COM_OBL_ACT"])
    return "manual control lost", MANUAL_LOSS_ACTIONS[int(p["NAV_RCL_ACT"])]


class LinkWatch:
    """When the ground station and the setpoint stream were last heard (link clock)."""

    def __init__(self) -> None:
        self.gcs_heard_s: float | None = None
        self.gcs_lost = False
        self.setpoint_heard_s: float | None = None
        self.manual_heard_s: float | None = None

    def gcs_heartbeat(self, link_t_s: float) -> bool:
        """A ground station heartbeat; True if it ends a loss."""
        self.gcs_heard_s = link_t_s
        regained, self.gcs_lost = self.gcs_lost, False
        return regained

    def gcs_lost_now(self, link_t_s: float, timeout_s: float) -> bool:
        """True once, when the ground station has been silent for ``timeout_s``."""
        if (self.gcs_heard_s is not None and not self.gcs_lost
                and link_t_s - self.gcs_heard_s > timeout_s):
            self.gcs_lost = True
            return True
        return False

    def setpoint_heard(self, link_t_s: float) -> None:
        self.setpoint_heard_s = link_t_s

    def setpoints_streaming(self, link_t_s: float, timeout_s: float) -> bool:
        return self.setpoint_heard_s is not None and \
            link_t_s - self.setpoint_heard_s <= timeout_s

    def manual_streaming(self, link_t_s: float, timeout_s: float) -> bool:
        return self.manual_heard_s is not None and link_t_s - self.manual_heard_s <= timeout_s

    def streaming(self, stream: Stream, link_t_s: float, p: dict[str, float]) -> bool:
        if stream is Stream.SETPOINTS:
            return self.setpoints_streaming(link_t_s, p["COM_OF_LOSS_T"])
        return self.manual_streaming(link_t_s, p["COM_RC_LOSS_T"])


class Failsafes:
    """Watches the links, the input streams and the fence of ``vehicle``, and carries out
    what their loss or breach calls for (as PX4's commander: say it, then hold, return,
    land, or disarm when already on the ground)."""

    def __init__(self, vehicle: Commander) -> None:
        self.vehicle = vehicle
        self.links = LinkWatch()
        self.geofence = GeofenceWatch()

    def check_links(self, link_t_s: float) -> None:
        v = self.vehicle
        p = v.parameters
        if self.links.gcs_lost_now(link_t_s, p["COM_DL_LOSS_T"]):
            self.trigger("ground station lost", GCS_LOSS_ACTIONS[int(p["NAV_DLL_ACT"])])
        stream = v.row.stream
        if stream is not None and not self.links.streaming(stream, link_t_s, p):
            if v.armed:
                self.trigger(*stream_loss(stream, p))
            else:
                v.mode = FlightMode.HOLD

    def check_geofence(self) -> None:
        """GF_ACTION on crossing out of the fence (once per breach): a STATUSTEXT, and
        hold, return or land."""
        v = self.vehicle
        p = v.parameters
        reason = self.geofence.crossed_out(
            v.mission.lists[FENCE], v.home, v.measurement[MEASUREMENT.position_ned_m],
            p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"])
        if reason is None:
            return
        action = GEOFENCE_ACTIONS[int(p["GF_ACTION"])]
        if action is not None:
            self.trigger(f"geofence: {reason}", action)
        elif p["GF_ACTION"] == 1:  # a warning, not a failsafe
            v.say(f"geofence: {reason}", 4)

    def trigger(self, what: str, action: FlightMode | None) -> None:
        v = self.vehicle
        v.failsafe = what
        if not v.armed or action is None:
            v.say(f"{what}", 4)
            return
        if v.landed:
            v.end_flight(f"{what}: disarmed on the ground")
            return
        v.say(f"{what}: {action.value}", 4)
        if v.mode != action:
            v.switch_to(action)
