"""QGroundControl ``.plan`` files read into the vehicle's mission, fence and rally lists
(pure: a file in, checked items out). The autopilot reads a scenario's plan with it
(``--mission``); ``ivfm plan`` (ground/uplink/plan.py) uploads one as a ground tool does.

A plan's simple items become MISSION_ITEM_INT as QGroundControl sends them (a DO_JUMP's
target, given as the target's doJumpId, becomes its sequence number); its fence polygons
and circles and its rally points become the fence and rally lists. Complex items
(surveys, corridor scans) are refused: QGroundControl expands them itself.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from autopilot.navigator.mission_store import (
    FENCE,
    MISSION,
    RALLY,
    ItemError,
    MissionItem,
    check_item,
)
from contracts.mavlink import GLOBAL_FRAMES, mavlink

M = mavlink


class PlanError(ValueError):
    """A plan file this stack cannot take; the message names the place in the file."""


def read_plan(path: Path) -> dict[int, tuple[MissionItem, ...]]:
    """The mission, fence and rally lists of a .plan file, each item checked as the vehicle
    will check it."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise PlanError(f"{path}: no such file") from None
    except OSError as exc:  # a folder (an empty name), no permission
        raise PlanError(f"{path}: cannot read it: {exc.strerror}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PlanError(f"{path}: not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("fileType") != "Plan":
        raise PlanError(f"{path}: not a QGroundControl plan (fileType must be \"Plan\")")
    lists = {MISSION: _shapes(_mission, _section(data, "mission", path), path, "mission"),
             FENCE: _shapes(_fence, _section(data, "geoFence", path), path, "geoFence"),
             RALLY: _shapes(_rally, _section(data, "rallyPoints", path), path, "rallyPoints")}
    for items in lists.values():
        for item in items:
            try:
                check_item(item, len(items))
            except ItemError as exc:
                raise PlanError(f"{path}: {exc}") from None
    return lists


def _section(data: dict, key: str, path: Path) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise PlanError(f"{path}: {key} must be an object, got {type(value).__name__}")
    return value


def _shapes(read: Any, section: dict, path: Path, key: str) -> tuple[MissionItem, ...]:
    """A mission, fence or rally section, its lists and their entries checked for shape: anything
    malformed is a PlanError naming the section."""
    try:
        return read(section, path)
    except PlanError:
        raise
    except (TypeError, AttributeError, IndexError, KeyError, ValueError,
            OverflowError) as exc:
        raise PlanError(f"{path}: {key} is malformed ({type(exc).__name__}: {exc}); "
                        "QGroundControl writes lists of objects there") from None


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def _mission(mission: dict, path: Path) -> tuple[MissionItem, ...]:
    raw = mission.get("items", [])
    if not isinstance(raw, list):
        raise PlanError(f"{path}: mission.items must be a list")
    jump_ids = {}
    for seq, entry in enumerate(raw):
        if not isinstance(entry, dict) or entry.get("type") != "SimpleItem":
            kind = entry.get("type") if isinstance(entry, dict) else type(entry).__name__
            raise PlanError(f"{path}: mission.items[{seq}] is a {kind}; only SimpleItem is "
                            "taken (QGroundControl expands surveys itself)")
        if "doJumpId" in entry:
            jump_ids[entry["doJumpId"]] = seq
    items = []
    for seq, entry in enumerate(raw):
        try:
            params = [_number(v) for v in entry["params"]]
            command, frame = int(entry["command"]), int(entry["frame"])
        except (KeyError, TypeError, ValueError, OverflowError):
            raise PlanError(f"{path}: mission.items[{seq}] needs command, frame and 7 "
                            "params") from None
        if len(params) != 7:
            raise PlanError(f"{path}: mission.items[{seq}].params must hold 7 values")
        if command == M.MAV_CMD_DO_JUMP:
            if params[0] not in jump_ids:
                raise PlanError(f"{path}: mission.items[{seq}] jumps to doJumpId "
                                f"{params[0]:g}, which no item has")
            params[0] = float(jump_ids[params[0]])
        global_frame = frame in GLOBAL_FRAMES
        scale = 1e7 if global_frame else 1.0
        x = 0.0 if math.isnan(params[4]) else params[4] * scale
        y = 0.0 if math.isnan(params[5]) else params[5] * scale
        z = 0.0 if math.isnan(params[6]) else params[6]
        items.append(MissionItem(seq, frame, command, 0, int(bool(entry.get("autoContinue",
                                                                             True))),
                                 tuple(params[0:4]), round(x) if global_frame else x,
                                 round(y) if global_frame else y, z, MISSION))
    return tuple(items)


def _fence(fence: dict, path: Path) -> tuple[MissionItem, ...]:
    items: list[MissionItem] = []
    for i, polygon in enumerate(fence.get("polygons", [])):
        points = polygon.get("polygon", [])
        command = (M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if polygon.get("inclusion",
                                                                               True)
                   else M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
        for lat, lon in (p[:2] for p in points):
            items.append(_global(len(items), command, (float(len(points)), 0.0, 0.0, 0.0),
                                 lat, lon, 0.0, FENCE, f"{path}: geoFence.polygons[{i}]"))
    for i, circle in enumerate(fence.get("circles", [])):
        shape = circle.get("circle", {})
        command = (M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if circle.get("inclusion", True)
                   else M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION)
        lat, lon = shape.get("center", [math.nan, math.nan])[:2]
        items.append(_global(len(items), command, (_number(shape.get("radius")), 0.0, 0.0,
                                                   0.0), lat, lon, 0.0, FENCE,
                             f"{path}: geoFence.circles[{i}]"))
    return tuple(items)


def _rally(rally: dict, path: Path) -> tuple[MissionItem, ...]:
    return tuple(_global(i, M.MAV_CMD_NAV_RALLY_POINT, (0.0, 0.0, 0.0, 0.0), p[0], p[1], p[2],
                         RALLY, f"{path}: rallyPoints.points[{i}]")
                 for i, p in enumerate(rally.get("points", [])))


def _global(seq: int, command: int, params, lat, lon, alt, mission_type: int,
            where: str) -> MissionItem:
    try:
        lat, lon, alt = float(lat), float(lon), float(alt)
    except (TypeError, ValueError):
        raise PlanError(f"{where}: latitude, longitude and altitude must be numbers") from None
    if not (math.isfinite(lat) and math.isfinite(lon)):
        raise PlanError(f"{where}: latitude and longitude must be finite")
    return MissionItem(seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 1, params,
                       round(lat * 1e7), round(lon * 1e7), alt, mission_type)
