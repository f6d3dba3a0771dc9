"""The ArduPilot-Copter flavour's modes and arming (autopilot/commander/personality.py),
and GUIDED as Copter flies it, against ArduCopter 4.5/4.6's rules: in process, on the
injected clocks (the commander alone), and through the MAVLink server on real loopback
sockets (the ACK results and texts a tool gets). Each rule's PX4 counterpart is
unchanged (test_vehicle_logic.py, test_mavlink_server.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.commander.failsafe import Stream
from autopilot.refusal import RefusedError
from contracts.frames import DEFAULT_HOME
from contracts.modes import COPTER_MODE_NAMES, COPTER_MODES, FlightMode
from tests.autopilot.test_vehicle_logic import (
    EPS,
    GROUND,
    INFO,
    LINK0,
    make_vehicle,
    said,
    state,
)
from tests.mavlink_station import ACCEPTED, ARM, M, Station, air, of_type, texts

FAILED, UNSUPPORTED = M.MAV_RESULT_FAILED, M.MAV_RESULT_UNSUPPORTED
SET_MODE, TAKEOFF = M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_NAV_TAKEOFF
TERMINATE = M.MAV_CMD_DO_FLIGHTTERMINATION
CUSTOM = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
# The modes Copter arms in (mode.h allows_arming; AUTO only with AUTO_OPTIONS bit 0).
ARMABLE = {"STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "POSHOLD"}
STICK_MODES = {FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL}
NUMBER = {mode: n for mode, n in COPTER_MODES.items()}


def copter(**parameters):
    """Disarmed on the ground, the simulator link up, in STABILIZE, nothing said."""
    v = make_vehicle(flavour="ardupilot", **parameters)
    v.sample(0.0, GROUND)
    said(v)
    return v


def sticks(v, link_t_s: float = LINK0) -> None:
    """The sticks a Copter has: RC channels 1-4 overridden, throttle low (1000 us)."""
    v.inputs.rc_override(link_t_s, [1500, 1500, 1000, 1500, *[65535] * 4, *[0] * 10])


def guided_in_the_air(altitude_m: float = 10.0, **parameters):
    v = copter(**parameters)
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.arm(LINK0)
    v.sample(0.01, state(altitude_m))
    assert v.armed and not v.landed
    said(v)
    return v


# -- modes -------------------------------------------------------------------------------
def test_copter_boots_in_stabilize_and_the_mode_numbers_are_coppers():
    v = copter()
    assert v.mode is FlightMode.STABILIZED and not v.armed
    assert {COPTER_MODE_NAMES[n]: m for m, n in COPTER_MODES.items()} == {
        "STABILIZE": FlightMode.STABILIZED, "ALT_HOLD": FlightMode.ALTCTL,
        "AUTO": FlightMode.MISSION, "GUIDED": FlightMode.GUIDED, "LOITER": FlightMode.HOLD,
        "RTL": FlightMode.RTL, "CIRCLE": FlightMode.ORBIT, "LAND": FlightMode.LAND,
        "POSHOLD": FlightMode.POSCTL, "FOLLOW": FlightMode.FOLLOW_TARGET,
        "SYSTEMID": FlightMode.REFERENCE, "BRAKE": FlightMode.BRAKE}


@pytest.mark.parametrize("mode", list(COPTER_MODES))
def test_every_mode_is_selectable_disarmed_without_its_checks_and_silently(mode):
    """Copter's set_mode ignores a mode's checks while disarmed: LAND and RTL (and AUTO
    without a mission, the stick modes without sticks) are selected on the ground."""
    v = copter()
    if mode is FlightMode.STABILIZED:
        v.set_mode(FlightMode.GUIDED, LINK0)
    v.set_mode(mode, LINK0)
    assert v.mode is mode and not v.armed
    # Copter says nothing (its HEARTBEAT shows the mode); CIRCLE and FOLLOW tell their own.
    assert [t for _, t in said(v) if not t.startswith(("orbit", "follow"))] == []
    assert np.array_equal(v.control(), np.zeros(4))


@pytest.mark.parametrize("mode", list(COPTER_MODES))
def test_arming_only_in_the_modes_copter_arms_in(mode):
    v = copter()
    if mode is not FlightMode.STABILIZED:
        v.set_mode(mode, LINK0)
    sticks(v)
    name = COPTER_MODE_NAMES[NUMBER[mode]]
    if name in ARMABLE:
        v.arm(LINK0)
        assert v.armed and said(v) == [(INFO, "Arming motors")]
    else:
        said(v)
        with pytest.raises(RefusedError, match=f"^Arm: {name} mode not armable$") as refused:
            v.arm(LINK0)
        assert not refused.value.temporary and not v.armed and said(v) == []


@pytest.mark.parametrize("mode", sorted(STICK_MODES, key=lambda m: m.value))
def test_arming_in_a_stick_mode_needs_the_rc_throttle_channel(mode):
    v = copter(RC_OVERRIDE_TIME=0.5)
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.set_mode(mode, LINK0)
    with pytest.raises(RefusedError, match="^PreArm: RC not found$") as refused:
        v.arm(LINK0)  # no channel overridden yet
    sticks(v)
    v.inputs.rc.refresh(LINK0 + 0.5 + EPS, 0.5)  # the override expired
    with pytest.raises(RefusedError, match="^PreArm: RC not found$") as refused:
        v.arm(LINK0 + 0.5 + EPS)
    assert refused.value.temporary and not v.armed
    sticks(v, LINK0 + 1.0)
    v.arm(LINK0 + 1.0)
    assert v.armed and v.mode is mode


def test_pre_arm_texts_are_coppers():
    v = make_vehicle(flavour="ardupilot")
    v.set_mode(FlightMode.GUIDED, LINK0)
    with pytest.raises(RefusedError, match="^PreArm: Need Position Estimate$") as refused:
        v.arm(LINK0)
    assert refused.value.temporary
    v.sample(0.0, GROUND)
    v.navigation_problem = "estimator settling after alignment"
    with pytest.raises(RefusedError, match="^PreArm: AHRS: estimator settling after "
                                           "alignment$"):
        v.arm(LINK0)
    assert not v.armed


def test_armed_a_mode_needs_what_it_needs_in_coppers_words():
    v = copter()
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.arm(LINK0)
    said(v)
    with pytest.raises(RefusedError, match="^Mode change to RTL failed: return denied: not "
                                           "in the air$") as refused:
        v.set_mode(FlightMode.RTL, LINK0)
    assert refused.value.temporary
    with pytest.raises(RefusedError, match="^Mode change to AUTO failed: mission denied: no "
                                           "mission uploaded$"):
        v.set_mode(FlightMode.MISSION, LINK0)
    with pytest.raises(RefusedError, match="^Mode change to ALT_HOLD failed: altctl denied: "
                                           "no manual control input$"):
        v.set_mode(FlightMode.ALTCTL, LINK0)
    assert v.mode is FlightMode.GUIDED and v.armed and said(v) == []


@pytest.mark.parametrize("mode", [FlightMode.GUIDED, FlightMode.LAND, FlightMode.RTL])
def test_disarming_after_a_landing_leaves_the_mode_as_it_is(mode):
    """Copter stays in GUIDED, LAND or RTL once landed and disarmed (PX4 goes to HOLD)."""
    v = guided_in_the_air(2.0, COM_DISARM_LAND=1.0)
    if mode is not FlightMode.GUIDED:
        v.set_mode(mode, LINK0)
        said(v)
    v.sample(1.0, GROUND)  # touched down
    assert v.landed
    if mode is FlightMode.LAND:
        v.sample(2.0 + EPS, GROUND)  # COM_DISARM_LAND on the ground: disarmed
    else:
        v.disarm()
    assert not v.armed and v.mode is mode
    assert (INFO, "Disarming motors") in said(v)


def test_a_lost_stick_stream_does_not_move_a_disarmed_copter():
    v = copter()
    sticks(v)
    v.check_links(LINK0 + 100.0)
    assert v.mode is FlightMode.STABILIZED and said(v) == []


# -- take-off and targets in GUIDED --------------------------------------------------------
def test_take_off_only_in_guided_armed_and_on_the_ground():
    v = copter()
    v.set_mode(FlightMode.HOLD, LINK0)
    v.arm(LINK0)
    with pytest.raises(RefusedError, match="^take-off needs GUIDED mode$"):
        v.takeoff(10.0)
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.takeoff(10.0)
    assert v.mode is FlightMode.GUIDED and v.takeoff_altitude_m == 10.0
    assert v.setpoint.position_ned_m[2] == -10.0
    v.sample(0.5, state(3.0))
    assert not v.landed
    with pytest.raises(RefusedError, match="^take-off denied: already flying$"):
        v.takeoff(20.0)
    assert v.takeoff_altitude_m == 10.0


def test_position_and_attitude_targets_are_ignored_outside_guided():
    v = guided_in_the_air()
    v.set_mode(FlightMode.HOLD, LINK0)  # LOITER
    held = v.setpoint.position_ned_m.copy()
    target = v.setpoint.__class__.hold([5.0, 5.0, -12.0], 0.0)
    v.inputs.position_setpoint(LINK0 + 1.0, target)
    v.inputs.attitude_setpoint(LINK0 + 1.0, (1.0, 0.0, 0.0, 0.0), 0.5)
    assert np.array_equal(v.setpoint.position_ned_m, held)
    assert v.state.attitude_target is None and v.state.streamed is None
    assert not v.inputs.streaming(Stream.SETPOINTS, LINK0 + 1.0)  # not even heard
    v.set_mode(FlightMode.GUIDED, LINK0 + 2.0)
    assert np.array_equal(v.setpoint.position_ned_m, held)  # nothing kept for GUIDED
    v.inputs.position_setpoint(LINK0 + 2.0, target)
    assert np.array_equal(v.setpoint.position_ned_m, [5.0, 5.0, -12.0])


def test_a_guided_go_to_flies_there_and_ends_a_take_off():
    v = guided_in_the_air()
    v.state.takeoff_altitude_m = 10.0
    v.auto.guided_go_to(np.array([20.0, -5.0, -12.0]))
    assert np.array_equal(v.setpoint.position_ned_m, [20.0, -5.0, -12.0])
    assert v.takeoff_altitude_m is None and v.mode is FlightMode.GUIDED
    assert said(v) == [(INFO, "going to 20.0 N -5.0 E 12.0 m up")]


@pytest.mark.parametrize("setup, target, reason", [
    ("loiter", [1.0, 0.0, -10.0], "^go-to needs GUIDED mode$"),
    ("ground", [1.0, 0.0, -10.0], "^go-to denied: not in the air$"),
    ("fence", [40.0, 30.0, -10.0], "^go-to denied: the target is 50.0 m from home, beyond "
                                   "45 m$"),
    ("fence", [0.0, 0.0, -61.0], "^go-to denied: the target is 61.0 m up, above 60 m$"),
    ("air", [1001.0, 0.0, -10.0], "more than 1 km from home"),
    ("air", [math.nan, 0.0, -10.0], "must be finite"),
])
def test_a_guided_go_to_is_refused_and_changes_nothing(setup, target, reason):
    v = guided_in_the_air(GF_MAX_HOR_DIST=45.0, GF_MAX_VER_DIST=60.0)
    if setup == "loiter":
        v.set_mode(FlightMode.HOLD, LINK0)
    if setup == "ground":
        v.sample(0.5, GROUND)
    said(v)
    before = v.setpoint.position_ned_m.copy()
    with pytest.raises(RefusedError, match=reason):
        v.auto.guided_go_to(np.array(target))
    assert np.array_equal(v.setpoint.position_ned_m, before) and said(v) == []


def test_a_guided_altitude_change_keeps_the_horizontal_target():
    v = guided_in_the_air()
    v.auto.guided_go_to(np.array([3.0, 4.0, -10.0]))
    v.auto.guided_altitude(25.0)
    assert np.array_equal(v.setpoint.position_ned_m, [3.0, 4.0, -25.0])
    for bad in (0.4, math.nan, math.inf, 1000.5):
        with pytest.raises(RefusedError, match="outside"):
            v.auto.guided_altitude(bad)
    assert np.array_equal(v.setpoint.position_ned_m, [3.0, 4.0, -25.0])


def test_flight_termination_stops_the_motors_in_the_air_and_keeps_the_mode():
    v = guided_in_the_air()
    assert np.any(v.control() > 0.0)
    v.terminate()
    assert not v.armed and v.mode is FlightMode.GUIDED
    assert v.failsafe == "flight terminated"
    assert np.array_equal(v.control(), np.zeros(4))
    assert said(v) == [(INFO, "Disarming motors")]
    v.terminate()  # disarmed already: nothing happens
    assert said(v) == []


# -- through the MAVLink server -----------------------------------------------------------
@pytest.fixture
def copter_station():
    s = Station(flavour="ardupilot")
    s.state_up()
    s.vehicle.messages.clear()  # "simulator link up"
    yield s
    s.close()


def arm(s: Station, *params: float) -> tuple[int, list[str]]:
    """COMPONENT_ARM_DISARM's result, and the texts with it and after it (the vehicle's
    own, such as "Arming motors", go out at the next service)."""
    result, with_ack = s.client.result(ARM, *params)
    s.server.service()
    return result, with_ack + texts(s.client.sync())


def guided_flying(s: Station) -> None:
    assert s.client.result(SET_MODE, CUSTOM, 4)[0] == ACCEPTED
    assert arm(s, 1) == (ACCEPTED, ["Arming motors"])
    s.state_up(air(10.0), 0.01)
    assert s.vehicle.armed and not s.vehicle.landed
    s.server.service()
    s.client.sync()


def test_heartbeat_shows_stabilize_at_boot_and_each_mode_by_number(copter_station):
    s = copter_station
    assert s.client.request(M.MAVLINK_MSG_ID_HEARTBEAT).custom_mode == 0
    for number in (6, 9, 4, 5, 3, 2, 16, 7, 23, 25, 17, 0):  # RTL, LAND ... disarmed
        assert s.client.result(SET_MODE, CUSTOM, number) == (ACCEPTED, [])
        assert s.client.request(M.MAVLINK_MSG_ID_HEARTBEAT).custom_mode == number
    # The legacy SET_MODE (MAVProxy's) too.
    s.client.send(M.MAVLink_set_mode_message(1, CUSTOM, 9))
    s.client.sync()
    assert s.vehicle.mode is FlightMode.LAND


@pytest.mark.parametrize("number, text", [
    (1, "Mode change to ACRO failed: not available in this SITL"),
    (11, "Mode change to DRIFT failed: not available in this SITL"),
    (24, "Mode change to ZIGZAG failed: not available in this SITL"),
    (8, "No such mode 8"), (99, "No such mode 99"),
])
def test_modes_copter_has_but_this_vehicle_does_not_fly_fail(copter_station, number, text):
    s = copter_station
    assert s.client.result(SET_MODE, CUSTOM, number) == (FAILED, [text])
    assert s.vehicle.mode is FlightMode.STABILIZED


def test_arm_refusals_are_failed_with_coppers_texts_and_2989_forces(copter_station):
    s = copter_station
    assert arm(s, 1) == (FAILED, ["PreArm: RC not found"])
    assert s.client.result(SET_MODE, CUSTOM, 6)[0] == ACCEPTED  # RTL, disarmed
    assert arm(s, 1) == (FAILED, ["Arm: RTL mode not armable"])
    assert arm(s, 1, 2988) == (FAILED, ["Arm: RTL mode not armable"])
    assert not s.vehicle.armed
    assert arm(s, 1, 2989) == (ACCEPTED, ["Arming motors"])
    assert s.vehicle.armed and s.vehicle.mode is FlightMode.RTL
    assert arm(s, 0) == (ACCEPTED, ["Disarming motors"])
    assert s.vehicle.mode is FlightMode.RTL


def test_take_off_above_home_then_failed_in_the_air(copter_station):
    s = copter_station
    guided_flying(s)
    assert s.client.result(TAKEOFF, *[0.0] * 6, 10.0) == (FAILED,
                                                        ["take-off denied: already flying"])


def test_flight_termination_in_the_air(copter_station):
    s = copter_station
    guided_flying(s)
    assert s.client.result(TERMINATE, 0.0) == (FAILED, ["flight termination needs param1 1, "
                                                       "got 0"])
    assert s.client.result(TERMINATE, math.nan)[0] == FAILED
    assert s.vehicle.armed
    assert s.client.result(TERMINATE, 1.0)[0] == ACCEPTED
    assert not s.vehicle.armed and np.array_equal(s.vehicle.control(), np.zeros(4))


def test_px4_does_not_serve_flight_termination(station):
    station.flying()
    assert station.client.result(TERMINATE, 1.0) == (UNSUPPORTED, [])
    assert station.vehicle.armed


def goto_item(lat: float, lon: float, alt: float, current: int = 2, legacy: bool = True,
              frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
              command: int = M.MAV_CMD_NAV_WAYPOINT):
    """DroneKit's simple_goto: MISSION_ITEM to 0/0, seq 0, current 2."""
    if legacy:
        return M.MAVLink_mission_item_message(0, 0, 0, frame, command, current, 0,
                                              0, 0, 0, 0, lat, lon, alt)
    int_frame = {M.MAV_FRAME_GLOBAL: M.MAV_FRAME_GLOBAL_INT,
                 M.MAV_FRAME_GLOBAL_RELATIVE_ALT: M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
    return M.MAVLink_mission_item_int_message(1, 1, 0, int_frame.get(frame, frame),
                                              command, current, 0, 0, 0, 0, 0,
                                              round(lat * 1e7), round(lon * 1e7), alt)


def north_east_of_home(north_m: float, east_m: float) -> tuple[float, float]:
    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north_m, east_m, 0.0)
    return lat, lon


