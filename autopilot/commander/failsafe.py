"""Failsafes: what the loss of a link or a fence breach does (PX4's parameters).

* timed on the link clock: the ground station's heartbeat (COM_DL_LOSS_T / NAV_DLL_ACT),
  and the input stream a mode flies on: offboard setpoints (COM_OF_LOSS_T / COM_OBL_ACT)
  or manual control (COM_RC_LOSS_T / NAV_RCL_ACT);
* the geofence (GF_ACTION), on sim time.
Pure, as PX4's failsafe: it reads a snapshot of the vehicle (:class:`FailsafeView`, plain
values) and returns a :class:`FailsafeDecision`; the commander carries it out
(``Commander.apply_failsafe``), the only place a failsafe changes the vehicle.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from autopilot.navigator.geofence import GeofenceWatch
from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import MissionItem
from contracts.modes import FlightMode


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


def radio_loss_action(fs_thr_enable: float, mode: FlightMode) -> FlightMode | None:
    """FS_THR_ENABLE (Copter's radio failsafe): 1, 4, 6 return (SmartRTL and DO_LAND_START
    are not built: RTL, as Copter falls back), 3, 5, 7 land, 2 returns unless AUTO flies
    on (None: said only)."""
    if int(fs_thr_enable) == 2 and mode is FlightMode.MISSION:
        return None
    return FlightMode.LAND if int(fs_thr_enable) in (3, 5, 7) else FlightMode.RTL


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


@dataclass(frozen=True)
class FailsafeView:
    """What the failsafes read of the vehicle: a snapshot the commander takes."""

    armed: bool
    landed: bool
    stream: Stream | None  # the input stream the current mode flies on


class Response(enum.Enum):
    """What the commander does with a failsafe (as PX4's commander: say it, then hold,
    return, land, or disarm when already on the ground)."""

    NOTE = "note"  # a warning only: said (severity 4), not a failsafe (GF_ACTION 1)
    WARN = "warn"  # a failsafe with nothing to do (disarmed, or no action): said
    DISARM = "disarm"  # a failsafe on the ground: disarmed, saying why
    SWITCH = "switch"  # a failsafe in the air: said, then the mode (unless already in it)
    FALL_BACK = "fall back"  # disarmed in a mode whose stream stopped: quietly in ``mode``


@dataclass(frozen=True)
class FailsafeDecision:
    """A failsafe's outcome: what went wrong (the commander's ``failsafe`` text) and what
    to do about it."""

    response: Response
    reason: str
    mode: FlightMode | None = None  # SWITCH and FALL_BACK: the mode to be in


def decide(reason: str, action: FlightMode | None, view: FailsafeView) -> FailsafeDecision:
    """The response to a failsafe whose action is ``action`` (None: a warning)."""
    if not view.armed or action is None:
        return FailsafeDecision(Response.WARN, reason)
    if view.landed:
        return FailsafeDecision(Response.DISARM, reason)
    return FailsafeDecision(Response.SWITCH, reason, action)


class Failsafes:
    """Watches the links, the input streams and the fence, and decides what their loss or
    breach calls for; the commander applies the decisions."""

    def __init__(self) -> None:
        self.links = LinkWatch()
        self.geofence = GeofenceWatch()

    def ground_station(self, link_t_s: float, p: Mapping[str, float],
                       view: FailsafeView) -> FailsafeDecision | None:
        """COM_DL_LOSS_T / NAV_DLL_ACT: the ground station's heartbeat stopped (once per
        loss)."""
        if self.links.gcs_lost_now(link_t_s, p["COM_DL_LOSS_T"]):
            return decide("ground station lost", GCS_LOSS_ACTIONS[int(p["NAV_DLL_ACT"])], view)
        return None

    def input_stream(self, link_t_s: float, p: Mapping[str, float],
                     view: FailsafeView) -> FailsafeDecision | None:
        """The current mode's input stream stopped: its failsafe in flight; disarmed, the
        vehicle falls back to HOLD without entering it (nothing said)."""
        stream = view.stream
        if stream is None or self.links.streaming(stream, link_t_s, p):
            return None
        if view.armed:
            return decide(*stream_loss(stream, p), view)
        return FailsafeDecision(Response.FALL_BACK, "", FlightMode.HOLD)

    def fence(self, fence: tuple[MissionItem, ...], places: Places, position_ned_m: np.ndarray,
              p: Mapping[str, float], view: FailsafeView) -> FailsafeDecision | None:
        """GF_ACTION on crossing out of the fence (once per breach): a STATUSTEXT, and
        hold, return or land."""
        reason = self.geofence.crossed_out(fence, places, position_ned_m,
                                           p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"])
        if reason is None:
            return None
        action = GEOFENCE_ACTIONS[int(p["GF_ACTION"])]
        if action is not None:
            return decide(f"geofence: {reason}", action, view)
        if p["GF_ACTION"] == 1:  # a warning, not a failsafe
            return FailsafeDecision(Response.NOTE, f"geofence: {reason}")
        return None
