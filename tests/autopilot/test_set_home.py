"""MAV_CMD_DO_SET_HOME: home moves apart from the local frame's origin (ArduPilot Copter's
set_home, PX4's commander alike), over real UDP sockets with pymavlink; and a mission
flown after it whose return lands at the new home (the rigid-body plant, in process).
The origin stays: LOCAL_POSITION_NED and the simulator link keep their frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.mavlink.home_command import do_set_home
from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import MISSION
from contracts.frames import DEFAULT_HOME
from contracts.modes import FlightMode
from tests.autopilot.test_mission_protocol import download
from tests.flight import Flight, do_item, mission_item
from tests.mavlink_station import ACCEPTED, REQUEST_MESSAGE, M, of_type

SET_HOME = M.MAV_CMD_DO_SET_HOME
# Home 30 m north, 20 m west of the origin and 2 m above it (latitude and longitude by the
# origin's own projection, so the numbers below are exact to the projection's rounding).
NEW_N, NEW_E, NEW_UP = 30.0, -20.0, 2.0
NEW_LAT, NEW_LON, _ = DEFAULT_HOME.geodetic_from_ned(NEW_N, NEW_E, 0.0)
NEW_ALT = DEFAULT_HOME.alt_amsl_m + NEW_UP


def position(north: float, east: float, up: float) -> np.ndarray:
    m = np.zeros(12)
    m[0:3] = (north, east, -up)
    return m


@pytest.fixture
def copter(make_station):
    s = make_station(flavour="ardupilot")
    s.vehicle.set_origin(DEFAULT_HOME)  # as the autopilot's loop does on the first fix
    s.state_up(position(5.0, 6.0, 3.0))
    s.service()
    s.client.sync()
    return s


def test_set_home_moves_home_and_not_the_origin(copter):
    c = copter.client
    # COMMAND_INT: latitude and longitude in 1e-7 degrees (COMMAND_LONG's float32
    # degrees are good to about a metre), the altitude AMSL in MAV_FRAME_GLOBAL.
    assert c.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT, kind="int") == (
        ACCEPTED, [])  # Copter says nothing: HOME_POSITION tells
    places = copter.vehicle.places
    assert places.origin == DEFAULT_HOME
    assert places.home == pytest.approx((NEW_LAT, NEW_LON, NEW_ALT), abs=1e-7)
    assert places.home_ned_m == pytest.approx((NEW_N, NEW_E, -NEW_UP), abs=0.01)
    # HOME_POSITION goes out to every tool when home changes (Copter's send_home), with
    # home's local position from the origin.
    copter.service()
    (home,) = of_type(c.sync(), "HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (
        round(NEW_LAT * 1e7), round(NEW_LON * 1e7), round(NEW_ALT * 1000))
    assert (home.x, home.y, home.z) == pytest.approx((NEW_N, NEW_E, -NEW_UP), abs=0.01)
    copter.service()
    assert of_type(c.sync(), "HOME_POSITION") == []  # once per change
    # The local frame stays; altitudes above home are from the new home.
    local = c.request(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
    assert (local.x, local.y, local.z) == (5.0, 6.0, -3.0)
    glob = c.request(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    assert glob.alt == round((DEFAULT_HOME.alt_amsl_m + 3.0) * 1000)  # AMSL: unchanged
    assert glob.relative_alt == 1000  # 3 m up from the origin, 2 m of it below home
    hud = c.request(M.MAVLINK_MSG_ID_VFR_HUD)
    assert hud.alt == pytest.approx(DEFAULT_HOME.alt_amsl_m + 3.0)  # Copter's: AMSL
    # Item 0 of the mission is the new home; GET_HOME_POSITION answers it too.
    item0 = download(copter)[0]
    assert (item0.x, item0.y, item0.z) == (round(NEW_LAT * 1e7), round(NEW_LON * 1e7),
                                           pytest.approx(NEW_ALT, abs=1e-3))
    ack, (asked,) = c.command(M.MAV_CMD_GET_HOME_POSITION)
    assert ack.result == ACCEPTED and asked.latitude == round(NEW_LAT * 1e7)


def test_param1_1_or_latlon_0_sets_home_where_the_vehicle_is(copter):
    here_lat, here_lon, here_alt = DEFAULT_HOME.geodetic_from_ned(5.0, 6.0, -3.0)
    for params in ((1.0, 0, 0, 0, 45.0, 7.0, 900.0), (0.0, 0, 0, 0, 0.0, 0.0, 900.0)):
        copter.vehicle.navigator.places = Places.at(DEFAULT_HOME)
        assert copter.client.result(SET_HOME, *params)[0] == ACCEPTED
        assert copter.vehicle.places.home == pytest.approx((here_lat, here_lon, here_alt))
    glob = copter.client.request(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    assert glob.relative_alt == 0  # home is here


def test_command_int_relative_altitude_is_above_the_current_home(copter):
    c = copter.client
    assert c.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT, kind="int")[0] == \
        ACCEPTED
    assert c.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, 4.0, kind="int",
                    frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)[0] == ACCEPTED
    assert copter.vehicle.places.home.alt_amsl_m == pytest.approx(NEW_ALT + 4.0)
    assert c.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, 4.0, kind="int",
                    frame=M.MAV_FRAME_LOCAL_NED)[0] == M.MAV_RESULT_DENIED


@pytest.mark.parametrize(("flavour", "failed"), [
    ("ardupilot", M.MAV_RESULT_FAILED), ("px4", M.MAV_RESULT_DENIED)])
def test_bad_homes_are_refused_and_nothing_changes(make_station, flavour, failed):
    s = make_station(flavour=flavour)
    s.state_up(position(5.0, 6.0, 3.0))
    c = s.client
    # Before the origin is known (Copter: no EKF origin): failed.
    result, said = c.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT)
    assert (result, said) == (failed, ["home not set: no position yet"])
    s.vehicle.set_origin(DEFAULT_HOME)
    before = s.vehicle.places
    for params, result in (
            ((0.0, 0, 0, 0, math.nan, NEW_LON, NEW_ALT), M.MAV_RESULT_DENIED),
            ((0.0, 0, 0, 0, NEW_LAT, NEW_LON, math.inf), M.MAV_RESULT_DENIED),
            ((0.0, 0, 0, 0, 95.0, NEW_LON, NEW_ALT), M.MAV_RESULT_DENIED),
            ((0.0, 0, 0, 0, NEW_LAT, 181.0, NEW_ALT), M.MAV_RESULT_DENIED),
            ((0.0, 0, 0, 0, NEW_LAT, NEW_LON, -2000.0), M.MAV_RESULT_DENIED),
            ((0.0, 0, 0, 0, NEW_LAT, NEW_LON, 9001.0), M.MAV_RESULT_DENIED)):
        got, said = c.result(SET_HOME, *params)
        assert got == result, params
        assert said and said[0].startswith("home not set"), said
        assert s.vehicle.places == before


def test_request_message_home_position_reports_the_new_home(copter):
    assert copter.client.result(SET_HOME, 0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT,
                                kind="int")[0] == ACCEPTED
    ack, (home,) = copter.client.command(REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
    assert home.latitude == round(NEW_LAT * 1e7) and home.altitude == round(NEW_ALT * 1000)


def test_a_mission_after_set_home_climbs_above_it_and_its_return_lands_there():
    """Copter: home set in the air 30 m north, 20 m west and 2 m up; a mission's relative
    altitudes and the return's are above the new home; the return lands at it."""
    f = Flight(flavour="ardupilot")
    f.vehicle.set_origin(DEFAULT_HOME)
    f.take_off(5.0)
    do_set_home(f.vehicle, M.MAV_FRAME_GLOBAL, [0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT])
    f.vehicle.mission.replace(MISSION, (
        mission_item(0, 10.0, 0.0, 6.0),  # 6 m above home: 8 m up in the local frame
        do_item(1, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, (0, 0, 0, 0))))
    f.vehicle.set_mode(FlightMode.MISSION, f.t_s)
    start = f.t_s
    f.run(70.0)
    log = f.since(start)
    assert not f.vehicle.armed
    # The waypoint was flown to 6 m above the new home, 8 m up in the local frame.
    assert np.linalg.norm(log[:, 1:4] - (10.0, 0.0, -8.0), axis=1).min() < 0.1
    rtl_alt = f.vehicle.parameters["RTL_RETURN_ALT"]
    assert -log[:, 3].min() == pytest.approx(rtl_alt + NEW_UP, abs=0.05)  # above home
    assert log[-1, 1:3] == pytest.approx((NEW_N, NEW_E), abs=0.1)  # landed at home
    assert log[-1, 3] == pytest.approx(0.0, abs=0.05)  # on the ground below it
    # The local origin did not move: the flight's frame is the one it took off in.
    assert f.vehicle.places.origin == DEFAULT_HOME


