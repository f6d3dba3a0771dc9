"""The mission protocol as ArduPilot Copter runs it (``--flavour ardupilot``), over real UDP
sockets with pymavlink: home is item 0 of the mission list, uploads are asked with
MISSION_REQUEST and answered with either item form, the stored mission is numbered from
1 on the wire (DO_JUMP targets, MISSION_CURRENT, MISSION_ITEM_REACHED, set-current), and
Copter's answers to what it refuses. The PX4 flavour's protocol is
tests/autopilot/test_mission_protocol.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import FENCE, MISSION
from tests.autopilot.test_mission_protocol import (
    HOME_LAT,
    HOME_LON,
    LAND,
    REL_INT,
    TAKEOFF,
    WAYPOINT,
    download,
    fields,
    item,
    of,
)
from tests.mavlink_station import M, texts


@pytest.fixture
def copter(make_station):
    return make_station(flavour="ardupilot")


def home_item_as_tools_send_it():
    """What MAVProxy's ``wp load`` and DroneKit send as item 0: a waypoint at home, AMSL."""
    return M.MAVLink_mission_item_int_message(
        1, 1, 0, M.MAV_FRAME_GLOBAL_INT, WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
        round(HOME_LAT * 1e7), round(HOME_LON * 1e7), 488.0, MISSION)


def mission_with_home():
    return [home_item_as_tools_send_it(), item(1, TAKEOFF, params=(0.0, 0.0, 0.0, math.nan)),
            item(2, north_m=20.0), item(3, LAND, north_m=20.0, alt_m=0.0)]


def upload(station, items, mission_type: int = MISSION, legacy_answers: bool = False):
    """A tool's upload answering what the vehicle asks; returns the ACK, the requests'
    message types and sequence numbers, and the texts said."""
    c = station.client
    c.send(M.MAVLink_mission_count_message(1, 1, len(items), mission_type))
    asked, said = [], []
    for _ in range(len(items) + 1):
        msgs = c.sync()
        said += texts(msgs)
        acks = of(msgs, "MISSION_ACK")
        if acks:
            return acks[0], asked, said
        (request,) = of(msgs, "MISSION_REQUEST_INT") + of(msgs, "MISSION_REQUEST")
        asked.append((request.get_type(), request.seq))
        c.send(items[request.seq])
    raise AssertionError("no MISSION_ACK")


def test_an_empty_mission_downloads_as_home_alone(copter):
    (home,) = download(copter)
    assert (home.seq, home.frame, home.command) == (0, M.MAV_FRAME_GLOBAL, WAYPOINT)
    h = copter.vehicle.places.home
    assert (home.x, home.y) == (round(h.lat_deg * 1e7), round(h.lon_deg * 1e7))
    assert home.z == pytest.approx(h.alt_amsl_m, abs=1e-3)  # above sea level, not home
    (home_legacy,) = download(copter, legacy=True)  # MISSION_REQUEST gets MISSION_ITEM
    assert home_legacy.x == pytest.approx(h.lat_deg, abs=4e-6)  # float32 degrees