def sent(s: Station, msg):
    """The MISSION_ACK's type, and the texts with it and after it."""
    s.client.send(msg)
    msgs = s.client.sync()
    s.server.service()
    msgs += s.client.sync()
    (ack,) = of_type(msgs, "MISSION_ACK")
    assert (ack.target_system, ack.target_component, ack.mission_type) == (255, 190, 0)
    return ack.type, texts(msgs)


@pytest.mark.parametrize("legacy", [True, False])
def test_mission_item_current_2_is_a_guided_go_to_answered_with_a_mission_ack(
        copter_station, legacy):
    s = copter_station
    guided_flying(s)
    # MISSION_ITEM's float32 latitude is good to 0.42 m here (its spacing at 47.4 deg),
    # MISSION_ITEM_INT's to 1 cm.
    atol = 0.25 if legacy else 0.01
    lat, lon = north_east_of_home(20.0, -5.0)
    result, said_ = sent(s, goto_item(lat, lon, 12.0, legacy=legacy))
    north = 20.1 if legacy else 20.0  # the float32 latitude's 0.42 m steps
    assert (result, said_) == (M.MAV_MISSION_ACCEPTED, [f"going to {north:.1f} N -5.0 E "
                                                        "12.0 m up"])
    np.testing.assert_allclose(s.vehicle.setpoint.position_ned_m, [20.0, -5.0, -12.0],
                               atol=atol)
    assert s.vehicle.mission.lists[0] == ()  # not stored in the mission
    # AMSL in the GLOBAL frame.
    lat, lon = north_east_of_home(-3.0, 4.0)
    assert sent(s, goto_item(lat, lon, DEFAULT_HOME.alt_amsl_m + 8.0, legacy=legacy,
                             frame=M.MAV_FRAME_GLOBAL))[0] == M.MAV_MISSION_ACCEPTED
    np.testing.assert_allclose(s.vehicle.setpoint.position_ned_m, [-3.0, 4.0, -8.0],
                               atol=atol)
    # current=3: the altitude only.
    assert sent(s, goto_item(0.0, 0.0, 15.0, current=3, legacy=legacy)) == (
        M.MAV_MISSION_ACCEPTED, ["changing altitude to 15.0 m"])
    assert s.vehicle.setpoint.position_ned_m[2] == -15.0
    np.testing.assert_allclose(s.vehicle.setpoint.position_ned_m, [-3.0, 4.0, -15.0],
                               atol=atol)


