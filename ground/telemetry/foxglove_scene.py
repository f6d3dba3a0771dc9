"""The shapes Foxglove draws, built from plain numbers: frame and topic names, poses,
the vehicle's model, the mission and the fence as scene entities; and how a message is
encoded for MCAP (``encode``) and its JSON schema. ``foxglove_view`` decides what to
draw and when."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove import messages as fg

FRAME_WORLD = "world"
FRAME_NED = "ned"
MAX_SCENE_ITEMS = 512  # waypoints / fence vertices drawn from one scene record


def body_frame(vehicle: int) -> str:
    return f"vehicle{vehicle}"


def rotor_frame(vehicle: int, rotor: int) -> str:
    return f"vehicle{vehicle}/rotor{rotor}"


def vehicle_topic(vehicle: int, name: str) -> str:
    return f"/vehicle{vehicle}/{name}"


def timestamp(sim_time_us: int) -> fg.Timestamp:
    sec, usec = divmod(int(sim_time_us), 1_000_000)
    return fg.Timestamp(sec, usec * 1000)


def fg_quaternion(q_wxyz: np.ndarray) -> fg.Quaternion:
    return fg.Quaternion(x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]),
                         w=float(q_wxyz[0]))


def fg_vector(v: Any) -> fg.Vector3:
    return fg.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def fg_point(v: Any) -> fg.Point3:
    return fg.Point3(x=float(v[0]), y=float(v[1]), z=float(v[2]) if len(v) > 2 else 0.0)


def fg_pose(position: Any, q_wxyz: np.ndarray) -> fg.Pose:
    return fg.Pose(position=fg_vector(position), orientation=fg_quaternion(q_wxyz))


def fg_color(r: float, g: float, b: float, a: float = 1.0) -> fg.Color:
    return fg.Color(r=r, g=g, b=b, a=a)


IDENTITY = fg.Pose(position=fg.Vector3(x=0, y=0, z=0),
                   orientation=fg.Quaternion(x=0, y=0, z=0, w=1))


def finite_list(values: Any, size: int) -> list[float]:
    """``size`` finite numbers, else ValueError (scene records come over the network)."""
    if not isinstance(values, list | tuple) or len(values) != size:
        raise ValueError(f"expected {size} numbers, got {values!r:.60}")
    out = [float(v) for v in values]
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"expected finite numbers, got {values!r:.60}")
    return out


def finite_or_none(x: Any) -> float | None:
    """JSON has no NaN: a missing number is null (plots show a gap)."""
    value = float(x)
    return value if math.isfinite(value) else None


def item_rows(values: Any, size: int, what: str) -> list[list[float]]:
    if not isinstance(values, list) or len(values) > MAX_SCENE_ITEMS:
        raise ValueError(f"scene: {what} must be a list of at most {MAX_SCENE_ITEMS}")
    return [finite_list(p, size) for p in values]


def zone_dict(zone: Any) -> dict[str, Any]:
    if not isinstance(zone, dict) or not isinstance(zone.get("inclusion"), bool):
        raise ValueError("scene: a fence zone is an object with a boolean inclusion")
    if "polygon" in zone:
        return {"inclusion": zone["inclusion"], "points": item_rows(zone["polygon"], 2, "polygon")}
    centre = finite_list(zone.get("centre"), 2)
    radius = finite_list([zone.get("radius_m")], 1)[0]
    if not 0 < radius <= 1e6:
        raise ValueError("scene: a fence circle's radius must be in (0, 1e6] m")
    points = [[centre[0] + radius * math.cos(a), centre[1] + radius * math.sin(a)]
              for a in np.linspace(0, 2 * math.pi, 64, endpoint=False)]
    return {"inclusion": zone["inclusion"], "points": points}


def text_pose(position: Any) -> fg.Pose:
    return fg.Pose(position=fg_vector(position), orientation=fg.Quaternion(x=0, y=0, z=0, w=1))


def vehicle_model(vehicle: int, stamp: fg.Timestamp, rotors_m: tuple, spins: list[float],
                   name: str) -> fg.SceneEntity:
    """Arms, rotor discs (cw blue, ccw green), a nose arrow: drawn in the body frame."""
    arms = []
    for r in rotors_m:
        arms.extend([fg.Point3(x=0, y=0, z=0), fg_point(r)])
    span = max((math.hypot(r[0], r[1]) for r in rotors_m), default=0.2)
    disc = max(0.35 * span, 0.05)
    cylinders = [fg.CylinderPrimitive(
        pose=text_pose((r[0], r[1], r[2] - 0.02)), size=fg.Vector3(x=disc, y=disc, z=0.01),
        bottom_scale=1, top_scale=1,
        color=fg_color(0.2, 0.4, 1.0, 0.6) if spin > 0 else fg_color(0.2, 0.9, 0.3, 0.6))
        for r, spin in zip(rotors_m, spins, strict=True)]
    return fg.SceneEntity(
        timestamp=stamp, frame_id=body_frame(vehicle), id="vehicle", frame_locked=True,
        metadata=[fg.KeyValuePair(key="airframe", value=name)],
        lines=[fg.LinePrimitive(type=fg.LinePrimitiveLineType.LineList, pose=IDENTITY,
                                thickness=0.02, points=arms, color=fg_color(0.9, 0.9, 0.9))],
        cylinders=cylinders,
        arrows=[fg.ArrowPrimitive(pose=IDENTITY, shaft_length=span, shaft_diameter=0.02,
                                  head_length=0.08, head_diameter=0.06,
                                  color=fg_color(1.0, 0.3, 0.2))])


def mission_entity(stamp: fg.Timestamp, mission: list[list[float]],
                    current: int) -> fg.SceneEntity:
    """Waypoints (the current one larger), their item numbers, and the legs between
    them."""
    spheres, texts = [], []
    for seq, *p in mission:
        size = 0.8 if seq == current else 0.5
        spheres.append(fg.SpherePrimitive(pose=text_pose(p),
                                          size=fg.Vector3(x=size, y=size, z=size),
                                          color=fg_color(1.0, 0.8, 0.1, 0.9)))
        texts.append(fg.TextPrimitive(pose=text_pose((p[0], p[1], p[2] - 0.8)),
                                      billboard=True, font_size=14, scale_invariant=True,
                                      color=fg_color(1, 1, 1), text=str(int(seq))))
    lines = [fg.LinePrimitive(type=fg.LinePrimitiveLineType.LineStrip, pose=IDENTITY,
                              thickness=0.05, points=[fg_point(p[1:]) for p in mission],
                              color=fg_color(1.0, 0.8, 0.1, 0.8))] if len(mission) > 1 else []
    return fg.SceneEntity(timestamp=stamp, frame_id=FRAME_NED, id="mission",
                          spheres=spheres, texts=texts, lines=lines)


def fence_entity(stamp: fg.Timestamp, zones: list[dict[str, Any]]) -> fg.SceneEntity:
    """Each zone as a loop on the ground (inclusion green, exclusion red)."""
    lines = [fg.LinePrimitive(
        type=fg.LinePrimitiveLineType.LineLoop, pose=IDENTITY, thickness=0.08,
        points=[fg.Point3(x=n, y=e, z=0.0) for n, e in z["points"]],
        color=fg_color(0.2, 0.9, 0.2) if z["inclusion"] else fg_color(0.9, 0.2, 0.2))
        for z in zones]
    return fg.SceneEntity(timestamp=stamp, frame_id=FRAME_NED, id="fence", lines=lines)


# -- encoding for MCAP and for JSON channels ----------------------------------------------

def json_schema(message: dict[str, Any]) -> dict[str, Any]:
    """A JSON schema naming every field of a plot-ready record (numbers, nested objects,
    arrays of numbers), so tools list them for plotting."""
    def schema_of(value: Any) -> dict[str, Any]:
        if isinstance(value, dict):
            return {"type": "object", "properties": {k: schema_of(v) for k, v in value.items()}}
        if isinstance(value, bool):
            return {"type": "boolean"}
        if isinstance(value, str):
            return {"type": "string"}
        if isinstance(value, list):
            return {"type": "array", "items": {"type": ["number", "null"]}}
        return {"type": ["number", "null"]}
    return schema_of(message)


@dataclass(frozen=True)
class JsonText:
    """A JSON channel's message already encoded (the bytes ``encode`` gives its record as
    a dict), and the JSON schema of its channel: the controller's record is written from
    a template 50 times a sim second rather than built as a dict and dumped."""

    data: bytes
    schema: dict[str, Any]


def channel_json_schema(message: Any) -> dict[str, Any] | None:
    """The JSON schema of a JSON channel's message; None for a Foxglove schema's."""
    if isinstance(message, JsonText):
        return message.schema
    return json_schema(message) if isinstance(message, dict) else None


def encode(message: Any) -> bytes:
    """The message as its channel carries it: protobuf for Foxglove schemas, JSON else."""
    if isinstance(message, dict):
        return json.dumps(message, allow_nan=False, separators=(",", ":")).encode()
    if isinstance(message, JsonText):
        return message.data
    return message.encode()
