"""The MAVLink mission protocol, vehicle side, as PX4 runs it (docs/missions.md): upload
(MISSION_COUNT, then MISSION_REQUEST_INT / MISSION_ITEM_INT item by item, MISSION_ACK),
download (MISSION_REQUEST_LIST, MISSION_COUNT, MISSION_REQUEST_INT / MISSION_ITEM_INT, the
tool's MISSION_ACK), MISSION_CLEAR_ALL and MISSION_SET_CURRENT, for the mission, fence and
rally lists; legacy float MISSION_ITEM / MISSION_REQUEST too.

One transfer at a time. An upload stores nothing until its last item is in and every
item passed ``check_item``; any failure acknowledges with its MAV_MISSION_RESULT and
leaves the stored list as it was. A request is sent again after RETRY_S without an
answer, and a transfer silent for TIMEOUT_S is cancelled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from autopilot.mavlink.guided import ALTITUDE_CHANGE, GUIDED_GO_TO, GuidedItems
from autopilot.mavlink.telemetry import mission_current
from autopilot.navigator.mission_store import (
    MAX_ITEMS,
    MISSION,
    MISSION_TYPES,
    ItemError,
    MissionItem,
    check_item,
)
from contracts.mavlink import GLOBAL_FRAMES, mavlink

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink

M = mavlink
RETRY_S = 0.25  # PX4's MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT
TIMEOUT_S = 5.0  # PX4's MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT


@dataclass
class Transfer:
    link: GroundLink
    address: tuple[str, int] | None
    partner: tuple[int, int]  # the tool's system and component
    mission_type: int
    count: int
    upload: bool
    legacy: bool = False  # the tool speaks float MISSION_ITEM / MISSION_REQUEST
    items: list[MissionItem] = field(default_factory=list)
    heard_s: float = 0.0
    asked_s: float = 0.0


def item_from_message(msg, legacy: bool) -> MissionItem:
    """A MissionItem of MISSION_ITEM_INT, or of a float MISSION_ITEM (global positions in
    degrees, turned into the integer form's 1e-7 deg)."""
    x, y = float(msg.x), float(msg.y)
    frame = msg.frame
    is_global = frame in GLOBAL_FRAMES
    if legacy and is_global:
        x, y = x * 1e7, y * 1e7
    elif not legacy and not is_global:
        x, y = x * 1e-4, y * 1e-4  # MISSION_ITEM_INT carries local metres x 1e4
    return MissionItem(msg.seq, frame, msg.command, msg.current, msg.autocontinue,
                       (float(msg.param1), float(msg.param2), float(msg.param3),
                        float(msg.param4)), x, y, float(msg.z),
                       getattr(msg, "mission_type", MISSION))


def item_message(item: MissionItem, partner: tuple[int, int], legacy: bool):
    """MISSION_ITEM_INT (or, to a legacy request, MISSION_ITEM) of a stored item; the
    integer form carries global positions in 1e-7 deg and local ones in metres x 1e4."""
    if legacy:
        scale = 1e-7 if item.is_global else 1.0
        return M.MAVLink_mission_item_message(
            *partner, item.seq, item.frame, item.command, item.current, item.autocontinue,
            *item.params, item.x * scale, item.y * scale, item.z, item.mission_type)
    return M.MAVLink_mission_item_int_message(
        *partner, item.seq, item.frame, item.command, item.current, item.autocontinue,
        *item.params, *(int(round(v * (1.0 if item.is_global else 1e4)))
                        for v in (item.x, item.y)), item.z, item.mission_type)


class MissionProtocol:
    def __init__(self, server: ServerLink) -> None:
        self.server = server
        self.store = server.vehicle.mission
        self.transfer: Transfer | None = None
        # Copter's flavour: an item with current=2 / 3 is a GUIDED request (guided.py).
        self.guided = GuidedItems(server) if server.vehicle.personality.guided_requests \
            else None

    def handlers(self) -> dict[str, Callable]:
        return {"MISSION_COUNT": self.on_count, "MISSION_ITEM_INT": self.on_item,
                "MISSION_ITEM": self.on_item, "MISSION_REQUEST_LIST": self.on_request_list,
                "MISSION_REQUEST_INT": self.on_request, "MISSION_REQUEST": self.on_request,
                "MISSION_ACK": self.on_ack, "MISSION_CLEAR_ALL": self.on_clear_all,
                "MISSION_SET_CURRENT": self.on_set_current}

    # -- helpers ---------------------------------------------------------------------------
    def _ack(self, link, address, partner: tuple[int, int], result: int,
             mission_type: int) -> None:
        self.server.send(link, M.MAVLink_mission_ack_message(*partner, result, mission_type),
                         address)

    def _say(self, link, address, text: str) -> None:
        self.server.send_text(link, 4, text, address)

    def _busy(self, link, address, msg) -> bool:
        """Another tool's transfer is under way: this one is denied."""
        t = self.transfer
        if t is None or (t.link is link and t.partner == _partner(msg)):
            return False
        self._ack(link, address, _partner(msg), M.MAV_MISSION_DENIED,
                  getattr(msg, "mission_type", MISSION))
        return True

    def _start(self, link, address, msg, types: tuple[int, ...]) -> int | None:
        """The mission type a tool's COUNT, REQUEST_LIST or CLEAR_ALL is about, or None
        when it has been answered already: DENIED (another tool's transfer is under way)
        or UNSUPPORTED (a type not in ``types``)."""
        if self._busy(link, address, msg):
            return None
        mission_type = getattr(msg, "mission_type", MISSION)
        if mission_type not in types:
            self._ack(link, address, _partner(msg), M.MAV_MISSION_UNSUPPORTED, mission_type)
            return None
        return mission_type

    def _ask(self, t: Transfer, now: float) -> None:
        seq = len(t.items)
        make = M.MAVLink_mission_request_message if t.legacy else \
            M.MAVLink_mission_request_int_message
        self.server.send(t.link, make(*t.partner, seq, t.mission_type), t.address)
        t.asked_s = now

    def _end(self, result: int | None = None) -> None:
        t, self.transfer = self.transfer, None
        if result is not None and t is not None:
            self._ack(t.link, t.address, t.partner, result, t.mission_type)

    # -- upload ----------------------------------------------------------------------------
    def on_count(self, link, address, msg, now: float) -> None:
        mission_type = self._start(link, address, msg, MISSION_TYPES)
        if mission_type is None:
            return
        if msg.count > MAX_ITEMS[mission_type]:
            self._ack(link, address, _partner(msg), M.MAV_MISSION_NO_SPACE, mission_type)
            self._say(link, address, f"mission: {msg.count} items, at most "
                                     f"{MAX_ITEMS[mission_type]}")
            return
        self.transfer = None  # a new count restarts an upload from this tool
        if msg.count == 0:
            self.store.replace(mission_type, ())
            self._ack(link, address, _partner(msg), M.MAV_MISSION_ACCEPTED, mission_type)
            return
        self.transfer = Transfer(link, address, _partner(msg), mission_type, msg.count,
                                 upload=True, heard_s=now)
        self._ask(self.transfer, now)

    def on_item(self, link, address, msg, now: float) -> None:
        if self.guided is not None and msg.current in (GUIDED_GO_TO, ALTITUDE_CHANGE) and \
                getattr(msg, "mission_type", MISSION) == MISSION:
            self.guided.on_item(link, address, msg, now)
            return
        t = self.transfer
        if t is None or not t.upload or t.link is not link or t.partner != _partner(msg):
            return  # not ours to take (a late duplicate, or another tool's)
        t.legacy = msg.get_type() == "MISSION_ITEM"
        t.heard_s = now
        expected = len(t.items)
        if msg.seq < expected:
            return  # a duplicate of one we have: our next request is on its way
        if msg.seq > expected or getattr(msg, "mission_type", MISSION) != t.mission_type:
            self._say(link, address, f"mission: item {msg.seq}, expected {expected}")
            self._end(M.MAV_MISSION_INVALID_SEQUENCE)
            return
        item = item_from_message(msg, t.legacy)
        try:
            check_item(item, t.count)
        except ItemError as exc:
            self._say(link, address, f"mission: {exc}")
            self._end(exc.result)
            return
        t.items.append(item)
        if len(t.items) < t.count:
            self._ask(t, now)
            return
        self.store.replace(t.mission_type, tuple(t.items))
        self._end(M.MAV_MISSION_ACCEPTED)

    # -- download --------------------------------------------------------------------------
    def on_request_list(self, link, address, msg, now: float) -> None:
        mission_type = self._start(link, address, msg, MISSION_TYPES)
        if mission_type is None:
            return
        count = len(self.store.lists[mission_type])
        self.transfer = Transfer(link, address, _partner(msg), mission_type, count,
                                 upload=False, heard_s=now) if count else None
        self.server.send(link, M.MAVLink_mission_count_message(*_partner(msg), count,
                                                               mission_type), address)

    def on_request(self, link, address, msg, now: float) -> None:
        t = self.transfer
        if t is not None and t.upload:
            return  # we ask during an upload; a tool does not
        mission_type = getattr(msg, "mission_type", MISSION)
        items = self.store.lists.get(mission_type, ())
        if not 0 <= msg.seq < len(items):
            self._ack(link, address, _partner(msg), M.MAV_MISSION_INVALID_SEQUENCE,
                      mission_type)
            return
        if t is not None:
            t.heard_s = now
        self.server.send(link, item_message(items[msg.seq], _partner(msg),
                                            msg.get_type() == "MISSION_REQUEST"), address)

    def on_ack(self, link, address, msg, now: float) -> None:
        t = self.transfer
        if t is not None and not t.upload and t.link is link and t.partner == _partner(msg):
            self.transfer = None  # the tool has the whole list

    # -- the rest ----------------------------------------------------------------------------
    def on_clear_all(self, link, address, msg, now: float) -> None:
        mission_type = self._start(link, address, msg,
                                   (*MISSION_TYPES, M.MAV_MISSION_TYPE_ALL))
        if mission_type is None:
            return
        self.transfer = None  # the tool's own transfer, if any, ends with the lists
        self.store.clear(mission_type)
        self._ack(link, address, _partner(msg), M.MAV_MISSION_ACCEPTED, mission_type)

    def on_set_current(self, link, address, msg, now: float) -> None:
        try:
            self.store.set_current(msg.seq)
        except ItemError as exc:
            self._say(link, address, f"mission: {exc}")
            return
        self.server.send(link, mission_current(self.server.vehicle), address)

    def service(self, now: float) -> None:
        """Ask again for an item not answered within RETRY_S; cancel a silent transfer."""
        t = self.transfer
        if t is None:
            return
        if now - t.heard_s > TIMEOUT_S:
            if t.upload:
                self._say(t.link, t.address, "mission: upload timed out")
                self._end(M.MAV_MISSION_OPERATION_CANCELLED)
            else:  # many tools never acknowledge a download: it just ends
                self._end()
        elif t.upload and now - t.asked_s >= RETRY_S:
            self._ask(t, now)


def _partner(msg) -> tuple[int, int]:
    return msg.get_srcSystem(), msg.get_srcComponent()