def home_item(seq: int, frame: int = M.MAV_FRAME_GLOBAL, p1: float = 0.0,
              alt_m: float = NEW_ALT, lat: float = NEW_LAT, lon: float = NEW_LON):
    from autopilot.navigator.mission_store import MissionItem

    return MissionItem(seq, frame, SET_HOME, 0, 1, (p1, 0.0, 0.0, 0.0), round(lat * 1e7),
                       round(lon * 1e7), alt_m)


def test_a_do_set_home_item_moves_home_mid_mission_and_the_return_lands_there():
    """AP_Mission's DO_SET_HOME runs with the position item before it (as a do command
    after a navigation command): the next waypoint's relative altitude and the return
    are from the new home."""
    f = Flight(flavour="ardupilot")
    f.vehicle.set_origin(DEFAULT_HOME)
    f.take_off(5.0)
    f.vehicle.mission.replace(MISSION, (
        mission_item(0, 10.0, 0.0, 5.0),
        home_item(1),
        mission_item(2, 10.0, 10.0, 5.0),  # 5 m above the new home: 7 m up
        do_item(3, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, (0, 0, 0, 0))))
    f.vehicle.set_mode(FlightMode.MISSION, f.t_s)
    start = f.t_s
    f.run(80.0)
    log = f.since(start)
    assert f.vehicle.places.home == pytest.approx((NEW_LAT, NEW_LON, NEW_ALT), abs=1e-7)
    assert np.linalg.norm(log[:, 1:4] - (10.0, 10.0, -7.0), axis=1).min() < 0.1
    assert not f.vehicle.armed
    assert log[-1, 1:3] == pytest.approx((NEW_N, NEW_E), abs=0.1)