def test_an_upload_is_asked_with_mission_request_and_item_0_is_dropped(copter):
    items = mission_with_home()
    ack, asked, said = upload(copter, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert asked == [("MISSION_REQUEST", seq) for seq in range(4)]  # as Copter asks
    assert said == ["Flight plan received"]
    stored = copter.vehicle.mission.lists[MISSION]
    assert [(i.seq, i.command) for i in stored] == [(0, TAKEOFF), (1, WAYPOINT), (2, LAND)]
    back = download(copter)
    assert [m.seq for m in back] == [0, 1, 2, 3]
    assert [fields(a)[1:] for a in back[1:]] == [fields(b)[1:] for b in items[1:]]
    assert back[0].z == pytest.approx(copter.vehicle.places.home.alt_amsl_m, abs=1e-3)
    current = copter.server.telemetry(M.MAVLINK_MSG_ID_MISSION_CURRENT)
    assert (current.seq, current.total) == (1, 3)  # the first item after home; the last is 3


def test_a_home_item_elsewhere_does_not_move_home(copter):
    before = copter.vehicle.places
    items = mission_with_home()
    items[0] = M.MAVLink_mission_item_int_message(
        1, 1, 0, M.MAV_FRAME_GLOBAL_INT, WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
        round((HOME_LAT + 0.01) * 1e7), round(HOME_LON * 1e7), 600.0, MISSION)
    assert upload(copter, items)[0].type == M.MAV_MISSION_ACCEPTED
    assert copter.vehicle.places == before
    assert download(copter)[0].x == round(before.home.lat_deg * 1e7)


def test_float_items_are_taken_in_degrees(copter):
    legacy = [M.MAVLink_mission_item_message(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                             WAYPOINT, 0, 1, 0.0, 1.0, 0.0, math.nan,
                                             HOME_LAT + 1e-4 * seq, HOME_LON, 5.0, MISSION)
              for seq in range(3)]
    ack, asked, _ = upload(copter, legacy)
    assert ack.type == M.MAV_MISSION_ACCEPTED and len(asked) == 3
    stored = copter.vehicle.mission.lists[MISSION]
    # float32 degrees: 4e-6 deg apart near 47 deg
    assert [i.x for i in stored] == pytest.approx(
        [(HOME_LAT + 1e-4) * 1e7, (HOME_LAT + 2e-4) * 1e7], abs=40)


def test_do_jump_targets_are_numbered_after_home(copter):
    items = mission_with_home()
    items.insert(3, item(3, M.MAV_CMD_DO_JUMP, M.MAV_FRAME_MISSION, params=(2.0, 1.0, 0.0, 0.0)))
    items = [M.MAVLink_mission_item_int_message(
        1, 1, seq, m.frame, m.command, 0, 1, m.param1, m.param2, m.param3, m.param4, m.x, m.y,
        m.z, MISSION) for seq, m in enumerate(items)]
    assert upload(copter, items)[0].type == M.MAV_MISSION_ACCEPTED
    jump = copter.vehicle.mission.lists[MISSION][2]
    assert (jump.command, jump.params[0]) == (M.MAV_CMD_DO_JUMP, 1.0)  # stored from 0
    assert download(copter)[3].param1 == 2.0  # and said from 1 again


def test_copter_refusals_leave_the_mission_as_it_was(copter):
    assert upload(copter, mission_with_home())[0].type == M.MAV_MISSION_ACCEPTED
    before = copter.vehicle.mission.lists[MISSION]
    to_home = mission_with_home()
    to_home[2] = item(2, M.MAV_CMD_DO_JUMP, M.MAV_FRAME_MISSION, params=(0.0, 1.0, 0.0, 0.0))
    ack, _, said = upload(copter, to_home)
    assert ack.type == M.MAV_MISSION_ERROR  # a jump to home, as Copter answers it
    assert said == ["mission: item 2: DO_JUMP to home"]
    bad = mission_with_home()
    bad[2] = item(2, alt_m=math.nan)
    ack, _, said = upload(copter, bad)
    assert ack.type == M.MAV_MISSION_INVALID_PARAM7
    assert said == ["mission: item 2: altitude nan m"]  # in the tool's numbering
    bad_home = mission_with_home()
    bad_home[0] = item(0, frame=M.MAV_FRAME_BODY_FRD)
    assert upload(copter, bad_home)[0].type == M.MAV_MISSION_UNSUPPORTED_FRAME
    assert copter.vehicle.mission.lists[MISSION] is before


def test_an_item_past_the_end_is_answered_with_the_count_then_an_error(copter):
    assert upload(copter, mission_with_home())[0].type == M.MAV_MISSION_ACCEPTED
    c = copter.client
    c.send(M.MAVLink_mission_request_int_message(1, 1, 4, MISSION))
    msgs = c.sync()
    assert [m.count for m in of(msgs, "MISSION_COUNT")] == [4]
    assert [m.type for m in of(msgs, "MISSION_ACK")] == [M.MAV_MISSION_ERROR]


def test_set_current_and_reached_are_numbered_after_home(copter):
    assert upload(copter, mission_with_home())[0].type == M.MAV_MISSION_ACCEPTED
    c = copter.client
    c.send(M.MAVLink_mission_set_current_message(1, 1, 2))
    (current,) = of(c.sync(), "MISSION_CURRENT")
    assert copter.vehicle.mission.current == 1 and current.seq == 2
    c.send(M.MAVLink_mission_set_current_message(1, 1, 0))  # home: the mission's start
    (current,) = of(c.sync(), "MISSION_CURRENT")
    assert copter.vehicle.mission.current == 0 and current.seq == 1
    copter.vehicle.reached.append(1)  # the runner reached stored item 1
    copter.service()
    assert [m.seq for m in of(c.sync(), "MISSION_ITEM_REACHED")] == [2]


def test_fences_have_no_home_item(copter):
    vertices = [item(seq, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, params=(3.0, 0, 0, 0),
                     north_m=30.0 * (seq == 1), east_m=30.0 * (seq == 2), mission_type=FENCE)
                for seq in range(3)]
    ack, asked, said = upload(copter, vertices, FENCE)
    assert ack.type == M.MAV_MISSION_ACCEPTED and said == []
    assert [seq for _, seq in asked] == [0, 1, 2]
    assert len(download(copter, FENCE)) == 3
    assert copter.vehicle.mission.lists[MISSION] == ()


def test_the_px4_flavour_keeps_its_numbering(station):
    items = [item(0, TAKEOFF, params=(0.0, 0.0, 0.0, math.nan)), item(1, north_m=20.0)]
    ack, asked, said = upload(station, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED and said == []
    assert asked == [("MISSION_REQUEST_INT", 0), ("MISSION_REQUEST_INT", 1)]
    back = download(station)
    assert [(m.seq, m.command, m.frame) for m in back] == [(0, TAKEOFF, REL_INT),
                                                          (1, WAYPOINT, REL_INT)]


# -- Copter's yaw and ROI items ------------------------------------------------------------
CONDITION_YAW, ROI_LOCATION, ROI_NONE = (M.MAV_CMD_CONDITION_YAW, M.MAV_CMD_DO_SET_ROI_LOCATION,
                                         M.MAV_CMD_DO_SET_ROI_NONE)


def yaw_item(seq: int, params) -> object:
    return M.MAVLink_mission_item_int_message(1, 1, seq, M.MAV_FRAME_MISSION, CONDITION_YAW, 0,
                                              1, *params, 0, 0, 0.0, MISSION)


def test_copter_yaw_and_roi_items_are_taken_in_the_ardupilot_flavour_only(copter, station):
    items = mission_with_home()[:3] + [
        yaw_item(3, (90.0, 20.0, 1.0, 0.0)), item(4, ROI_LOCATION, params=(0, 0, 0, 0),
                                                  east_m=30.0),
        M.MAVLink_mission_item_int_message(1, 1, 5, M.MAV_FRAME_MISSION, ROI_NONE, 0, 1,
                                           0, 0, 0, 0, 0, 0, 0.0, MISSION),
        item(6, M.MAV_CMD_DO_SET_ROI, params=(0, 0, 0, 0), east_m=10.0)]
    ack, _, _ = upload(copter, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert [i.command for i in copter.vehicle.mission.lists[MISSION][2:]] == [
        CONDITION_YAW, ROI_LOCATION, ROI_NONE, M.MAV_CMD_DO_SET_ROI]
    # PX4 takes what it took: a CONDITION_YAW is refused, the mission stays empty.
    px4 = [item(0, TAKEOFF, params=(0.0, 0.0, 0.0, math.nan)),
           M.MAVLink_mission_item_int_message(1, 1, 1, M.MAV_FRAME_MISSION, CONDITION_YAW, 0,
                                              1, 90.0, 0.0, 0.0, 0.0, 0, 0, 0.0, MISSION)]
    ack, _, said = upload(station, px4)
    assert ack.type == M.MAV_MISSION_UNSUPPORTED and station.vehicle.mission.lists[MISSION] == ()


@pytest.mark.parametrize(("params", "result"), [
    ((400.0, 0.0, 0.0, 0.0), M.MAV_MISSION_INVALID_PARAM1),
    ((math.nan, 0.0, 0.0, 0.0), M.MAV_MISSION_INVALID_PARAM1),
    ((90.0, -5.0, 0.0, 0.0), M.MAV_MISSION_INVALID_PARAM2),
    ((90.0, 0.0, 2.0, 0.0), M.MAV_MISSION_INVALID_PARAM3),
    ((90.0, 0.0, 0.0, 0.5), M.MAV_MISSION_INVALID_PARAM4),
])
def test_a_bad_condition_yaw_is_refused(copter, params, result):
    items = mission_with_home()[:2] + [yaw_item(2, params)]
    ack, _, said = upload(copter, items)
    assert ack.type == result and copter.vehicle.mission.lists[MISSION] == ()
    assert said and said[0].startswith("mission: item 2: ")


def _runner(items):
    from autopilot.navigator.mission_runner import MissionRunner
    from autopilot.parameters import default_parameters
    from contracts.frames import DEFAULT_HOME

    return MissionRunner(tuple(items), default_parameters(), Places.at(DEFAULT_HOME))


# Headings to points placed by latitude and longitude (1e-7 deg, 1 cm, of rounding, and the
# projection's round trip): within 1e-5 rad at 20 m, 1e-4 rad for the ROI's.
def test_condition_yaw_turns_during_the_leg_before_it_until_the_next_waypoint():
    from tests.flight import do_item, mission_item

    runner = _runner([mission_item(0, 20.0, 0.0, 5.0), do_item(1, CONDITION_YAW,
                                                               (90.0, 0.0, 0.0, 0.0)),
                      mission_item(2, 20.0, 20.0, 5.0)])
    here = np.array([0.0, 0.0, -5.0])
    runner.start(0, here, 0.0, False, 2.5)
    goal = runner.step(0.0, here, here)
    assert goal.setpoint.yaw_rad == pytest.approx(math.pi / 2, abs=1e-5)  # east, not facing north
    relative = _runner([mission_item(0, 20.0, 0.0, 5.0), do_item(1, CONDITION_YAW,
                                                                 (30.0, 0.0, -1.0, 1.0))])
    relative.start(0, here, 0.0, False, 2.5)
    assert relative.step(0.0, here, here).setpoint.yaw_rad == pytest.approx(-math.pi / 6, abs=1e-5)
    there = np.array([20.0, 0.0, -5.0])  # at the first waypoint: the next leg faces east
    for t in np.arange(0.01, 5.0, 0.01):
        goal = runner.step(t, there, there)
        if runner.seq == 2:
            break
    assert runner.seq == 2 and goal.setpoint.yaw_rad == pytest.approx(math.pi / 2, abs=1e-5)
    runner.step(5.0, there, there)


def test_a_region_of_interest_holds_the_nose_across_legs_until_roi_none():
    """As AP_Mission runs them, the do items after a waypoint run during the leg to it:
    the ROI after WP1 holds on the legs to WP1 and WP2; the ROI_NONE after WP3 ends it
    on the leg to WP3, which faces its way again."""
    from contracts.frames import DEFAULT_HOME
    from tests.flight import do_item, mission_item

    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(0.0, 30.0, 0.0)
    runner = _runner([mission_item(0, 20.0, 0.0, 5.0), MissionItem_at(1, ROI_LOCATION, lat, lon),
                      mission_item(2, 20.0, -20.0, 5.0), mission_item(3, 0.0, -20.0, 5.0),
                      do_item(4, ROI_NONE, (0, 0, 0, 0)), mission_item(5, 0.0, 0.0, 5.0)])
    here = np.array([0.0, 0.0, -5.0])
    runner.start(0, here, 0.0, False, 2.5)
    assert runner.step(0.0, here, here).setpoint.yaw_rad == pytest.approx(math.pi / 2, abs=1e-4)
    midway = np.array([10.0, 0.0, -5.0])
    assert runner.step(0.01, midway, midway).setpoint.yaw_rad == pytest.approx(
        math.atan2(30.0, -10.0), abs=1e-4)

    def fly_to(position, seq: int, t0: float):
        for t in np.arange(t0, t0 + 5.0, 0.01):
            goal = runner.step(t, position, position)
            if runner.seq == seq:
                return goal
        raise AssertionError(f"item {seq} not begun")

    goal = fly_to(np.array([20.0, 0.0, -5.0]), 2, 0.02)
    assert goal.setpoint.yaw_rad == pytest.approx(math.atan2(30.0, -20.0), abs=1e-4)  # ROI
    goal = fly_to(np.array([20.0, -20.0, -5.0]), 3, 5.0)
    assert abs(goal.setpoint.yaw_rad) == pytest.approx(math.pi, abs=1e-4)  # south: no ROI


def MissionItem_at(seq: int, command: int, lat_deg: float, lon_deg: float):  # noqa: N802
    from autopilot.navigator.mission_store import MissionItem

    return MissionItem(seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 1,
                       (0.0, 0.0, 0.0, 0.0), round(lat_deg * 1e7), round(lon_deg * 1e7), 5.0)


def test_a_waypoint_at_latitude_and_longitude_0_is_here_in_copter_missions_only():
    from dataclasses import replace

    from autopilot.navigator.mission_runner import MissionRunner
    from autopilot.parameters import default_parameters
    from contracts.frames import DEFAULT_HOME
    from tests.flight import mission_item

    here = np.array([7.0, -3.0, -5.0])
    zero = replace(MissionItem_at(0, M.MAV_CMD_NAV_WAYPOINT, 0.0, 0.0), z=12.0)
    items = (mission_item(0, 7.0, -3.0, 5.0), zero)
    for copter, expected_ne in ((True, (7.0, -3.0)), (False, None)):
        runner = MissionRunner(items, default_parameters(), Places.at(DEFAULT_HOME),
                               zero_latlon_is_here=copter)
        runner.start(1, here, 0.0, False, 2.5)
        goal = runner.step(0.0, here, here)
        target = goal.setpoint.position_ned_m
        assert target[2] == pytest.approx(-12.0)  # its own altitude above home, both ways
        if copter:
            assert tuple(target[:2]) == pytest.approx(expected_ne)
        else:  # PX4: latitude 0, longitude 0 is a place (thousands of km away)
            assert math.hypot(*target[:2]) > 1e6


def test_the_ardupilot_flavour_flies_position_items_at_0_0_where_it_is(make_station):
    assert make_station(flavour="ardupilot").vehicle.navigator.copter_rules
    assert not make_station().vehicle.navigator.copter_rules


def test_auto_armed_on_the_ground_needs_a_take_off_first_as_copter(make_station):
    """Copter refuses AUTO armed on the ground unless the next position item is a take-off
    ("Auto: Missing Takeoff Cmd"); disarmed it may be selected. PX4 climbs first instead."""
    from tests.mavlink_station import ACCEPTED, ARM

    SET_MODE = M.MAV_CMD_DO_SET_MODE

    custom = float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    copter = make_station(flavour="ardupilot")
    no_takeoff = [home_item_as_tools_send_it(), item(1, north_m=20.0)]
    assert upload(copter, no_takeoff)[0].type == M.MAV_MISSION_ACCEPTED
    copter.state_up()
    assert copter.client.result(SET_MODE, custom, 4.0)[0] == ACCEPTED  # GUIDED
    assert copter.client.result(ARM, 1)[0] == ACCEPTED  # in GUIDED, on the ground
    result, said = copter.client.result(SET_MODE, custom, 3.0)  # AUTO
    assert result != ACCEPTED and "Auto: Missing Takeoff Cmd" in " ".join(said)
    assert copter.vehicle.mode.value == "guided"
    assert upload(copter, mission_with_home())[0].type == M.MAV_MISSION_ACCEPTED
    assert copter.client.result(SET_MODE, custom, 3.0)[0] == ACCEPTED
    assert copter.vehicle.mode.value == "mission"

    px4 = make_station()
    assert upload(px4, [item(0, north_m=20.0)])[0].type == M.MAV_MISSION_ACCEPTED
    px4.state_up()
    assert px4.client.result(ARM, 1)[0] == ACCEPTED
    assert px4.client.result(SET_MODE, custom, 4.0, 4.0)[0] == ACCEPTED  # AUTO.MISSION
    assert px4.vehicle.mode.value == "mission"


@pytest.mark.parametrize(("speed_type", "result"), [
    (0.0, M.MAV_MISSION_ACCEPTED), (1.0, M.MAV_MISSION_ACCEPTED),
    (2.0, M.MAV_MISSION_INVALID_PARAM1), (3.0, M.MAV_MISSION_INVALID_PARAM1),
    (math.nan, M.MAV_MISSION_INVALID_PARAM1)])
def test_do_change_speed_types_in_copter_missions(copter, speed_type, result):
    """Air and ground speed set the horizontal cruise; Copter's climb and descent types
    are refused (the mission flies its vertical speeds from the parameters)."""
    speed = M.MAVLink_mission_item_int_message(1, 1, 2, M.MAV_FRAME_MISSION,
                                               M.MAV_CMD_DO_CHANGE_SPEED, 0, 1, speed_type,
                                               4.0, -1.0, 0.0, 0, 0, 0.0, MISSION)
    ack, _, said = upload(copter, mission_with_home()[:2] + [speed])
    assert ack.type == result
    if result == M.MAV_MISSION_ACCEPTED:
        assert copter.vehicle.mission.lists[MISSION][1].params[:2] == (speed_type, 4.0)
    else:
        assert said[0].startswith("mission: item 2: speed type")


def test_an_empty_upload_and_a_home_only_upload_empty_the_mission(copter):
    for items in ([], [home_item_as_tools_send_it()]):
        assert upload(copter, mission_with_home())[0].type == M.MAV_MISSION_ACCEPTED
        ack, asked, said = upload(copter, items)
        assert ack.type == M.MAV_MISSION_ACCEPTED and said == ["Flight plan received"]
        assert asked == [("MISSION_REQUEST", 0)] * len(items)
        assert copter.vehicle.mission.lists[MISSION] == () and len(download(copter)) == 1