@pytest.mark.parametrize("case, text", [
    ("loiter", "go-to needs GUIDED mode"),
    ("nan", "guided item position must be finite"),
    ("local frame", "guided item frame 1 is not supported"),
    ("takeoff", "guided item command 22 is not a waypoint"),
    ("fence", "go-to denied: the target is 120.0 m from home, beyond 50 m"),
    ("far", "go-to position is more than 1 km from home"),
])
def test_a_refused_guided_item_is_a_mission_error_and_changes_nothing(case, text):
    s = Station(flavour="ardupilot", GF_MAX_HOR_DIST=50.0 if case == "fence" else 0.0)
    try:
        s.state_up()
        s.vehicle.messages.clear()
        guided_flying(s)
        if case == "loiter":
            assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED
        before = s.vehicle.setpoint.position_ned_m.copy()
        lat, lon = north_east_of_home(120.0 if case == "fence" else 10.0, 0.0)
        msg = {"nan": goto_item(math.nan, lon, 10.0),
               "local frame": goto_item(lat, lon, 10.0, frame=M.MAV_FRAME_LOCAL_NED),
               "takeoff": goto_item(lat, lon, 10.0, command=M.MAV_CMD_NAV_TAKEOFF),
               "far": goto_item(0.0, 0.0, 10.0)}.get(case, goto_item(lat, lon, 10.0, legacy=False))
        assert sent(s, msg) == (M.MAV_MISSION_ERROR, [text])
        assert np.array_equal(s.vehicle.setpoint.position_ned_m, before)
    finally:
        s.close()


