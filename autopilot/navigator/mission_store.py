"""Missions, fences and rally points as the vehicle stores them, and the check each item
passes before it is stored (pure: no I/O). The MAVLink mission protocol that fills them
is autopilot/mavlink/mission_protocol.py; docs/missions.md describes both.

What PX4 takes is what we take: the commands below in the frames below, each parameter in
its range. An item that fails says which MAV_MISSION_RESULT (the protocol's ACK) and why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from contracts.mavlink import GLOBAL_FRAMES, mavlink

M = mavlink
MISSION, FENCE, RALLY = (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE,
                         M.MAV_MISSION_TYPE_RALLY)
MISSION_TYPES = (MISSION, FENCE, RALLY)
MAX_ITEMS = {MISSION: 500, FENCE: 64, RALLY: 8}  # MISSION_COUNT above: NO_SPACE

POSITION_FRAMES = frozenset(GLOBAL_FRAMES) | {M.MAV_FRAME_LOCAL_NED}
# The commands each mission type holds, and whether they carry a position.
NAV_COMMANDS = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME,
                M.MAV_CMD_NAV_LOITER_UNLIM,
                M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_TAKEOFF}
# Payload items (camera, gimbal): taken, so that plans with them upload, and passed over
# in flight (there is no payload).
PAYLOAD_COMMANDS = {M.MAV_CMD_DO_MOUNT_CONTROL, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                    M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
                    M.MAV_CMD_VIDEO_START_CAPTURE, M.MAV_CMD_VIDEO_STOP_CAPTURE,
                    M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, M.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
                    M.MAV_CMD_DO_TRIGGER_CONTROL}
DO_COMMANDS = {M.MAV_CMD_DO_JUMP, M.MAV_CMD_DO_CHANGE_SPEED, *PAYLOAD_COMMANDS}
# Waits without a position of their own (MAVSDK sends a loiter time as NAV_DELAY).
WAIT_COMMANDS = {M.MAV_CMD_NAV_DELAY}
FENCE_COMMANDS = {M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                  M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
                  M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION}
COMMANDS = {MISSION: NAV_COMMANDS | DO_COMMANDS | WAIT_COMMANDS, FENCE: FENCE_COMMANDS,
            RALLY: {M.MAV_CMD_NAV_RALLY_POINT}}
# What ArduPilot Copter missions hold beyond PX4's set (taken from ArduPilot-flavour
# uploads only, so the PX4 flavour takes what it always took): a heading to turn to, and
# a region of interest the nose points at (DO_SET_ROI, DO_SET_ROI_LOCATION: a location;
# DO_SET_ROI_NONE, or a location at latitude and longitude 0: none), and DO_SET_HOME
# (param1 1 or latitude and longitude 0: here; else the item's global location).
ARDUPILOT_DO_COMMANDS = {M.MAV_CMD_CONDITION_YAW, M.MAV_CMD_DO_SET_ROI,
                         M.MAV_CMD_DO_SET_ROI_LOCATION, M.MAV_CMD_DO_SET_ROI_NONE,
                         M.MAV_CMD_DO_SET_HOME}
ROI_COMMANDS = (M.MAV_CMD_DO_SET_ROI, M.MAV_CMD_DO_SET_ROI_LOCATION)
WITHOUT_POSITION = DO_COMMANDS | WAIT_COMMANDS | {M.MAV_CMD_NAV_RETURN_TO_LAUNCH,
                                                  M.MAV_CMD_CONDITION_YAW,
                                                  M.MAV_CMD_DO_SET_ROI_NONE}
MAX_ALTITUDE_M = 10_000.0
MAX_LOCAL_M = 100_000.0
MAX_SPEED_MPS = 30.0
SPEED_TYPE_AIRSPEED, SPEED_TYPE_GROUNDSPEED = 0.0, 1.0  # DO_CHANGE_SPEED param1 (SPEED_TYPE)


@dataclass(frozen=True)
class MissionItem:
    """One item as MISSION_ITEM_INT carries it: x, y in 1e-7 deg for global frames (metres
    for LOCAL_NED), z in metres."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float
    mission_type: int = MISSION

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES


class ItemError(ValueError):
    """An item refused: ``result`` is the MAV_MISSION_RESULT to acknowledge it with."""

    def __init__(self, result: int, text: str) -> None:
        super().__init__(text)
        self.result = result


def check_item(item: MissionItem, count: int, ardupilot: bool = False) -> None:
    """Raise ItemError unless the vehicle can fly (or fence with) this item of a list of
    ``count`` items; ``ardupilot``: an ArduPilot-flavour upload (ARDUPILOT_DO_COMMANDS
    taken in a mission too)."""
    commands = COMMANDS[item.mission_type]
    if ardupilot and item.mission_type == MISSION:
        commands = commands | ARDUPILOT_DO_COMMANDS
    if item.command not in commands:
        raise ItemError(M.MAV_MISSION_UNSUPPORTED,
                        f"item {item.seq}: command {item.command} is not supported here")
    positioned = item.command not in WITHOUT_POSITION and not is_roi_none(item)
    if positioned and item.frame not in POSITION_FRAMES:
        raise ItemError(M.MAV_MISSION_UNSUPPORTED_FRAME,
                        f"item {item.seq}: frame {item.frame} is not supported")
    if (item.mission_type != MISSION or item.command == M.MAV_CMD_DO_SET_HOME) and \
            item.frame not in GLOBAL_FRAMES:
        raise ItemError(M.MAV_MISSION_UNSUPPORTED_FRAME,
                        f"item {item.seq}: fence, rally and home items are global")
    p1, p2, p3, p4 = item.params
    for i, value in enumerate(item.params):
        if math.isinf(value):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM1 + i,
                            f"item {item.seq}: param{i + 1} is infinite")
    if positioned:
        _check_position(item)
    command = item.command
    if command == M.MAV_CMD_NAV_WAYPOINT:
        _at_least(item, 1, p1, 0.0, "hold time")
        _at_least(item, 2, p2, 0.0, "acceptance radius")
        _yaw(item, p4)
    elif command == M.MAV_CMD_NAV_LOITER_TIME:
        _at_least(item, 1, p1, 0.0, "loiter time")
    elif command == M.MAV_CMD_NAV_DELAY and (math.isnan(p1) or p1 < 0):
        raise ItemError(M.MAV_MISSION_INVALID_PARAM1,
                        f"item {item.seq}: delay {p1} s (a time of day is not supported)")
    elif command in (M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_LOITER_UNLIM):
        _yaw(item, p4)
    elif command == M.MAV_CMD_DO_JUMP:
        if math.isnan(p1) or not (0 <= p1 < count and p1 == int(p1)) or p1 == item.seq:
            raise ItemError(M.MAV_MISSION_INVALID_PARAM1,
                            f"item {item.seq}: jump target {p1} is not another item of "
                            f"the {count}")
        if math.isnan(p2) or p2 < -1 or p2 != int(p2):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM2,
                            f"item {item.seq}: repeat count {p2} (-1 for ever)")
    elif command == M.MAV_CMD_CONDITION_YAW:
        if math.isnan(p1) or not 0.0 <= p1 <= 360.0:
            raise ItemError(M.MAV_MISSION_INVALID_PARAM1,
                            f"item {item.seq}: heading {p1} deg (0-360)")
        if math.isnan(p2) or p2 < 0.0:
            raise ItemError(M.MAV_MISSION_INVALID_PARAM2,
                            f"item {item.seq}: yaw rate {p2} deg/s (0: the default)")
        if p3 not in (-1.0, 0.0, 1.0):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM3,
                            f"item {item.seq}: direction {p3} (-1 ccw, 1 cw, 0 shortest)")
        if p4 not in (0.0, 1.0):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM4,
                            f"item {item.seq}: {p4} (0 absolute, 1 relative)")
    elif command == M.MAV_CMD_DO_CHANGE_SPEED:
        if ardupilot and p1 not in (SPEED_TYPE_AIRSPEED, SPEED_TYPE_GROUNDSPEED):
            # Copter's types 2 and 3 set the climb and descent speeds; the mission here
            # flies its vertical speeds from the parameters, so they are refused, not
            # taken and ignored.
            raise ItemError(M.MAV_MISSION_INVALID_PARAM1,
                            f"item {item.seq}: speed type {p1} (0 airspeed, 1 ground speed; "
                            "climb and descent speeds are not flown)")
        if math.isnan(p2) or not (p2 == -1 or 0 < p2 <= MAX_SPEED_MPS):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM2,
                            f"item {item.seq}: speed {p2} m/s (0-{MAX_SPEED_MPS:g}, -1 "
                            "no change)")
    elif command in (M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                     M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
        if math.isnan(p1) or p1 < 3 or p1 != int(p1):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM1,
                            f"item {item.seq}: a polygon has at least 3 vertices, not {p1}")
    elif command in (M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                     M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION) and (math.isnan(p1) or p1 <= 0) \
            and not is_empty_circle(item):
        raise ItemError(M.MAV_MISSION_INVALID_PARAM1, f"item {item.seq}: circle radius {p1} m")


