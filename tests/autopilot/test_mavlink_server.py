"""The vehicle's MAVLink server in process: real loopback UDP links, a pymavlink client,
an injected link clock, and the test calling ``receive`` and ``service`` itself.

Every command's COMMAND_ACK, the parameter protocol, the telemetry streams' timing, and
the link failsafes as a ground tool sees them, without processes or wall-clock windows
(test_vehicle_mavlink.py flies the same through real processes). No test sleeps: a
PING round trip is the barrier after which everything the server sent has arrived.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from autopilot.copter_parameters import px4_parameters
from autopilot.mavlink.params import float_as_int32, int32_as_float
from autopilot.parameters import PARAMETERS, default_parameters, validate_parameters
from contracts.frames import DEFAULT_HOME
from contracts.modes import FlightMode, px4_custom_mode
from tests.flight import mission_item
from tests.mavlink_station import (
    ACCEPTED,
    ARM,
    GROUND,
    REQUEST_MESSAGE,
    T0,
    Client,
    M,
    Station,
    air,
    of_type,
    texts,
)

DENIED = M.MAV_RESULT_DENIED
TEMPORARILY_REJECTED, UNSUPPORTED = M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_UNSUPPORTED
TAKEOFF, LAND = M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND
SET_MODE = M.MAV_CMD_DO_SET_MODE
SET_INTERVAL = M.MAV_CMD_SET_MESSAGE_INTERVAL
CUSTOM = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
FORCE = 21196
EPS = 0.001
DEFAULTS = default_parameters()
STATUSTEXT_CHARS = 50




def px4(main: int, sub: int = 0) -> tuple[float, float, float]:
    return float(CUSTOM), float(main), float(sub)


def main_sub(heartbeat) -> tuple[int, int]:
    return (heartbeat.custom_mode >> 16) & 0xFF, (heartbeat.custom_mode >> 24) & 0xFF


# -- arming ----------------------------------------------------------------------------
def test_arming_without_simulator_state_is_temporarily_rejected_and_says_why(station):
    assert station.client.result(ARM, 1) == (
        TEMPORARILY_REJECTED, ["arming denied: no state from the simulator"])
    assert not station.vehicle.armed


@pytest.mark.parametrize("kind", ["long", "int"])
def test_arm_and_disarm_on_the_ground_are_accepted(station, kind):
    station.state_up()
    ack, others = station.client.command(ARM, 1, kind=kind)
    assert ack.result == ACCEPTED and texts(others) == [] and station.vehicle.armed
    assert station.client.result(ARM, 1, kind=kind) == (ACCEPTED, [])  # armed already
    assert station.client.result(ARM, 0, kind=kind) == (ACCEPTED, [])
    assert not station.vehicle.armed


def test_arm_param1_other_than_0_or_1_is_denied(station):
    station.state_up()
    assert station.client.result(ARM, 7) == (DENIED, ["arm param1 must be 0 or 1, got 7"])
    assert station.client.result(ARM, math.nan)[0] == DENIED
    assert not station.vehicle.armed


def test_arming_in_the_air_is_denied(station):
    station.state_up(air())
    assert station.client.result(ARM, 1) == (DENIED, ["arming denied: not on the ground"])


def test_arming_in_offboard_without_setpoints_is_temporarily_rejected(station):
    station.state_up()
    station.vehicle.inputs.position_setpoint(T0, station.vehicle.setpoint)
    assert station.client.result(SET_MODE, *px4(6))[0] == ACCEPTED
    station.at(T0 + DEFAULTS["COM_OF_LOSS_T"] + EPS)
    assert station.client.result(ARM, 1) == (TEMPORARILY_REJECTED,
                                             ["arming denied: no offboard setpoints"])


def test_disarming_in_the_air_is_denied_unless_forced_with_21196(station):
    station.flying()
    # The whole hint, in two STATUSTEXT chunks.
    assert station.client.result(ARM, 0) == (
        DENIED, ["disarming denied: in the air (force with param2 21196)"])
    assert station.client.result(ARM, 0, FORCE - 1)[0] == DENIED
    assert station.vehicle.armed
    assert station.client.result(ARM, 0, FORCE, kind="int") == (ACCEPTED, [])
    assert not station.vehicle.armed


# -- take-off, landing, modes -------------------------------------------------------------
def test_take_off_and_land_are_temporarily_rejected_disarmed(station):
    station.state_up()
    assert station.client.result(TAKEOFF, *[math.nan] * 7) == (
        TEMPORARILY_REJECTED, ["take-off denied: disarmed"])
    assert station.client.result(LAND) == (TEMPORARILY_REJECTED, ["landing denied: disarmed"])


@pytest.mark.parametrize("param7, kind, altitude", [
    (math.nan, "long", DEFAULTS["MIS_TAKEOFF_ALT"]),  # NaN: MIS_TAKEOFF_ALT
    (DEFAULT_HOME.alt_amsl_m + 3.0, "long", 3.0),  # PX4 reads param7 as AMSL
    (DEFAULT_HOME.alt_amsl_m + 4.0, "int", 4.0)])
def test_take_off_is_accepted_armed_to_the_altitude_asked(station, param7, kind, altitude):
    station.state_up()
    station.client.result(ARM, 1)
    ack, others = station.client.command(TAKEOFF, *[math.nan] * 6, param7, kind=kind)
    assert ack.result == ACCEPTED
    assert station.vehicle.takeoff_altitude_m == altitude
    assert station.vehicle.mode == FlightMode.TAKEOFF


def test_take_off_below_half_a_metre_above_home_is_denied(station):
    station.state_up()
    station.client.result(ARM, 1)
    result, said = station.client.result(TAKEOFF, *[math.nan] * 6, 0.0)  # 0 m AMSL
    assert (result, said) == (DENIED, ["take-off altitude -488 m is outside [0.5, 100] m"])
    assert station.vehicle.mode == FlightMode.HOLD


def test_land_is_accepted_armed(station):
    station.flying()
    assert station.client.result(LAND, kind="int") == (ACCEPTED, [])
    assert station.vehicle.mode == FlightMode.LAND


@pytest.mark.parametrize("params, result, said", [
    (px4(4, 3), ACCEPTED, []),  # HOLD, the mode in force
    (px4(3), TEMPORARILY_REJECTED, ["posctl denied: no manual control input"]),
    (px4(2), TEMPORARILY_REJECTED, ["altctl denied: no manual control input"]),
    (px4(7), TEMPORARILY_REJECTED, ["stabilized denied: no manual control input"]),
    (px4(42), DENIED, ["unknown mode 42/0"]),
    (px4(4, 9), DENIED, ["unknown mode 4/9"]),
    (px4(4, 4), DENIED, ["mission denied: no mission uploaded"]),
    (px4(4, 5), TEMPORARILY_REJECTED, ["return denied: not in the air"]),
    ((0.0, 4.0, 3.0), DENIED, ["only custom modes are supported"]),
    ((float(CUSTOM), math.nan, 0.0), DENIED, ["mode parameters must be finite"]),
    (px4(6), TEMPORARILY_REJECTED, ["offboard denied: no setpoint stream"]),
    (px4(4, 2), TEMPORARILY_REJECTED, ["take-off denied: disarmed"]),
    (px4(4, 6), TEMPORARILY_REJECTED, ["landing denied: disarmed"]),
    (px4(6, 1), DENIED, ["no reference generator configured"]),  # REFERENCE
    (px4(4, 1), DENIED, ["unknown mode 4/1"]),  # AUTO.READY: not a mode of ours
])
@pytest.mark.parametrize("kind", ["long", "int"])
def test_px4_mode_changes_disarmed(station, params, result, said, kind):
    station.state_up()
    assert station.client.result(SET_MODE, *params, kind=kind) == (result, said)
    assert station.vehicle.mode == FlightMode.HOLD


def test_px4_mode_changes_armed_in_the_air_and_set_mode_acknowledged_as_do_set_mode(station):
    station.flying()
    for mode in (FlightMode.LAND, FlightMode.HOLD, FlightMode.TAKEOFF):
        station.client.send(M.MAVLink_set_mode_message(1, CUSTOM, px4_custom_mode(mode)))
        msgs = station.client.sync()
        acks = of_type(msgs, "COMMAND_ACK")
        assert [(a.command, a.result) for a in acks] == [(SET_MODE, ACCEPTED)]
        assert station.vehicle.mode == mode and texts(msgs) == []
    assert station.vehicle.takeoff_altitude_m == DEFAULTS["MIS_TAKEOFF_ALT"]


def test_offboard_is_accepted_with_a_setpoint_stream(station):
    station.flying()
    station.client.send(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000, 1.0, 2.0, -3.0, 0, 0, 0, 0, 0, 0, 0,
        0))
    station.client.sync()
    station.at(T0 + 0.5)
    assert station.client.result(SET_MODE, *px4(6)) == (ACCEPTED, [])
    assert station.vehicle.mode == FlightMode.OFFBOARD
    assert np.array_equal(station.vehicle.setpoint.position_ned_m, [1.0, 2.0, -3.0])


def test_ardupilot_modes_and_take_off_above_home_in_guided():
    """Copter boots in STABILIZE; refusals are MAV_RESULT_FAILED with Copter's words
    (tests/autopilot/test_copter_modes.py has the rest of its rules)."""
    failed = M.MAV_RESULT_FAILED
    s = Station(flavour="ardupilot")
    try:
        s.state_up()
        heartbeat = s.client.request(M.MAVLINK_MSG_ID_HEARTBEAT)
        assert (heartbeat.autopilot, heartbeat.custom_mode) == (M.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                                 0)
        assert s.client.result(SET_MODE, CUSTOM, 99) == (failed, ["No such mode 99"])
        assert s.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
        assert s.vehicle.mode == FlightMode.HOLD
        assert s.client.result(ARM, 1)[0] == ACCEPTED
        assert s.client.result(TAKEOFF, *[0.0] * 6, 3.0) == (failed,
                                                           ["take-off needs GUIDED mode"])
        assert s.client.result(SET_MODE, CUSTOM, 4)[0] == ACCEPTED
        assert s.client.result(TAKEOFF, *[0.0] * 6, 3.0)[0] == ACCEPTED  # above home
        assert s.vehicle.takeoff_altitude_m == 3.0 and s.vehicle.mode == FlightMode.GUIDED
    finally:
        s.close()


# -- requests and unsupported commands ----------------------------------------------------
@pytest.mark.parametrize("kind", ["long", "int"])
def test_request_message_answers_after_the_ack(station, kind):
    station.client.send_command(REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, kind=kind)
    msgs = station.client.sync()
    assert [m.get_type() for m in msgs] == ["COMMAND_ACK", "AUTOPILOT_VERSION"]
    assert msgs[0].result == ACCEPTED
    caps = msgs[1].capabilities
    for bit in (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
                M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT,
                M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET,
                M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED):
        assert caps & bit
    assert not caps & M.MAV_PROTOCOL_CAPABILITY_FTP
    ack, others = station.client.command(REQUEST_MESSAGE, M.MAVLINK_MSG_ID_ATTITUDE, kind=kind)
    assert ack.result == ACCEPTED and [m.get_type() for m in others] == ["ATTITUDE"]
    ack, others = station.client.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1,
                                         kind=kind)
    assert ack.result == ACCEPTED and [m.get_type() for m in others] == ["AUTOPILOT_VERSION"]


@pytest.mark.parametrize("msg_id", [395, 0xFFFF, M.MAVLINK_MSG_ID_PARAM_VALUE])
def test_request_message_for_what_is_not_produced_is_denied(station, msg_id):
    assert station.client.result(REQUEST_MESSAGE, msg_id) == (
        DENIED, [f"message {msg_id} is not produced"])


@pytest.mark.parametrize("command, params", [
    (REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_HOME_POSITION,)),
    (M.MAV_CMD_GET_HOME_POSITION, ())])
def test_home_position_on_request(station, command, params):
    ack, others = station.client.command(command, *params)
    assert ack.result == ACCEPTED
    (home,) = others
    assert home.get_type() == "HOME_POSITION"
    assert (home.latitude, home.longitude, home.altitude) == (
        round(DEFAULT_HOME.lat_deg * 1e7), round(DEFAULT_HOME.lon_deg * 1e7),
        round(DEFAULT_HOME.alt_amsl_m * 1000))


@pytest.mark.parametrize("kind", ["long", "int"])
@pytest.mark.parametrize("command", [M.MAV_CMD_USER_1, M.MAV_CMD_DO_SET_SERVO,
                                     M.MAV_CMD_DO_SET_RELAY])
def test_unsupported_commands_get_unsupported(station, command, kind):
    station.state_up()
    ack, others = station.client.command(command, 1, kind=kind)
    assert ack.result == UNSUPPORTED and others == []
    assert not station.vehicle.armed


def test_commands_for_another_system_are_not_answered(station):
    station.state_up()
    ack, others = station.client.command(ARM, 1, target=7)
    assert ack is None and others == [] and not station.vehicle.armed
    assert station.server.commands.handled == 0


@pytest.mark.parametrize("value", [math.nan, math.inf])
@pytest.mark.parametrize("command", [REQUEST_MESSAGE, SET_INTERVAL],
                         ids=["REQUEST_MESSAGE", "SET_MESSAGE_INTERVAL"])
def test_a_non_finite_message_id_is_denied(station, command, value):
    assert station.client.result(command, value, 0)[0] == DENIED


# -- message intervals and the telemetry streams -------------------------------------------
STREAMS = {"HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "EXTENDED_SYS_STATE": 1.0, "ATTITUDE": 0.05,
           "ATTITUDE_QUATERNION": 0.05, "LOCAL_POSITION_NED": 0.05,
           "GLOBAL_POSITION_INT": 0.1, "HOME_POSITION": 5.0, "VFR_HUD": 0.25,
           "ESTIMATOR_STATUS": 1.0, "MISSION_CURRENT": 1.0, "GPS_RAW_INT": 1.0}


def stream_counts(s: Station, start: float, seconds: float, every: float = 0.005,
                  client: Client | None = None) -> Counter:
    """Service every ``every`` s of link clock (as the process does, every 5 ms) over
    [start, start + seconds): what the client got, by type."""
    client = client or s.client
    client.sync()  # what came before does not count
    got: Counter = Counter()
    n = round(seconds / every)
    for k in range(n):
        s.service(start + k * every)
        if k % 100 == 99 or k == n - 1:
            got.update(m.get_type() for m in client.sync())
    return got


def test_every_stream_at_its_default_rate(station):
    station.state_up()
    station.client.heartbeat()  # a peer now: it hears the telemetry
    station.client.sync()
    got = stream_counts(station, T0, 3.0)
    assert got == {"STATUSTEXT": 1,  # "simulator link up"
                   **{name: round(3.0 / every) if every < 3.0 else 1
                      for name, every in STREAMS.items()}}


def test_heartbeat_every_second_exactly_on_the_link_clock(station):
    station.client.heartbeat()
    station.client.sync()
    station.service(T0)
    assert len(of_type(station.client.sync(), "HEARTBEAT")) == 1
    for t, expected in ((T0 + 1.0 - EPS, 0), (T0 + 1.0, 1), (T0 + 2.0 - EPS, 0), (T0 + 2.0, 1)):
        station.service(t)
        assert len(of_type(station.client.sync(), "HEARTBEAT")) == expected, t


def test_a_late_service_does_not_shift_the_schedule_and_a_stall_sends_no_burst(station):
    station.client.heartbeat()
    station.client.sync()
    for t, expected in ((T0, 1), (T0 + 1.003, 1), (T0 + 2.0 - EPS, 0), (T0 + 2.0, 1)):
        station.service(t)
        assert len(of_type(station.client.sync(), "HEARTBEAT")) == expected, t
    # Five seconds late: the missed heartbeats are not all sent. (The schedule restarts
    # from now, which sends one more at the next service, 5 ms later.)
    got = stream_counts(station, T0 + 7.5, 0.5)
    assert 1 <= got["HEARTBEAT"] <= 2


def test_an_arming_or_mode_change_sends_a_heartbeat_at_once_and_restarts_its_second(station):
    station.state_up()
    station.client.heartbeat()
    station.client.sync()
    station.service(T0)
    first = of_type(station.client.sync(), "HEARTBEAT")[0]
    assert not first.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert first.system_status == M.MAV_STATE_STANDBY
    station.at(T0 + 0.25)
    station.client.result(ARM, 1)
    station.service()
    msgs = station.client.sync()
    (heartbeat,) = of_type(msgs, "HEARTBEAT")
    assert heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert heartbeat.system_status == M.MAV_STATE_ACTIVE
    assert main_sub(heartbeat) == (4, 3)
    assert of_type(msgs, "EXTENDED_SYS_STATE")[0].landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert texts(msgs) == ["armed"]  # the vehicle's announcement, broadcast
    station.service(T0 + 1.0)  # the old schedule no longer holds
    assert of_type(station.client.sync(), "HEARTBEAT") == []
    station.service(T0 + 1.25)
    assert len(of_type(station.client.sync(), "HEARTBEAT")) == 1


def test_set_message_interval_per_link(make_station):
    s = make_station(n_links=2)
    api = s.new_client(1)
    s.state_up()
    for client in (s.client, api):
        client.heartbeat()
        client.sync()
    att = M.MAVLINK_MSG_ID_ATTITUDE
    s.at(T0)
    assert s.client.result(SET_INTERVAL, att, 200_000) == (ACCEPTED, [])  # 5 Hz
    got = stream_counts(s, T0, 1.0)
    assert got["ATTITUDE"] == 5
    assert stream_counts(s, T0 + 1.0, 1.0, client=api)["ATTITUDE"] == 20  # the other link
    assert s.client.result(SET_INTERVAL, att, -1) == (ACCEPTED, [])  # stop
    assert stream_counts(s, T0 + 2.0, 1.0)["ATTITUDE"] == 0
    assert s.client.result(SET_INTERVAL, att, 0) == (ACCEPTED, [])  # the default again
    assert stream_counts(s, T0 + 3.0, 1.0)["ATTITUDE"] == 20
    assert s.client.result(SET_INTERVAL, att, 1) == (ACCEPTED, [])  # 1 us: at most 200 Hz
    assert stream_counts(s, T0 + 4.0, 0.5, every=0.001)["ATTITUDE"] == 100
    assert s.client.result(SET_INTERVAL, M.MAVLINK_MSG_ID_SCALED_IMU, 100_000) == (
        DENIED, [f"message {M.MAVLINK_MSG_ID_SCALED_IMU} is not produced"])
    assert s.client.result(SET_INTERVAL, att, -5) == (DENIED, ["interval -5 us is invalid"])
    assert s.client.result(SET_INTERVAL, att, math.inf) == (DENIED,
                                                            ["interval must be finite"])
    # A stream stopped with -1 can be started with an interval.
    assert s.client.result(SET_INTERVAL, M.MAVLINK_MSG_ID_VFR_HUD, -1)[0] == ACCEPTED
    assert s.client.result(SET_INTERVAL, M.MAVLINK_MSG_ID_VFR_HUD, 500_000)[0] == ACCEPTED
    assert stream_counts(s, T0 + 5.0, 2.0)["VFR_HUD"] == 4


def test_an_autopilot_version_stream_is_sent_or_refused(station):
    station.client.heartbeat()
    result, _ = station.client.result(SET_INTERVAL, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                      1_000_000)
    station.service(T0)
    got = station.client.sync()
    assert result == DENIED or of_type(got, "AUTOPILOT_VERSION")


def test_telemetry_shows_the_vehicle_state(station):
    request = station.client.request
    ext, sys_status = M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, M.MAVLINK_MSG_ID_SYS_STATUS
    status = request(sys_status)
    assert status.onboard_control_sensors_health == 0  # no simulator: nothing is healthy
    station.state_up()
    status = request(sys_status)
    assert status.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    assert status.onboard_control_sensors_health & M.MAV_SYS_STATUS_SENSOR_GPS
    assert request(ext).landed_state == M.MAV_LANDED_STATE_ON_GROUND
    station.client.result(ARM, 1)
    station.client.result(TAKEOFF, *[math.nan] * 7)
    station.state_up(air(1.0), 1.0)
    assert request(ext).landed_state == M.MAV_LANDED_STATE_TAKEOFF
    local = request(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
    assert local.z == -1.0
    position = request(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    assert position.relative_alt == 1000
    assert position.alt == round((DEFAULT_HOME.alt_amsl_m + 1) * 1e3)
    station.vehicle.set_mode(FlightMode.HOLD, T0)
    assert request(ext).landed_state == M.MAV_LANDED_STATE_IN_AIR
    station.client.result(LAND)
    assert request(ext).landed_state == M.MAV_LANDED_STATE_LANDING
    heartbeat = request(M.MAVLINK_MSG_ID_HEARTBEAT)
    assert main_sub(heartbeat) == (4, 6) and heartbeat.type == M.MAV_TYPE_QUADROTOR
    assert heartbeat.autopilot == M.MAV_AUTOPILOT_PX4


# -- parameters ------------------------------------------------------------------------
INT32, REAL32 = M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32
PX4_INT32 = {"COM_DL_LOSS_T", "NAV_DLL_ACT", "COM_OBL_ACT", "SYS_FAILURE_EN", "GF_ACTION",
             "FLW_TGT_ALT_M", "NAV_RCL_ACT", "EKF2_NOAID_TOUT"}  # PX4's own definitions


def px4_param_set(name: str, value: float, kind: int | None = None):
    """A PARAM_SET as MAVSDK sends it to PX4: an INT32 as its bytes in the float field."""
    kind = (INT32 if name in PX4_INT32 else REAL32) if kind is None else kind
    wire = int32_as_float(int(value)) if kind == INT32 else value
    return M.MAVLink_param_set_message(1, 1, name.encode(), wire, kind)


def decoded(v) -> float:
    """A PARAM_VALUE's value, byte-wise decoded for INT32 (PX4's encoding)."""
    return float(float_as_int32(v.param_value)) if v.param_type == INT32 else v.param_value


def test_param_request_list_sends_every_parameter_in_order_with_px4_types(station):
    station.client.send(M.MAVLink_param_request_list_message(1, 1))
    values = of_type(station.client.sync(), "PARAM_VALUE")
    listed = px4_parameters()  # the table without the ArduPilot-only names
    assert [v.param_id for v in values] == list(listed)
    assert [v.param_index for v in values] == list(range(len(listed)))
    assert {v.param_count for v in values} == {len(listed)}
    assert {v.param_id for v in values if v.param_type == INT32} == PX4_INT32
    assert {v.param_type for v in values if v.param_id not in PX4_INT32} == {REAL32}
    for v in values:
        assert decoded(v) == pytest.approx(DEFAULTS[v.param_id], rel=1e-6)
    # the bytes, not a cast: NAV_DLL_ACT 1 is the float 1.4e-45 (a denormal), not 1.0
    (dll,) = [v for v in values if v.param_id == "NAV_DLL_ACT"]
    assert dll.param_value == pytest.approx(1.401298e-45) and decoded(dll) == 1.0


def test_autopilot_version_declares_px4_bytewise_parameter_encoding(station):
    caps = station.client.request(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).capabilities
    assert caps & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert not caps & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST


def test_param_request_read_by_name_and_by_index(station):
    station.client.send(M.MAVLink_param_request_read_message(1, 1, b"COM_DL_LOSS_T", -1))
    station.client.send(M.MAVLink_param_request_read_message(1, 1, b"", 0))
    station.client.send(M.MAVLink_param_request_read_message(1, 1, b"NO_SUCH_PARAM", -1))
    station.client.send(M.MAVLink_param_request_read_message(1, 1, b"", 9999))
    msgs = station.client.sync()
    values = of_type(msgs, "PARAM_VALUE")
    assert [(v.param_id, decoded(v), v.param_type, v.param_index) for v in values] == [
        ("COM_DL_LOSS_T", 10.0, INT32,
         [s.name for s in PARAMETERS].index("COM_DL_LOSS_T")),
        (PARAMETERS[0].name, pytest.approx(PARAMETERS[0].default), REAL32, 0)]
    assert texts(msgs) == ["unknown parameter NO_SUCH_PARAM", "unknown parameter 9999"]


@pytest.mark.parametrize("name, value", [("COM_OF_LOSS_T", 2.5), ("COM_DL_LOSS_T", 3),
                                         ("EKF2_NOAID_TOUT", 7_000_000)])
def test_param_set_takes_effect_and_is_echoed_on_every_link(make_station, name, value):
    s = make_station(n_links=2)
    api = s.new_client(1)
    api.heartbeat()
    api.sync()
    s.client.send(px4_param_set(name, value))
    msgs = s.client.sync()
    # PX4: the answer to the setter, then the change on every link (send_untransmitted)
    assert [(v.param_id, decoded(v)) for v in of_type(msgs, "PARAM_VALUE")] == [
        (name, value)] * 2
    assert texts(msgs) == []
    assert s.vehicle.parameters[name] == value
    assert [(v.param_id, decoded(v)) for v in of_type(api.sync(), "PARAM_VALUE")] == [
        (name, value)]


@pytest.mark.parametrize("name, kind", [("SYS_FAILURE_EN", REAL32),
                                        ("COM_OF_LOSS_T", INT32)])
def test_a_param_set_of_the_wrong_type_changes_nothing_and_gets_no_value_as_px4(
        station, name, kind):
    # PX4 (mavlink_parameters.cpp) refuses a type other than the parameter's and sends
    # no PARAM_VALUE: MAVSDK's set_param_float on an INT32 times out there too.
    station.client.send(px4_param_set(name, 1.0, kind))
    msgs = station.client.sync()
    assert texts(msgs) == [f"param types mismatch: {name}"]
    assert of_type(msgs, "PARAM_VALUE") == []
    assert station.vehicle.parameters[name] == DEFAULTS[name]


@pytest.mark.parametrize("name, value, why", [
    ("ATT_LAM", math.nan, "ATT_LAM: parameter ATT_LAM must be finite and in"),
    ("ATT_LAM", 1e9, "ATT_LAM: parameter ATT_LAM must be finite and in"),
    ("GF_ACTION", 4, "GF_ACTION: parameter GF_ACTION must be one of 0, 1,"),
    ("COM_DL_LOSS_T", -7, "COM_DL_LOSS_T: parameter COM_DL_LOSS_T must be fini"),
    ("COM_OF_LOSS_T", 0.0, "COM_OF_LOSS_T: parameter COM_OF_LOSS_T must be fin")])
def test_a_refused_param_set_keeps_the_old_value_and_says_why(station, name, value, why):
    old = DEFAULTS[name]
    station.client.send(px4_param_set(name, value))
    msgs = station.client.sync()
    (said,) = texts(msgs)
    assert said.startswith(why)
    # the whole reason, range and value included, in two chunks
    assert len(said) > STATUSTEXT_CHARS and said.endswith(f"got {float(value)!r}")
    for echo in of_type(msgs, "PARAM_VALUE"):  # the value in force, answered twice
        assert (echo.param_id, decoded(echo)) == (name, pytest.approx(old))
    assert len(of_type(msgs, "PARAM_VALUE")) == 2
    assert station.vehicle.parameters[name] == old
    assert of_type(msgs, "STATUSTEXT")[0].severity == M.MAV_SEVERITY_WARNING


def test_an_integer_parameter_refuses_a_fraction_from_the_command_line():
    with pytest.raises(ValueError, match="COM_DL_LOSS_T takes whole numbers, got 2.5"):
        validate_parameters({"COM_DL_LOSS_T": 2.5})
    assert validate_parameters({"COM_DL_LOSS_T": 3.0})["COM_DL_LOSS_T"] == 3.0


def test_an_unknown_param_set_is_said_and_not_echoed(station):
    station.client.send(M.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0,
                                                    M.MAV_PARAM_TYPE_REAL32))
    msgs = station.client.sync()
    assert texts(msgs) == ["unknown parameter NO_SUCH_PARAM"]
    assert of_type(msgs, "PARAM_VALUE") == []


# -- link failsafes through the server ---------------------------------------------------
def set_param(s: Station, name: str, value: float) -> None:
    s.client.send(px4_param_set(name, value))
    s.client.sync()
    assert s.vehicle.parameters[name] == value


@pytest.mark.parametrize("timeout_s", [DEFAULTS["COM_DL_LOSS_T"], 3.0])
def test_ground_station_heartbeat_loss_lands_after_com_dl_loss_t(station, timeout_s):
    s = station
    s.flying()
    set_param(s, "COM_DL_LOSS_T", timeout_s)
    set_param(s, "NAV_DLL_ACT", 3)
    s.at(T0 + 0.5)
    s.client.heartbeat()
    s.client.sync()
    s.service(T0 + 0.5 + timeout_s - EPS)
    assert not s.vehicle.gcs_lost
    assert texts(s.client.sync()) == []
    s.service(T0 + 0.5 + timeout_s + EPS)
    msgs = s.client.sync()
    assert texts(msgs) == ["ground station lost: land", "mode land"]
    assert of_type(msgs, "STATUSTEXT")[0].severity == M.MAV_SEVERITY_WARNING
    (heartbeat,) = of_type(msgs, "HEARTBEAT")  # at once: the mode changed
    assert main_sub(heartbeat) == (4, 6) and heartbeat.system_status == M.MAV_STATE_CRITICAL
    s.at(T0 + 20.0)
    s.client.heartbeat()
    s.client.sync()
    s.service()
    assert texts(s.client.sync()) == ["ground station link regained"]
    assert s.vehicle.mode == FlightMode.LAND


def test_only_ground_station_heartbeats_feed_the_failsafe(station):
    s = station
    s.flying()
    companion = s.new_client(sysid=1, compid=M.MAV_COMP_ID_ONBOARD_COMPUTER)
    companion.heartbeat(M.MAV_TYPE_ONBOARD_CONTROLLER)
    companion.sync()
    assert s.vehicle.links.gcs_heard_s is None
    planner = s.new_client(sysid=254, compid=M.MAV_COMP_ID_MISSIONPLANNER)
    planner.heartbeat(M.MAV_TYPE_GENERIC)  # a mission planner's component counts
    planner.sync()
    assert s.vehicle.links.gcs_heard_s == T0


def test_offboard_setpoint_loss_holds_after_com_of_loss_t(station):
    s = station
    s.flying()

    def setpoint(z: float) -> None:
        s.client.send(M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000, 0.0, 0.0, z, 0, 0, 0, 0, 0, 0,
            0, 0))
        s.client.sync()

    setpoint(-2.5)
    assert s.client.result(SET_MODE, *px4(6))[0] == ACCEPTED
    s.at(T0 + 0.5)
    setpoint(-2.5)  # the stream's last good setpoint
    s.service()
    s.client.sync()
    s.at(T0 + 1.25)
    setpoint(math.nan)  # refused: it does not keep the stream alive
    s.service(T0 + 0.5 + 1.0 - EPS)
    assert texts(s.client.sync()) == [] and s.vehicle.mode == FlightMode.OFFBOARD
    s.service(T0 + 0.5 + 1.0 + EPS)
    msgs = s.client.sync()
    assert texts(msgs) == ["offboard setpoints lost: hold", "mode hold"]
    assert main_sub(of_type(msgs, "HEARTBEAT")[0]) == (4, 3)


def test_refused_setpoints_are_said_at_most_once_a_second(station):
    s = station
    s.flying()
    got = []
    for t in (0.0, 0.5, 0.999, 1.0, 1.5, 2.25):
        s.at(T0 + t)
        s.client.send(M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000, 0.0, 0.0, math.nan, 0, 0, 0, 0,
            0, 0, 0, 0))
        got.append(texts(s.client.sync()))
    said = ["setpoint refused: setpoint position holds NaN or infinity"]
    assert got == [said, [], [], said, [], said]
    s.client.send(M.MAVLink_set_attitude_target_message(
        0, 1, 1, 0, [1.0, 0.0, 0.0, 0.0], 0.1, 0.0, 0.0, 0.5))
    s.at(T0 + 5.0)
    assert texts(s.client.sync()) == ["setpoint refused: body-rate setpoints are not "
                                          "supported"]
    assert s.vehicle.links.setpoint_heard_s is None


def test_a_failsafe_that_is_over_does_not_mark_the_next_flight_critical(station):
    s = station
    s.flying()
    s.vehicle.sim_link_lost()  # -> LAND
    s.state_up(GROUND, 0.5)  # the simulator is back, the vehicle on the ground
    s.state_up(GROUND, 0.5 + DEFAULTS["COM_DISARM_LAND"])
    assert not s.vehicle.armed
    assert s.client.result(ARM, 1)[0] == ACCEPTED
    heartbeat = s.client.request(M.MAVLINK_MSG_ID_HEARTBEAT)
    assert heartbeat.system_status == M.MAV_STATE_ACTIVE


# -- other protocols -----------------------------------------------------------------------
def test_ftp_gets_a_nak_missions_are_empty_and_timesync_answers_on_the_link_clock(station):
    payload = [0] * 251
    payload[0:4] = [7, 0, 3, 5]  # seq 7, session 3, OpenFileRO
    station.client.send(M.MAVLink_file_transfer_protocol_message(0, 1, 1, payload))
    station.client.send(M.MAVLink_mission_request_list_message(1, 1, 0))
    station.at(T0 + 2.5)
    station.client.send(M.MAVLink_timesync_message(0, 123456789))
    station.client.send(M.MAVLink_timesync_message(5, 42))  # an answer: not answered
    nak, count, timesync = station.client.sync()
    assert nak.get_type() == "FILE_TRANSFER_PROTOCOL"
    assert (nak.payload[0], nak.payload[2], nak.payload[3], nak.payload[5], nak.payload[12]) \
        == (8, 3, 129, 5, 4)  # seq + 1, session, NAK for OpenFileRO: unsupported
    assert count.get_type() == "MISSION_COUNT" and count.count == 0
    assert (timesync.tc1, timesync.ts1) == (2_500_000_000, 123456789)


# -- navigation commands, manual control, mission progress -------------------------------
REPOSITION, RETURN, MISSION_START = (M.MAV_CMD_DO_REPOSITION, M.MAV_CMD_NAV_RETURN_TO_LAUNCH,
                                     M.MAV_CMD_MISSION_START)
REL_INT = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def north_east(north_m: float, east_m: float) -> tuple[float, float]:
    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north_m, east_m, 0.0)
    return lat, lon


def test_go_to_flies_to_a_global_position_in_hold(station):
    station.flying()
    lat, lon = north_east(20.0, -5.0)
    # Yaw in radians, as PX4 and MAVSDK have it.
    result = station.client.result(REPOSITION, -1, 1, 0, math.pi / 2, lat, lon, 7.0,
                                   kind="int", frame=REL_INT)
    assert result == (ACCEPTED, [])
    v = station.vehicle
    assert v.mode == FlightMode.HOLD
    assert np.allclose(v.setpoint.position_ned_m, (20.0, -5.0, -7.0), atol=1e-2)
    assert v.setpoint.yaw_rad == pytest.approx(math.pi / 2)


def test_go_to_amsl_and_left_out_coordinates(station):
    station.flying()
    # COMMAND_LONG: altitude AMSL, latitude and longitude in float32 (0.1 m steps here);
    # COMMAND_INT x = y = INT32_MAX: stay over this point.
    result = station.client.result(REPOSITION, -1, 1, 0, math.nan, *north_east(3.0, 4.0),
                                   DEFAULT_HOME.alt_amsl_m + 6.0)
    assert result == (ACCEPTED, [])
    assert np.allclose(station.vehicle.setpoint.position_ned_m, (3.0, 4.0, -6.0), atol=0.2)
    result = station.client.result(REPOSITION, -1, 1, 0, math.nan, math.nan, math.nan, 9.0,
                                   kind="int", frame=REL_INT)
    assert result == (ACCEPTED, [])
    assert np.allclose(station.vehicle.setpoint.position_ned_m[2], -9.0)
    assert np.allclose(station.vehicle.setpoint.position_ned_m[0:2], (3.0, 4.0), atol=0.2)


@pytest.mark.parametrize("params, frame, result, said", [
    ((-1, 1, 0, 0, *north_east(5, 5), 5.0), M.MAV_FRAME_LOCAL_NED, DENIED,
     "go-to frame 1 is not supported"),
    ((-1, 1, 0, 0, 95.0, 8.0, 5.0), REL_INT, DENIED,
     "go-to latitude/longitude 95, 8 is not on Earth"),
    ((-1, 1, 0, math.inf, *north_east(5, 5), 5.0), REL_INT, DENIED,
     "go-to values must be finite or NaN"),
    ((-1, 1, 0, 0, *north_east(5, 5), math.inf), REL_INT, DENIED,
     "go-to values must be finite or NaN"),
    ((math.inf, 1, 0, 0, *north_east(5, 5), 5.0), REL_INT, DENIED,
     "go-to values must be finite or NaN"),
])
def test_bad_go_to_is_refused_and_changes_nothing(station, params, frame, result, said):
    station.flying()
    before = station.vehicle.setpoint.position_ned_m.copy()
    assert station.client.result(REPOSITION, *params, kind="int", frame=frame) == (
        result, [said])
    assert np.array_equal(station.vehicle.setpoint.position_ned_m, before)


def test_go_to_on_the_ground_is_rejected_for_now(station):
    station.state_up()
    assert station.client.result(REPOSITION, -1, 1, 0, 0, *north_east(5, 5), 5.0,
                                 kind="int", frame=REL_INT) == (
        TEMPORARILY_REJECTED, ["go-to denied: not in the air"])


def test_return_to_launch_command_and_mission_start(station):
    station.flying()
    assert station.client.result(MISSION_START, 0, 0) == (
        DENIED, ["mission denied: no mission uploaded"])
    assert station.client.result(RETURN) == (ACCEPTED, [])
    assert station.vehicle.mode == FlightMode.RTL
    assert _custom_mode(station.client) == (4, 5)
    station.vehicle.mission.replace(M.MAV_MISSION_TYPE_MISSION, tuple(
        mission_item(i, 10.0 * i, 0.0, 3.0) for i in range(3)))
    assert station.client.result(MISSION_START, 3, 0) == (
        DENIED, ["mission start: no item 3 (the mission has 3)"])
    assert station.client.result(MISSION_START, 1, 0) == (ACCEPTED, [])
    assert station.vehicle.mode == FlightMode.MISSION and station.vehicle.mission.current == 1
    assert _custom_mode(station.client) == (4, 4)


def _custom_mode(client) -> tuple[int, int]:
    client.station.service()
    hb = of_type(client.sync(), "HEARTBEAT")[-1]
    return (hb.custom_mode >> 16) & 0xFF, (hb.custom_mode >> 24) & 0xFF


def test_manual_control_is_taken_and_bad_sticks_are_refused(station):
    station.flying()
    station.client.send(M.MAVLink_manual_control_message(1, 1000, -250, 500, 0, 0))
    station.client.sync()
    sticks = station.vehicle.state.sticks
    assert sticks.forward == 1.0 and sticks.right == -0.25
    assert station.client.result(SET_MODE, *px4(3)) == (ACCEPTED, [])
    assert station.vehicle.mode == FlightMode.POSCTL
    station.client.send(M.MAVLink_manual_control_message(1, 0, 0, 1500, 0, 0))
    assert texts(station.client.sync()) == [
        "setpoint refused: manual control z 1500 is outside [0, 1000]"]
    assert station.vehicle.state.sticks.forward == 1.0  # unchanged


def test_mission_progress_is_announced_as_px4_does(station):
    station.flying()
    v = station.vehicle
    v.mission.replace(M.MAV_MISSION_TYPE_MISSION, tuple(
        mission_item(i, 10.0 * i, 0.0, 3.0) for i in range(3)))
    assert station.client.request(M.MAVLINK_MSG_ID_MISSION_CURRENT).mission_state == \
        M.MISSION_STATE_NOT_STARTED
    v.set_mode(FlightMode.MISSION, T0)
    v.reached.append(0)
    station.service()
    msgs = station.client.sync()
    assert [m.seq for m in of_type(msgs, "MISSION_ITEM_REACHED")] == [0]
    current = of_type(msgs, "MISSION_CURRENT")[-1]
    assert (current.total, current.mission_state) == (3, M.MISSION_STATE_ACTIVE)
    v.set_mode(FlightMode.HOLD, T0)
    assert station.client.request(M.MAVLINK_MSG_ID_MISSION_CURRENT).mission_state == \
        M.MISSION_STATE_PAUSED


def test_change_speed_command_sets_the_go_to_speed(station):
    station.flying()
    lat, lon = north_east(20.0, 0.0)
    assert station.client.result(REPOSITION, -1, 1, 0, math.nan, lat, lon, 3.0, kind="int",
                                 frame=REL_INT)[0] == ACCEPTED
    assert station.client.result(M.MAV_CMD_DO_CHANGE_SPEED, 1, 2.5, -1) == (ACCEPTED, [])
    assert station.vehicle.tasks[FlightMode.HOLD].speed_mps == 2.5
    assert station.client.result(M.MAV_CMD_DO_CHANGE_SPEED, 1, math.nan, -1) == (
        DENIED, ["speed nan m/s is outside (0, 30]"])
    assert station.vehicle.tasks[FlightMode.HOLD].speed_mps == 2.5


ORBIT = M.MAV_CMD_DO_ORBIT


def test_orbit_command_circles_the_centre_it_names_and_changes_it_while_orbiting(station):
    station.flying()
    lat, lon = north_east(6.0, 0.0)
    # MAVSDK's do_orbit: an AMSL altitude, even in a relative-altitude frame (as PX4 reads).
    assert station.client.result(ORBIT, 4.0, 1.5, 0, math.nan, lat, lon,
                                 DEFAULT_HOME.alt_amsl_m + 3.0, kind="int", frame=REL_INT) == (
        ACCEPTED, [])
    v = station.vehicle
    task = v.tasks[FlightMode.ORBIT]
    assert v.mode == FlightMode.ORBIT
    assert np.allclose(task.centre_ned_m, (6.0, 0.0, -3.0), atol=0.01)
    assert (task.radius_m, task.speed_mps) == (4.0, 1.5)
    assert station.client.result(ORBIT, -2.0, math.nan, 3, math.nan, math.nan, math.nan,
                                 math.nan, kind="int", frame=REL_INT) == (ACCEPTED, [])
    assert v.mode == FlightMode.ORBIT and (task.radius_m, task.speed_mps) == (-2.0, 1.5)
    assert np.allclose(task.centre_ned_m, (6.0, 0.0, -3.0), atol=0.01)  # NaN: kept


@pytest.mark.parametrize("params, frame, said", [
    ((5.0, 1.0, 0, 0, *north_east(5, 5), 500.0), M.MAV_FRAME_LOCAL_NED,
     "orbit frame 1 is not supported"),
    ((0.2, 1.0, 0, 0, *north_east(5, 5), 500.0), REL_INT,
     "orbit radius 0.2 m is outside [1, 1000] m"),
    ((5.0, math.inf, 0, 0, *north_east(5, 5), 500.0), REL_INT,
     "orbit values must be finite or NaN"),
    ((5.0, 1.0, 9, 0, *north_east(5, 5), 500.0), REL_INT,
     "orbit yaw behaviour 9 is unknown"),
    ((5.0, 1.0, 0, 0, 95.0, 8.0, 500.0), REL_INT,
     "orbit latitude/longitude 95, 8 is not on Earth"),
])
def test_bad_orbits_are_refused_and_change_nothing(station, params, frame, said):
    station.flying()
    before = station.vehicle.mode
    assert station.client.result(ORBIT, *params, kind="int", frame=frame) == (DENIED, [said])
    assert station.vehicle.mode == before


def test_orbit_on_the_ground_is_rejected_for_now_and_forgotten(station):
    station.state_up()
    assert station.client.result(ORBIT, 5.0, 1.0, 0, 0, *north_east(5, 5), 500.0,
                                 kind="int", frame=REL_INT) == (
        TEMPORARILY_REJECTED, ["orbit denied: not in the air"])
    assert station.vehicle.tasks[FlightMode.ORBIT].pending is None


def test_long_texts_get_chunk_ids_that_never_are_zero(station):
    station.client.sync()  # the client is a peer of the link
    station.server._text_id = 65534
    for _ in range(3):
        station.server.send_text(None, 4, "v" * 60)
    msgs = [m for m in station.client.sync() if m.get_type() == "STATUSTEXT"]
    assert [m.id for m in msgs] == [65535, 65535, 1, 1, 2, 2]
    assert texts(msgs) == ["v" * 60] * 3