def test_px4_takes_no_guided_items(station):
    """In PX4's flavour a current=2 item outside an upload is not ours to take: dropped."""
    station.flying()
    before = station.vehicle.setpoint.position_ned_m.copy()
    lat, lon = north_east_of_home(10.0, 0.0)
    station.client.send(goto_item(lat, lon, 5.0))
    assert of_type(station.client.sync(), "MISSION_ACK") == []
    assert np.array_equal(station.vehicle.setpoint.position_ned_m, before)


def test_copter_takes_position_targets_only_in_guided(copter_station):
    s = copter_station
    guided_flying(s)
    assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
    held = s.vehicle.setpoint.position_ned_m.copy()
    s.client.send(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000, 5.0, 6.0, -7.0, 0, 0, 0, 0, 0, 0, 0,
        0))
    assert texts(s.client.sync()) == []  # ignored, as Copter ignores it
    assert np.array_equal(s.vehicle.setpoint.position_ned_m, held)
    assert s.client.result(SET_MODE, CUSTOM, 4)[0] == ACCEPTED
    s.client.send(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000, 5.0, 6.0, -7.0, 0, 0, 0, 0, 0, 0, 0,
        0))
    s.client.sync()
    assert np.array_equal(s.vehicle.setpoint.position_ned_m, [5.0, 6.0, -7.0])