def is_roi_none(item: MissionItem) -> bool:
    """An item that ends the region of interest: DO_SET_ROI_NONE, or a region of interest
    at latitude and longitude 0 (Copter reads the location, not DO_SET_ROI's mode)."""
    if item.command == M.MAV_CMD_DO_SET_ROI_NONE:
        return True
    return item.command in ROI_COMMANDS and item.is_global and item.x == 0 and item.y == 0


def is_empty_circle(item: MissionItem) -> bool:
    """A fence circle of radius 0 at latitude 0, longitude 0: what MAVSDK's geofence
    plugin uploads for a caller with no circle. Accepted and ignored, as PX4 does (a
    radius of 0 anywhere else is refused: a mistake, not a placeholder)."""
    return (item.command in (M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                             M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION)
            and item.params[0] == 0.0 and item.x == 0 and item.y == 0)


def _check_position(item: MissionItem) -> None:
    if item.is_global:
        if not (math.isfinite(item.x) and -90e7 <= item.x <= 90e7):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM5_X,
                            f"item {item.seq}: latitude {item.x * 1e-7} deg")
        if not (math.isfinite(item.y) and -180e7 <= item.y <= 180e7):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM6_Y,
                            f"item {item.seq}: longitude {item.y * 1e-7} deg")
        if not (math.isfinite(item.z) and abs(item.z) <= MAX_ALTITUDE_M):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM7,
                            f"item {item.seq}: altitude {item.z} m")
        return
    for value, result, name in ((item.x, M.MAV_MISSION_INVALID_PARAM5_X, "x"),
                                (item.y, M.MAV_MISSION_INVALID_PARAM6_Y, "y"),
                                (item.z, M.MAV_MISSION_INVALID_PARAM7, "z")):
        if not (math.isfinite(value) and abs(value) <= MAX_LOCAL_M):
            raise ItemError(result, f"item {item.seq}: {name} {value} m")


def _at_least(item: MissionItem, index: int, value: float, low: float, what: str) -> None:
    if not math.isnan(value) and value < low:
        raise ItemError(M.MAV_MISSION_INVALID_PARAM1 + index - 1,
                        f"item {item.seq}: {what} {value} below {low:g}")


def _yaw(item: MissionItem, value: float) -> None:
    if not math.isnan(value) and abs(value) > 360.0:
        raise ItemError(M.MAV_MISSION_INVALID_PARAM4,
                        f"item {item.seq}: yaw {value} deg (NaN: keep the heading)")


@dataclass
class MissionStore:
    """The stored lists, one per mission type, and the mission's current item. A list is
    replaced only by a complete, valid upload (or cleared); the stored mission survives
    mode changes."""

    lists: dict[int, tuple[MissionItem, ...]] = field(
        default_factory=lambda: {t: () for t in MISSION_TYPES})
    current: int = 0

    def replace(self, mission_type: int, items: tuple[MissionItem, ...]) -> None:
        self.lists[mission_type] = items
        if mission_type == MISSION:
            self.current = 0

    def clear(self, mission_type: int) -> None:
        for t in (MISSION_TYPES if mission_type == M.MAV_MISSION_TYPE_ALL else (mission_type,)):
            self.replace(t, ())

    def set_current(self, seq: int) -> None:
        if not 0 <= seq < len(self.lists[MISSION]):
            raise ItemError(M.MAV_MISSION_INVALID_SEQUENCE,
                            f"no mission item {seq} (the mission has "
                            f"{len(self.lists[MISSION])})")
        self.current = seq
