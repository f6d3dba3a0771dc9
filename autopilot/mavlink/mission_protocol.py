"""The MAVLink mission protocol, vehicle side, as PX4 runs it (docs/missions.md): upload
(MISSION_COUNT, then MISSION_REQUEST_INT / MISSION_ITEM_INT item by item, MISSION_ACK),
download (MISSION_REQUEST_LIST, MISSION_COUNT, MISSION_REQUEST_INT / MISSION_ITEM_INT, the
tool's MISSION_ACK), MISSION_CLEAR_ALL and MISSION_SET_CURRENT, for the mission, fence and
rally lists; legacy float MISSION_ITEM / MISSION_REQUEST too.

The ArduPilot flavour numbers and asks as ArduPilot Copter does (GCS_MAVLink's
MissionItemProtocol, AP_Mission): home is item 0 of the mission list (telemetry.home_items:
an empty mission downloads with count 1, the stored item k is the tools' k + 1, DO_JUMP
targets too); an upload's item 0 is checked and dropped (Copter reads home back from its
position estimate, never from the upload); uploads are asked with MISSION_REQUEST, which a
tool answers with MISSION_ITEM or MISSION_ITEM_INT; a complete upload says "Flight plan
received".

One transfer at a time. An upload stores nothing until its last item is in and every
item passed ``check_item``; any failure acknowledges with its MAV_MISSION_RESULT and
leaves the stored list as it was. A request is sent again after RETRY_S without an
answer, and a transfer silent for TIMEOUT_S is cancelled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from autopilot.mavlink.guided import ALTITUDE_CHANGE, GUIDED_GO_TO, GuidedItems
from autopilot.mavlink.telemetry import home_items, mission_current, stored_seq
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
    from contracts.frames import Home

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
    home: int = 0  # items before the stored list on the wire (telemetry.home_items)
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


def home_item(home: Home) -> MissionItem:
    """Item 0 of an ArduPilot mission: a waypoint at home, altitude above mean sea level
    (MAV_FRAME_GLOBAL), as AP_Mission reads it back."""
    return MissionItem(0, M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_WAYPOINT, 0, 1,
                       (0.0, 0.0, 0.0, 0.0), home.lat_deg * 1e7, home.lon_deg * 1e7,
                       home.alt_amsl_m)


def renumbered(item: MissionItem, shift: int) -> MissionItem:
    """The item ``shift`` places on: its seq and, for DO_JUMP, its target (stored lists
    are numbered from 0; an ArduPilot tool's from 1, after home)."""
    if shift == 0:
        return item
    params = item.params
    if item.command == M.MAV_CMD_DO_JUMP:
        params = (params[0] + shift, *params[1:])
    return replace(item, seq=item.seq + shift, params=params)


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
        make = M.MAVLink_mission_request_message if t.legacy or \
            self.server.flavour == "ardupilot" else M.MAVLink_mission_request_int_message
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
        home = home_items(self.server.flavour, mission_type)
        if msg.count - home > MAX_ITEMS[mission_type]:
            self._ack(link, address, _partner(msg), M.MAV_MISSION_NO_SPACE, mission_type)
            self._say(link, address, f"mission: {msg.count} items, at most "
                                     f"{MAX_ITEMS[mission_type]}")
            return
        self.transfer = None  # a new count restarts an upload from this tool
        if msg.count == 0:
            self.store.replace(mission_type, ())
            if home:  # Copter: an empty upload is a complete one
                self.server.send_text(link, M.MAV_SEVERITY_INFO, "Flight plan received",
                                      address)
            self._ack(link, address, _partner(msg), M.MAV_MISSION_ACCEPTED, mission_type)
            return
        self.transfer = Transfer(link, address, _partner(msg), mission_type, msg.count,
                                 upload=True, heard_s=now, home=home)
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
        try:
            item = self._checked(item_from_message(msg, t.legacy), t)
        except ItemError as exc:
            self._say(link, address, f"mission: {exc}")
            self._end(exc.result)
            return
        t.items.append(item)
        if len(t.items) < t.count:
            self._ask(t, now)
            return
        self.store.replace(t.mission_type, tuple(t.items[t.home:]))
        if t.home:
            self.server.send_text(link, M.MAV_SEVERITY_INFO, "Flight plan received", address)
        self._end(M.MAV_MISSION_ACCEPTED)

    def _checked(self, item: MissionItem, t: Transfer) -> MissionItem:
        """The item as stored, once it passed check_item (raises ItemError). An ArduPilot
        upload's home item is checked as it came and dropped later; the others are
        numbered from 0, as stored (a DO_JUMP to home is Copter's MAV_MISSION_ERROR);
        an ArduPilot mission takes Copter's yaw and ROI items too."""
        ardupilot = self.server.flavour == "ardupilot"
        if item.seq < t.home:
            check_item(item, t.count, ardupilot)
            return item
        if item.command == M.MAV_CMD_DO_JUMP and item.params[0] < t.home:
            raise ItemError(M.MAV_MISSION_ERROR, f"item {item.seq}: DO_JUMP to home")
        stored = renumbered(item, -t.home)
        try:
            check_item(stored, t.count - t.home, ardupilot)
        except ItemError as exc:  # said in the tool's numbering
            raise ItemError(exc.result, f"item {item.seq}:" + str(exc).split(":", 1)[1]) \
                from None
        return stored

    # -- download --------------------------------------------------------------------------
    def on_request_list(self, link, address, msg, now: float) -> None:
        mission_type = self._start(link, address, msg, MISSION_TYPES)
        if mission_type is None:
            return
        count = len(self.store.lists[mission_type]) + home_items(self.server.flavour,
                                                                 mission_type)
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
        home = home_items(self.server.flavour, mission_type)
        if not 0 <= msg.seq < len(items) + home:
            if home:  # Copter tells the tool the mission's length, then refuses
                self.server.send(link, M.MAVLink_mission_count_message(
                    *_partner(msg), len(items) + home, mission_type), address)
            self._ack(link, address, _partner(msg), M.MAV_MISSION_ERROR if home else
                      M.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        if t is not None:
            t.heard_s = now
        item = home_item(self.server.vehicle.places.home) if msg.seq < home else \
            renumbered(items[msg.seq - home], home)
        self.server.send(link, item_message(item, _partner(msg),
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
        flavour = self.server.flavour
        try:
            self.store.set_current(stored_seq(flavour, msg.seq))
        except ItemError as exc:
            self._say(link, address, f"mission: {exc}")
            return
        self.server.send(link, mission_current(self.server.vehicle, flavour), address)

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