# -- yaw and region of interest in GUIDED ---------------------------------------------------
YAW, ROI = M.MAV_CMD_CONDITION_YAW, M.MAV_CMD_DO_SET_ROI_LOCATION


def test_condition_yaw_in_guided_absolute_and_relative(copter_station):
    s = copter_station
    guided_flying(s)
    assert s.client.result(YAW, 90.0, 0.0, 0.0, 0.0) == (ACCEPTED, [])
    assert s.vehicle.setpoint.yaw_rad == pytest.approx(math.pi / 2)
    assert s.client.result(YAW, 30.0, 0.0, -1.0, 1.0)[0] == ACCEPTED  # 30 deg to the left
    assert s.vehicle.setpoint.yaw_rad == pytest.approx(math.radians(60.0))
    assert s.client.result(YAW, 150.0, 0.0, 1.0, 1.0)[0] == ACCEPTED  # 150 to the right
    assert s.vehicle.setpoint.yaw_rad == pytest.approx(math.radians(-150.0))
    for bad, text in (((361.0, 0, 0, 0), "yaw angle 361 deg is outside [0, 360]"),
                      ((math.nan, 0, 0, 0), "yaw angle nan deg is outside [0, 360]"),
                      ((10.0, 0, math.inf, 0), "yaw direction must be finite"),
                      ((10.0, 0, 0, 2.0), "yaw param4 must be 0 (absolute) or 1 "
                                          "(relative), got 2")):
        assert s.client.result(YAW, *bad) == (FAILED, [text])
    assert s.vehicle.setpoint.yaw_rad == pytest.approx(math.radians(-150.0))
    assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
    assert s.client.result(YAW, 10.0) == (FAILED, ["yaw needs GUIDED mode"])


