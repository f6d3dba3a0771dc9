"""The MAVLink mission protocol, vehicle side (autopilot/mavlink/mission_protocol.py), over real
UDP sockets with pymavlink on an injected link clock: upload, download, clear and set
current for missions, fences and rally points; every bad upload gets PX4's
MAV_MISSION_RESULT and leaves the stored list as it was; retries and time-outs."""

from __future__ import annotations

import math

import pytest

from autopilot.mavlink.mission_protocol import RETRY_S, TIMEOUT_S
from autopilot.navigator.geofence import zones_from_items
from autopilot.navigator.mission_store import MISSION
from contracts.frames import DEFAULT_HOME
from tests.mavlink_station import T0, M

HOME_LAT, HOME_LON = 47.397742, 8.545594
WAYPOINT, TAKEOFF, LAND = M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND
REL_INT = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def item(seq: int, command: int = WAYPOINT, frame: int = REL_INT, params=(0.0, 1.0, 0.0,
         math.nan), north_m: float = 0.0, east_m: float = 0.0, alt_m: float = 5.0,
         mission_type: int = MISSION):
    lat = HOME_LAT + north_m / 111_320.0
    lon = HOME_LON + east_m / 75_000.0
    return M.MAVLink_mission_item_int_message(1, 1, seq, frame, command, 0, 1, *params,
                                              round(lat * 1e7), round(lon * 1e7), alt_m,
                                              mission_type)


def three_waypoints():
    return [item(0, TAKEOFF, params=(0.0, 0.0, 0.0, math.nan)), item(1, north_m=20.0),
            item(2, LAND, north_m=20.0, alt_m=0.0)]


def of(msgs, kind: str) -> list:
    return [m for m in msgs if m.get_type() == kind]


def upload(station, items, mission_type: int = MISSION, client=None):
    """A tool's upload: MISSION_COUNT, then each item the vehicle asks for. Returns the
    vehicle's MISSION_ACK and the sequence numbers it asked for."""
    c = client or station.client
    c.send(M.MAVLink_mission_count_message(1, 1, len(items), mission_type))
    asked = []
    for _ in range(len(items) + 1):
        msgs = c.sync()
        acks = of(msgs, "MISSION_ACK")
        if acks:
            return acks[0], asked
        (request,) = of(msgs, "MISSION_REQUEST_INT") + of(msgs, "MISSION_REQUEST")
        asked.append(request.seq)
        c.send(items[request.seq])
    raise AssertionError("no MISSION_ACK")


def download(station, mission_type: int = MISSION, legacy: bool = False) -> list:
    c = station.client
    c.send(M.MAVLink_mission_request_list_message(1, 1, mission_type))
    (count,) = of(c.sync(), "MISSION_COUNT")
    got = []
    for seq in range(count.count):
        make = M.MAVLink_mission_request_message if legacy else \
            M.MAVLink_mission_request_int_message
        c.send(make(1, 1, seq, mission_type))
        (msg,) = of(c.sync(), "MISSION_ITEM" if legacy else "MISSION_ITEM_INT")
        got.append(msg)
    c.send(M.MAVLink_mission_ack_message(1, 1, M.MAV_MISSION_ACCEPTED, mission_type))
    c.sync()
    return got


def fields(msg) -> tuple:
    return (msg.seq, msg.frame, msg.command, msg.param1, msg.param2, msg.param3, msg.x,
            msg.y, msg.z, msg.mission_type)


def same(a, b) -> bool:
    return all(x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
               for x, y in zip(fields(a), fields(b), strict=True))


