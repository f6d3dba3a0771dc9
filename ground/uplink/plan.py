"""QGroundControl ``.plan`` files uploaded with the MAVLink mission protocol as a ground
tool does (``ivfm plan``). Reading a plan is autopilot/navigator/plan_file.py.
"""

from __future__ import annotations

import time

from autopilot.navigator.mission_store import FENCE, MISSION, RALLY, MissionItem
from autopilot.navigator.plan_file import PlanError, read_plan
from contracts.mavlink import mavlink

M = mavlink
__all__ = ["PlanError", "read_plan", "upload"]


def upload(conn, lists: dict[int, tuple[MissionItem, ...]], timeout_s: float = 10.0,
           log=print) -> None:
    """Upload each list over a pymavlink connection to a vehicle whose HEARTBEAT has been
    heard, as a ground tool: MISSION_COUNT, then each item asked for, until MISSION_ACK.
    Raises PlanError with the vehicle's MAV_MISSION_RESULT when it refuses."""
    target = (conn.target_system, conn.target_component or 1)
    for mission_type, items in lists.items():
        conn.mav.mission_count_send(*target, len(items), mission_type)
        deadline = time.monotonic() + timeout_s
        while True:
            msg = conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
                                  blocking=True, timeout=max(0.0, deadline - time.monotonic()))
            if msg is None:
                raise PlanError(f"no answer from the vehicle within {timeout_s:g} s")
            if getattr(msg, "mission_type", MISSION) != mission_type:
                continue
            if msg.get_type() == "MISSION_ACK":
                if msg.type != M.MAV_MISSION_ACCEPTED:
                    name = M.enums["MAV_MISSION_RESULT"][msg.type].name
                    raise PlanError(f"the vehicle refused the {_kind(mission_type)}: {name}")
                log(f"{_kind(mission_type)}: {len(items)} items uploaded")
                break
            item = items[msg.seq]
            conn.mav.mission_item_int_send(
                *target, item.seq, item.frame, item.command, 0, item.autocontinue,
                *item.params, int(item.x), int(item.y), item.z, mission_type)


def _kind(mission_type: int) -> str:
    return {MISSION: "mission", FENCE: "fence", RALLY: "rally points"}[mission_type]