def test_a_region_of_interest_turns_the_nose_to_it_in_guided_until_cleared():
    v = guided_in_the_air()
    v.auto.guided_roi(np.array([0.0, 10.0, 0.0]))  # due east
    v.control()
    assert v.setpoint.yaw_rad == pytest.approx(math.pi / 2)
    v.sample(0.02, state(10.0, north_m=20.0))  # it moved north: the ROI is south-east
    v.control()
    assert v.setpoint.yaw_rad == pytest.approx(math.atan2(10.0, -20.0))
    v.auto.guided_roi(None)
    v.sample(0.03, state(10.0, north_m=0.0))
    v.control()
    assert v.setpoint.yaw_rad == pytest.approx(math.atan2(10.0, -20.0))  # stays
    assert said(v) == [(INFO, "region of interest 0.0 N 10.0 E"),
                       (INFO, "region of interest cleared")]
    v.auto.guided_roi(np.array([0.0, 10.0, 0.0]))
    v.set_mode(FlightMode.HOLD, LINK0)
    v.set_mode(FlightMode.GUIDED, LINK0)  # a new GUIDED: no ROI
    v.control()
    assert v.tasks[FlightMode.GUIDED].roi_ned_m is None


def test_do_set_roi_location_through_the_server(copter_station):
    s = copter_station
    guided_flying(s)
    lat, lon = north_east_of_home(0.0, 30.0)
    assert s.client.result(ROI, 0, 0, 0, 0, lat, lon, 0.0, kind="int",
                           frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)[0] == ACCEPTED
    np.testing.assert_allclose(s.vehicle.tasks[FlightMode.GUIDED].roi_ned_m[:2], [0.0, 30.0],
                               atol=0.01)
    assert s.client.result(ROI, 0, 0, 0, 0, math.nan, lon, 0.0) == (
        FAILED, ["region of interest latitude/longitude must be finite"])
    assert s.client.result(M.MAV_CMD_DO_SET_ROI, 0, 0, 0, 0, 0.0, 0.0, 0.0)[0] == ACCEPTED
    assert s.vehicle.tasks[FlightMode.GUIDED].roi_ned_m is None  # 0, 0: none
    assert s.client.result(ROI, 0, 0, 0, 0, lat, lon, 0.0)[0] == ACCEPTED
    assert s.client.result(M.MAV_CMD_DO_SET_ROI_NONE)[0] == ACCEPTED
    assert s.vehicle.tasks[FlightMode.GUIDED].roi_ned_m is None