def test_a_mission_goes_up_item_by_item_and_comes_back_the_same(station):
    items = three_waypoints()
    ack, asked = upload(station, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED and asked == [0, 1, 2]
    assert (ack.target_system, ack.target_component) == (255, 190)  # to the sender
    back = download(station)
    assert len(back) == 3 and all(same(a, b) for a, b in zip(items, back, strict=True))
    current = station.server.telemetry(M.MAVLINK_MSG_ID_MISSION_CURRENT)
    assert (current.seq, current.total) == (0, 3)
    assert current.mission_state == M.MISSION_STATE_NOT_STARTED


def test_legacy_float_items_go_up_and_come_back_in_degrees(station):
    legacy = [M.MAVLink_mission_item_message(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                             WAYPOINT, 0, 1, 0.0, 1.0, 0.0, math.nan,
                                             HOME_LAT + 1e-4 * seq, HOME_LON, 5.0, MISSION)
              for seq in range(2)]
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, 2, MISSION))
    (request,) = of(c.sync(), "MISSION_REQUEST_INT")
    c.send(legacy[request.seq])
    (request,) = of(c.sync(), "MISSION_REQUEST")  # it answers in the tool's form
    c.send(legacy[request.seq])
    (ack,) = of(c.sync(), "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_ACCEPTED
    back = download(station, legacy=True)
    # MISSION_ITEM carries float32 degrees: 4e-6 deg (0.4 m) apart near 47 deg, the
    # reason MISSION_ITEM_INT exists.
    assert [m.x for m in back] == pytest.approx([HOME_LAT, HOME_LAT + 1e-4], abs=4e-6)
    assert station.vehicle.mission.lists[MISSION][1].x == pytest.approx(
        (HOME_LAT + 1e-4) * 1e7, abs=40)


# Each bad item, at position 1 of three, and PX4's answer.
BAD_ITEMS = [
    ("an unsupported command", item(1, M.MAV_CMD_NAV_LOITER_TURNS), M.MAV_MISSION_UNSUPPORTED),
    ("a fence vertex in a mission", item(1, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                                          params=(4.0, 0.0, 0.0, 0.0)),
     M.MAV_MISSION_UNSUPPORTED),
    ("a body frame", item(1, frame=M.MAV_FRAME_BODY_FRD), M.MAV_MISSION_UNSUPPORTED_FRAME),
    ("a latitude off the Earth", M.MAVLink_mission_item_int_message(
        1, 1, 1, REL_INT, WAYPOINT, 0, 1, 0.0, 1.0, 0.0, 0.0, 91 * 10**7, 0, 5.0, MISSION),
     M.MAV_MISSION_INVALID_PARAM5_X),
    ("a NaN altitude", item(1, alt_m=math.nan), M.MAV_MISSION_INVALID_PARAM7),
    ("a negative acceptance radius", item(1, params=(0.0, -1.0, 0.0, math.nan)),
     M.MAV_MISSION_INVALID_PARAM2),
    ("a negative hold time", item(1, params=(-2.0, 1.0, 0.0, math.nan)),
     M.MAV_MISSION_INVALID_PARAM1),
    ("an infinite param3", item(1, params=(0.0, 1.0, math.inf, math.nan)),
     M.MAV_MISSION_INVALID_PARAM3),
    ("a yaw of 400 deg", item(1, params=(0.0, 1.0, 0.0, 400.0)), M.MAV_MISSION_INVALID_PARAM4),
    ("a jump past the end", item(1, M.MAV_CMD_DO_JUMP, M.MAV_FRAME_MISSION,
                                 params=(7.0, 1.0, 0.0, 0.0)), M.MAV_MISSION_INVALID_PARAM1),
    ("a negative delay", item(1, M.MAV_CMD_NAV_DELAY, M.MAV_FRAME_MISSION,
                              params=(-1.0, 10.0, 30.0, 0.0)), M.MAV_MISSION_INVALID_PARAM1),
    ("a speed of 50 m/s", item(1, M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION,
                               params=(1.0, 50.0, -1.0, 0.0)), M.MAV_MISSION_INVALID_PARAM2),
]


@pytest.mark.parametrize("what, bad, result", BAD_ITEMS, ids=[b[0] for b in BAD_ITEMS])
def test_a_bad_item_is_refused_with_its_result_and_the_mission_stays(station, what, bad,
                                                                    result):
    assert upload(station, three_waypoints())[0].type == M.MAV_MISSION_ACCEPTED
    before = station.vehicle.mission.lists[MISSION]
    items = three_waypoints()
    items[1] = bad
    ack, asked = upload(station, items)
    assert ack.type == result, (what, ack.type)
    assert asked == [0, 1]  # it stopped there
    assert station.vehicle.mission.lists[MISSION] == before


def test_a_count_too_large_and_a_wrong_sequence(station):
    assert upload(station, three_waypoints())[0].type == M.MAV_MISSION_ACCEPTED
    before = station.vehicle.mission.lists[MISSION]
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, 501, MISSION))
    (ack,) = of(c.sync(), "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_NO_SPACE
    c.send(M.MAVLink_mission_count_message(1, 1, 3, MISSION))
    (request,) = of(c.sync(), "MISSION_REQUEST_INT")
    assert request.seq == 0
    c.send(three_waypoints()[2])  # seq 2 where 0 was asked for
    (ack,) = of(c.sync(), "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_INVALID_SEQUENCE
    assert station.vehicle.mission.lists[MISSION] == before


def test_an_unanswered_request_is_sent_again_then_the_upload_is_cancelled(station):
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, 2, MISSION))
    assert [m.seq for m in of(c.sync(), "MISSION_REQUEST_INT")] == [0]
    station.service(T0 + RETRY_S - 0.01)
    assert not of(c.sync(), "MISSION_REQUEST_INT")
    station.service(T0 + RETRY_S)
    assert [m.seq for m in of(c.sync(), "MISSION_REQUEST_INT")] == [0]
    c.send(three_waypoints()[0])  # answered: the next one
    assert [m.seq for m in of(c.sync(), "MISSION_REQUEST_INT")] == [1]
    c.send(three_waypoints()[0])  # a duplicate: ignored
    assert not of(c.sync(), "MISSION_ACK")
    station.service(T0 + RETRY_S + TIMEOUT_S - 0.01)  # the duplicate was heard at RETRY_S
    assert not of(c.sync(), "MISSION_ACK")
    station.service(T0 + RETRY_S + TIMEOUT_S + 0.01)
    msgs = c.sync()
    (ack,) = of(msgs, "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_OPERATION_CANCELLED
    assert "upload timed out" in of(msgs, "STATUSTEXT")[0].text
    assert station.vehicle.mission.lists[MISSION] == ()


def test_a_second_tool_is_denied_while_one_uploads(station):
    other = station.new_client(sysid=254, compid=190)
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, 3, MISSION))
    c.sync()
    other.send(M.MAVLink_mission_count_message(1, 1, 1, MISSION))
    (ack,) = of(other.sync(), "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_DENIED
    for seq in range(3):
        c.send(three_waypoints()[seq])
        msgs = c.sync()
    assert of(msgs, "MISSION_ACK")[0].type == M.MAV_MISSION_ACCEPTED


def test_fence_and_rally_lists_are_kept_apart_from_the_mission(station):
    fence = [item(i, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, M.MAV_FRAME_GLOBAL_INT,
                  params=(4.0, 0.0, 0.0, 0.0), north_m=n, east_m=e, alt_m=0.0,
                  mission_type=M.MAV_MISSION_TYPE_FENCE)
             for i, (n, e) in enumerate(((50, 50), (50, -50), (-50, -50), (-50, 50)))]
    fence.append(item(4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, M.MAV_FRAME_GLOBAL_INT,
                      params=(5.0, 0.0, 0.0, 0.0), north_m=10, alt_m=0.0,
                      mission_type=M.MAV_MISSION_TYPE_FENCE))
    rally = [item(0, M.MAV_CMD_NAV_RALLY_POINT, params=(0.0, 0.0, 0.0, 0.0), north_m=-10,
                  mission_type=M.MAV_MISSION_TYPE_RALLY)]
    assert upload(station, three_waypoints())[0].type == M.MAV_MISSION_ACCEPTED
    assert upload(station, fence, M.MAV_MISSION_TYPE_FENCE)[0].type == M.MAV_MISSION_ACCEPTED
    assert upload(station, rally, M.MAV_MISSION_TYPE_RALLY)[0].type == M.MAV_MISSION_ACCEPTED
    lists = station.vehicle.mission.lists
    assert [len(lists[t]) for t in (MISSION, M.MAV_MISSION_TYPE_FENCE,
                                    M.MAV_MISSION_TYPE_RALLY)] == [3, 5, 1]
    assert all(same(a, b) for a, b in zip(fence, download(station, M.MAV_MISSION_TYPE_FENCE),
                                          strict=True))
    bad = [item(0, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_FRAME_GLOBAL_INT,
                params=(0.0, 0.0, 0.0, 0.0), mission_type=M.MAV_MISSION_TYPE_FENCE)]
    assert upload(station, bad, M.MAV_MISSION_TYPE_FENCE)[0].type == \
        M.MAV_MISSION_INVALID_PARAM1  # a circle of radius 0 near home
    assert len(lists[M.MAV_MISSION_TYPE_FENCE]) == 5
    # MAVSDK's empty circle (radius 0 at 0, 0) beside a real fence: accepted, stored as
    # sent, no zone.
    empty = M.MAVLink_mission_item_int_message(
        1, 1, 5, M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0, 1,
        0.0, 0.0, 0.0, 0.0, 0, 0, 0.0, M.MAV_MISSION_TYPE_FENCE)
    assert upload(station, [*fence, empty], M.MAV_MISSION_TYPE_FENCE)[0].type == \
        M.MAV_MISSION_ACCEPTED
    assert len(lists[M.MAV_MISSION_TYPE_FENCE]) == 6
    assert len(zones_from_items(lists[M.MAV_MISSION_TYPE_FENCE], DEFAULT_HOME)) == 2
    assert upload(station, fence, M.MAV_MISSION_TYPE_FENCE)[0].type == M.MAV_MISSION_ACCEPTED
    c = station.client
    c.send(M.MAVLink_mission_clear_all_message(1, 1, M.MAV_MISSION_TYPE_FENCE))
    assert of(c.sync(), "MISSION_ACK")[0].type == M.MAV_MISSION_ACCEPTED
    assert lists[M.MAV_MISSION_TYPE_FENCE] == () and len(lists[MISSION]) == 3
    c.send(M.MAVLink_mission_clear_all_message(1, 1, M.MAV_MISSION_TYPE_ALL))
    assert of(c.sync(), "MISSION_ACK")[0].type == M.MAV_MISSION_ACCEPTED
    assert all(not v for v in lists.values())


def test_set_current_and_requests_out_of_range(station):
    upload(station, three_waypoints())
    c = station.client
    c.send(M.MAVLink_mission_set_current_message(1, 1, 2))
    (current,) = of(c.sync(), "MISSION_CURRENT")
    assert (current.seq, current.total) == (2, 3)
    c.send(M.MAVLink_mission_set_current_message(1, 1, 3))
    msgs = c.sync()
    assert not of(msgs, "MISSION_CURRENT") and "no mission item 3" in \
        of(msgs, "STATUSTEXT")[0].text
    assert station.vehicle.mission.current == 2
    c.send(M.MAVLink_mission_request_int_message(1, 1, 3, MISSION))
    (ack,) = of(c.sync(), "MISSION_ACK")
    assert ack.type == M.MAV_MISSION_INVALID_SEQUENCE
    # An empty upload clears the list; the mission survives a mode change meanwhile.
    assert upload(station, [])[0].type == M.MAV_MISSION_ACCEPTED
    assert station.vehicle.mission.lists[MISSION] == ()
    c.send(M.MAVLink_mission_request_list_message(1, 1, MISSION))
    assert of(c.sync(), "MISSION_COUNT")[0].count == 0


def test_local_items_carry_metres_times_1e4_and_come_back_the_same(station):
    """MISSION_ITEM_INT's x, y are metres x 1e4 in local frames (1e-7 deg in global ones)."""
    local = [M.MAVLink_mission_item_int_message(1, 1, 0, M.MAV_FRAME_LOCAL_NED, WAYPOINT, 0, 1,
                                                0.0, 1.0, 0.0, math.nan, 123_456, -78_900,
                                                -5.0, MISSION)]
    assert upload(station, local)[0].type == M.MAV_MISSION_ACCEPTED
    stored = station.vehicle.mission.lists[MISSION][0]
    assert (stored.x, stored.y) == pytest.approx((12.3456, -7.89))
    (back,) = download(station)
    assert (back.x, back.y, back.z) == (123_456, -78_900, -5.0)


def test_do_set_mission_current_and_clear_all_mid_transfer(station):
    upload(station, three_waypoints())
    ack, others = station.client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 1)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert station.vehicle.mission.current == 1 and of(others, "MISSION_CURRENT")[0].seq == 1
    ack, _ = station.client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 9)
    assert ack.result == M.MAV_RESULT_DENIED and station.vehicle.mission.current == 1
    # A tool that clears in the middle of its own upload ends the upload with it.
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, 3, MISSION))
    c.sync()
    c.send(M.MAVLink_mission_clear_all_message(1, 1, MISSION))
    assert of(c.sync(), "MISSION_ACK")[0].type == M.MAV_MISSION_ACCEPTED
    c.send(three_waypoints()[0])
    assert not of(c.sync(), "MISSION_REQUEST_INT")  # no upload goes on
    assert station.vehicle.mission.lists[MISSION] == ()