def test_a_do_set_home_item_at_0_0_or_param1_1_sets_home_where_the_leg_starts():
    from autopilot.navigator.mission_runner import EventKind, MissionRunner
    from autopilot.parameters import default_parameters

    for item in (home_item(1, p1=1.0), home_item(1, lat=0.0, lon=0.0)):
        runner = MissionRunner((mission_item(0, 10.0, 0.0, 5.0), item),
                               default_parameters(), Places.at(DEFAULT_HOME))
        runner.start(0, np.array([3.0, 4.0, -5.0]), 0.0, False, 2.5)
        assert [e.kind for e in runner.events] == [EventKind.HOME]
        assert runner.places.home_ned_m == pytest.approx((3.0, 4.0, -5.0), abs=1e-6)


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_do_set_home_items_upload_in_the_ardupilot_flavour_only_in_a_global_frame(
        make_station, flavour):
    from tests.autopilot.test_mission_protocol import item
    from tests.autopilot.test_mission_protocol_ardupilot import (
        home_item_as_tools_send_it,
        upload,
    )

    def wire(seq: int, frame: int):
        return M.MAVLink_mission_item_int_message(
            1, 1, seq, frame, SET_HOME, 0, 1, 0.0, 0.0, 0.0, 0.0, round(NEW_LAT * 1e7),
            round(NEW_LON * 1e7), NEW_ALT, MISSION)

    s = make_station(flavour=flavour)
    first = [home_item_as_tools_send_it()] if flavour == "ardupilot" else []
    n = len(first)
    ack = upload(s, [*first, item(n), wire(n + 1, M.MAV_FRAME_GLOBAL_INT)])[0]
    assert ack.type == (M.MAV_MISSION_ACCEPTED if flavour == "ardupilot"
                        else M.MAV_MISSION_UNSUPPORTED)
    if flavour == "ardupilot":
        assert s.vehicle.mission.lists[MISSION][1].command == SET_HOME
        assert s.vehicle.places == Places.at(DEFAULT_HOME)  # uploaded, not yet run
        ack = upload(s, [*first, item(1), wire(2, M.MAV_FRAME_LOCAL_NED)])[0]
        assert ack.type == M.MAV_MISSION_UNSUPPORTED_FRAME


def test_take_off_and_altitude_change_are_above_the_new_home():
    """Copter's NAV_TAKEOFF and GUIDED altitude change take altitudes above home: with
    home 2 m above the ground, a take-off to 5 m climbs to 7 m and a change to 3 m
    descends to 5 m (local frame); the 0.5 m floor is above home too."""
    from autopilot.refusal import RefusedError

    f = Flight(flavour="ardupilot")
    f.vehicle.set_origin(DEFAULT_HOME)
    f.run(0.05)
    do_set_home(f.vehicle, M.MAV_FRAME_GLOBAL, [0.0, 0, 0, 0, NEW_LAT, NEW_LON, NEW_ALT])
    f.vehicle.set_mode(FlightMode.GUIDED, f.t_s)
    f.vehicle.arm(f.t_s)
    f.vehicle.takeoff(5.0)
    f.run(15.0)
    assert f.vehicle.takeoff_altitude_m is None  # reached
    assert -f.log[-1, 3] == pytest.approx(5.0 + NEW_UP, abs=0.1)
    f.vehicle.auto.guided_altitude(3.0)
    f.run(8.0)
    assert -f.log[-1, 3] == pytest.approx(3.0 + NEW_UP, abs=0.05)
    with pytest.raises(RefusedError, match="outside"):
        f.vehicle.auto.guided_altitude(0.4)