def test_px4_serves_no_copter_yaw_or_roi_commands(station):
    station.flying()
    for command in (YAW, ROI, M.MAV_CMD_DO_SET_ROI_NONE):
        assert station.client.result(command, 10.0) == (UNSUPPORTED, [])


def test_do_reposition_is_a_guided_go_to_and_changes_mode_only_when_flagged(copter_station):
    """Copter's DO_REPOSITION: refused outside GUIDED unless param2 has
    MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, which enters GUIDED; NaN keeps a coordinate."""
    s = copter_station
    guided_flying(s)
    assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
    lat, lon = north_east_of_home(15.0, 5.0)
    reposition = M.MAV_CMD_DO_REPOSITION
    assert s.client.result(reposition, -1, 0, 0, math.nan, lat, lon, 12.0, kind="int",
                           frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) == (
        M.MAV_RESULT_DENIED, ["go-to needs GUIDED mode (or DO_REPOSITION's change-mode flag)"])
    assert s.vehicle.mode is FlightMode.HOLD
    assert s.client.result(reposition, -1, 1, 0, math.nan, lat, lon, 12.0, kind="int",
                           frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)[0] == ACCEPTED
    assert s.vehicle.mode is FlightMode.GUIDED
    np.testing.assert_allclose(s.vehicle.setpoint.position_ned_m, [15.0, 5.0, -12.0],
                               atol=0.01)
    # In GUIDED no flag is needed; NaN altitude keeps the target's.
    lat, lon = north_east_of_home(-4.0, 2.0)
    assert s.client.result(reposition, -1, 0, 0, math.nan, lat, lon, math.nan, kind="int",
                           frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)[0] == ACCEPTED
    np.testing.assert_allclose(s.vehicle.setpoint.position_ned_m, [-4.0, 2.0, -12.0],
                               atol=0.01)


def test_a_flagged_do_reposition_beyond_the_fence_changes_nothing():
    s = Station(flavour="ardupilot", GF_MAX_HOR_DIST=50.0)
    try:
        s.state_up()
        s.vehicle.messages.clear()
        guided_flying(s)
        assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
        before = s.vehicle.setpoint.position_ned_m.copy()
        lat, lon = north_east_of_home(80.0, 0.0)
        assert s.client.result(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.nan, lat, lon, 10.0,
                               kind="int", frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) == (
            M.MAV_RESULT_DENIED, ["go-to denied: the target is 80.0 m from home, beyond 50 m"])
        assert s.vehicle.mode is FlightMode.HOLD
        assert np.array_equal(s.vehicle.setpoint.position_ned_m, before)
    finally:
        s.close()


def test_brake_stops_and_holds_in_the_air_and_is_refused_on_the_ground_armed():
    v = guided_in_the_air()
    v.sample(0.02, state(10.0, north_m=3.0))
    v.set_mode(FlightMode.BRAKE, LINK0)
    assert v.mode is FlightMode.BRAKE and said(v) == []
    np.testing.assert_allclose(v.setpoint.position_ned_m, [3.0, 0.0, -10.0])
    v = copter()
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.arm(LINK0)
    with pytest.raises(RefusedError, match="^Mode change to BRAKE failed: brake denied: not "
                                           "in the air$"):
        v.set_mode(FlightMode.BRAKE, LINK0)
    assert v.mode is FlightMode.GUIDED
