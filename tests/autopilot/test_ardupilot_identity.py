"""The ArduPilot flavour's identity, streams and maintenance commands as a Copter GCS sees
them: a real UDP link in the ardupilotmega dialect, the server driven by the test
(tests/mavlink_station.py). ArduCopter SITL 4.5 is the reference (docs/mavlink.md)."""

from __future__ import annotations

import dataclasses

import pytest
from pymavlink import mavutil

from autopilot.estimation.estimator import EstimatorStatus
from autopilot.mavlink.copter import CAPABILITIES, copter_version_number
from contracts.mavlink import ardupilotmega as apm
from contracts.modes import PX4_MODES, FlightMode, px4_custom_mode
from tests.mavlink_station import ACCEPTED, ARM, GROUND, T0, Station, air, of_type, texts

DENIED = apm.MAV_RESULT_DENIED


@pytest.fixture
def copter():
    """A Copter in GUIDED, where it arms without RC (it boots in STABILIZE, whose sticks
    need RC: tests/autopilot/test_copter_modes.py)."""
    s = Station(flavour="ardupilot")
    s.vehicle.set_mode(FlightMode.GUIDED, T0)
    yield s
    s.close()


def heartbeat(s: Station):
    """The HEARTBEAT the link sends now (the stream's builder)."""
    return s.server.telemetry(apm.MAVLINK_MSG_ID_HEARTBEAT)


def test_heartbeat_as_copter_sets_it(copter):
    copter.state_up()
    hb = heartbeat(copter)
    assert (hb.type, hb.autopilot) == (apm.MAV_TYPE_QUADROTOR, apm.MAV_AUTOPILOT_ARDUPILOTMEGA)
    # STABILIZE | MANUAL_INPUT | CUSTOM_MODE (16 + 64 + 1), standby on the ground.
    assert (hb.base_mode, hb.system_status, hb.custom_mode) == (81, apm.MAV_STATE_STANDBY, 4)
    assert copter.client.result(ARM, 1)[0] == ACCEPTED
    assert (heartbeat(copter).base_mode, heartbeat(copter).system_status) == (
        81 | 128, apm.MAV_STATE_STANDBY)  # armed on the ground: still STANDBY
    copter.state_up(air(), 0.01)
    hb = heartbeat(copter)  # flying GUIDED: the position controller runs
    assert (hb.base_mode, hb.system_status) == (81 | 128 | 8, apm.MAV_STATE_ACTIVE)


def test_autopilot_version_is_copters(copter):
    msg = copter.client.request(apm.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert msg.capabilities == CAPABILITIES
    assert not msg.capabilities & apm.MAV_PROTOCOL_CAPABILITY_FTP
    assert msg.flight_sw_version == copter_version_number() == 0x040507FF
    assert bytes(msg.flight_custom_version) == b"ivfmsitl"


def test_banner_says_the_firmware_and_the_frame(copter):
    ack, others = copter.client.command(apm.MAV_CMD_DO_SEND_BANNER)
    assert ack.result == ACCEPTED
    assert texts(others) == ["ArduCopter V4.5.7 (ivfmsitl)", "Frame: QUAD/X"]


def test_the_banner_comes_with_a_parameter_list_request(copter, station):
    copter.client.send(apm.MAVLink_param_request_list_message(1, 1))
    msgs = copter.client.sync()
    assert texts(msgs) == ["ArduCopter V4.5.7 (ivfmsitl)", "Frame: QUAD/X"]
    assert msgs[0].get_type() == "STATUSTEXT" and len(of_type(msgs, "PARAM_VALUE")) > 50
    station.client.send(apm.MAVLink_param_request_list_message(1, 1))
    assert texts(station.client.sync()) == []  # PX4 says nothing


def stream_ids(s: Station, seconds: float) -> dict[str, int]:
    counts: dict[str, int] = {}
    t = s.clock.t
    for _ in range(int(seconds / 0.01)):
        t += 0.01
        s.service(t)
    for m in s.client.sync():
        if m.get_type() != "STATUSTEXT":
            counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    return counts


def test_only_heartbeats_until_a_tool_asks_then_the_groups_at_their_rates(copter):
    copter.state_up()
    copter.client.heartbeat()
    copter.client.sync()  # now a peer of the link
    assert stream_ids(copter, 2.0) == {"HEARTBEAT": 2}
    copter.client.send(apm.MAVLink_request_data_stream_message(
        1, 1, apm.MAV_DATA_STREAM_ALL, 4, 1))
    copter.client.sync()
    counts = stream_ids(copter, 2.0)
    for name in ("SYS_STATUS", "MISSION_CURRENT", "GPS_RAW_INT", "SERVO_OUTPUT_RAW",
                 "RC_CHANNELS", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE",
                 "VFR_HUD", "EKF_STATUS_REPORT"):
        assert counts[name] in (8, 9), (name, counts)  # 4 Hz for 2 s
    copter.client.send(apm.MAVLink_request_data_stream_message(
        1, 1, apm.MAV_DATA_STREAM_POSITION, 0, 1))  # rate 0 stops the group
    copter.client.send(apm.MAVLink_request_data_stream_message(
        1, 1, apm.MAV_DATA_STREAM_EXTRA1, 10, 0))  # start_stop 0 stops too
    copter.client.sync()
    counts = stream_ids(copter, 1.0)
    assert "GLOBAL_POSITION_INT" not in counts and "ATTITUDE" not in counts
    assert counts["VFR_HUD"] in (4, 5) and counts["HEARTBEAT"] == 1


def test_gps_ekf_rc_and_servo_messages_on_the_ground(copter):
    copter.state_up()
    gps = copter.client.request(apm.MAVLINK_MSG_ID_GPS_RAW_INT)
    assert (gps.fix_type, gps.satellites_visible, gps.eph) == (3, 10, 121)
    assert (gps.lat, gps.lon) == (round(copter.vehicle.places.home.lat_deg * 1e7),
                                  round(copter.vehicle.places.home.lon_deg * 1e7))
    ekf = copter.client.request(apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT)
    assert ekf.flags == 0x33F  # healthy on the simulator's truth, as SITL's
    rc = copter.client.request(apm.MAVLINK_MSG_ID_RC_CHANNELS)
    assert (rc.chancount, rc.chan1_raw, rc.chan18_raw) == (0, 0, 0)  # no RC
    servo = copter.client.request(apm.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
    assert [servo.servo1_raw, servo.servo4_raw, servo.servo5_raw] == [1000, 1000, 0]


def test_ekf_uninitialised_without_the_simulator(copter):
    assert copter.client.request(apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT).flags == \
        apm.EKF_UNINITIALIZED
    gps = copter.client.request(apm.MAVLINK_MSG_ID_GPS_RAW_INT)
    assert (gps.fix_type, gps.satellites_visible) == (apm.GPS_FIX_TYPE_NO_FIX, 0)


def test_home_position_sent_when_home_is_set(copter):
    copter.state_up()
    copter.client.heartbeat()
    copter.client.sync()
    copter.service(T0)
    copter.client.sync()
    assert of_type(copter.client.sync(), "HOME_POSITION") == []  # not known yet
    copter.vehicle.set_origin(copter.vehicle.places.origin)
    copter.service(T0 + 0.01)
    (home,) = of_type(copter.client.sync(), "HOME_POSITION")
    assert home.latitude == round(copter.vehicle.places.home.lat_deg * 1e7)
    copter.service(T0 + 0.02)
    assert of_type(copter.client.sync(), "HOME_POSITION") == []  # once per change


def test_reboot_refused_armed_then_restarts_the_vehicle_keeping_parameters(copter):
    copter.state_up()
    copter.vehicle.set_origin(copter.vehicle.places.origin)
    copter.vehicle.set_parameter("MPC_XY_VEL_MAX", 7.0)
    assert copter.client.result(ARM, 1)[0] == ACCEPTED
    assert copter.client.result(apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == (
        DENIED, ["reboot denied: armed"])
    assert copter.client.result(ARM, 0)[0] == ACCEPTED
    copter.client.send(apm.MAVLink_request_data_stream_message(1, 1, 0, 4, 1))
    ack, _ = copter.client.command(apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
    assert ack.result == ACCEPTED
    copter.service(T0 + 1.0)
    said = texts(copter.client.sync())
    assert said[-3:] == ["rebooted", "ArduCopter V4.5.7 (ivfmsitl)", "Frame: QUAD/X"]
    v = copter.vehicle
    assert not v.armed and not v.home_known and v.parameters["MPC_XY_VEL_MAX"] == 7.0
    assert copter.links[0].intervals_s == {apm.MAVLINK_MSG_ID_HEARTBEAT: 1.0}
    assert copter.client.result(apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 3)[0] == \
        apm.MAV_RESULT_UNSUPPORTED


def test_a_reboot_overtaken_by_an_arming_is_cancelled(copter):
    copter.state_up()
    copter.client.send_command(apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
    copter.client.send_command(ARM, 1)  # read in the same batch, before the server services
    acks = of_type(copter.client.sync(), "COMMAND_ACK")
    assert [(a.command, a.result) for a in acks] == [
        (apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, ACCEPTED), (ARM, ACCEPTED)]
    copter.service(T0 + 0.01)
    assert "reboot cancelled: armed" in texts(copter.client.sync())
    assert copter.vehicle.armed


@pytest.mark.parametrize("params, said", [
    ((1,), []), ((0, 0, 0, 0, 1), []), ((0, 0, 0, 0, 2), []), ((0, 0, 0, 0, 4), []),
    ((0, 0, 1), ["Updating barometer calibration", "Barometer calibration complete"])])
def test_calibrations_complete_at_once_disarmed(copter, params, said):
    copter.state_up()
    assert copter.client.result(apm.MAV_CMD_PREFLIGHT_CALIBRATION, *params) == (
        ACCEPTED, said)


def test_bad_or_armed_calibrations_are_refused(copter):
    copter.state_up()
    cal = apm.MAV_CMD_PREFLIGHT_CALIBRATION
    assert copter.client.result(cal, float("nan"))[0] == DENIED
    assert copter.client.result(cal, 0, 0, 0, 1) == (  # RC calibration: not here
        apm.MAV_RESULT_UNSUPPORTED, ["calibration param4 1 is not supported"])
    assert copter.client.result(ARM, 1)[0] == ACCEPTED
    assert copter.client.result(cal, 1) == (DENIED, ["calibration denied: armed"])


def test_mag_cal_reports_success_at_once(copter):
    copter.state_up()
    ack, others = copter.client.command(apm.MAV_CMD_DO_START_MAG_CAL, 0, 1, 1)
    assert ack.result == ACCEPTED
    (report,) = of_type(others, "MAG_CAL_REPORT")
    assert (report.cal_status, report.autosaved) == (apm.MAG_CAL_SUCCESS, 1)
    assert copter.client.result(apm.MAV_CMD_DO_ACCEPT_MAG_CAL)[0] == ACCEPTED
    assert copter.client.result(apm.MAV_CMD_DO_CANCEL_MAG_CAL)[0] == ACCEPTED


def test_prearm_checks_say_what_fails_and_set_the_bit(copter):
    ack, others = copter.client.command(apm.MAV_CMD_RUN_PREARM_CHECKS)
    assert ack.result == ACCEPTED
    assert texts(others) == ["PreArm: no state from the simulator"]
    (status,) = of_type(others, "SYS_STATUS")
    assert not status.onboard_control_sensors_health & apm.MAV_SYS_STATUS_PREARM_CHECK
    copter.state_up(GROUND)
    ack, others = copter.client.command(apm.MAV_CMD_RUN_PREARM_CHECKS)
    assert texts(others) == []
    (status,) = of_type(others, "SYS_STATUS")
    assert status.onboard_control_sensors_health & apm.MAV_SYS_STATUS_PREARM_CHECK


def test_px4_flavour_answers_reboot_and_calibration_but_not_ardupilot_commands(station):
    station.state_up()
    assert station.client.result(apm.MAV_CMD_PREFLIGHT_CALIBRATION, 1, 0, 1) == (ACCEPTED, [
        "[cal] calibration started: 2 gyro", "[cal] calibration done: gyro",
        "[cal] calibration started: 2 baro", "[cal] calibration done: baro"])
    assert station.client.result(apm.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)[0] == ACCEPTED
    assert station.client.result(42428)[0] == apm.MAV_RESULT_UNSUPPORTED  # DO_SEND_BANNER
    gps = station.client.request(apm.MAVLINK_MSG_ID_GPS_RAW_INT)
    assert gps.fix_type == 3


def test_rc_channels_and_servo_outputs_follow_the_vehicle(copter):
    copter.flying()
    ignore = 65535  # channels 5-8 left alone; 9-18 (0) too
    copter.client.send(apm.MAVLink_rc_channels_override_message(
        1, 1, 1500, 1500, 1000, 1500, *[ignore] * 4, *[0] * 10))
    copter.client.sync()
    assert copter.vehicle.rc_channels_pwm[:5] == (1500, 1500, 1000, 1500, 0)
    rc = copter.client.request(apm.MAVLINK_MSG_ID_RC_CHANNELS)
    assert (rc.chancount, rc.chan1_raw, rc.chan3_raw, rc.chan5_raw) == (4, 1500, 1000, 0)
    copter.vehicle.step(0.02, air())
    commands = copter.vehicle.last_commands
    servo = copter.client.request(apm.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
    pwm = [servo.servo1_raw, servo.servo2_raw, servo.servo3_raw, servo.servo4_raw]
    assert pwm == [round(1000 + 1000 * c) for c in commands] and min(pwm) > 1000


ALIGNED = EstimatorStatus(
    aligned=True, converged=True, gps_ok=True, since_gps_s=0.1, reason="",
    tilt_sigma_rad=0.01, yaw_sigma_rad=0.02, horizontal_sigma_m=0.5, vertical_sigma_m=0.8,
    velocity_sigma_mps=0.1, gps_test_ratio=0.3, gps_position_test_ratio=0.25,
    gps_velocity_test_ratio=0.2, baro_test_ratio=0.1, mag_test_ratio=0.05, gps_rejected=0,
    gps_late=0)


@pytest.mark.parametrize("change, flags", [
    ({}, 0x33F),  # fused: what SITL's EKF3 reports healthy
    ({"gps_ok": False, "since_gps_s": 3.0},  # dead reckoning: no absolute position
     apm.EKF_ATTITUDE | apm.EKF_VELOCITY_VERT | apm.EKF_POS_VERT_ABS | apm.EKF_CONST_POS_MODE),
    ({"gps_test_ratio": 1.5}, 0x33F | apm.EKF_GPS_GLITCHING),
    ({"aligned": False, "gps_ok": False}, apm.EKF_UNINITIALIZED),
])
def test_ekf_status_report_from_the_onboard_estimator(copter, change, flags):
    copter.state_up()
    copter.vehicle.estimator_status = dataclasses.replace(ALIGNED, **change)
    ekf = copter.client.request(apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT)
    assert ekf.flags == flags
    s = copter.vehicle.estimator_status
    assert [ekf.velocity_variance, ekf.pos_horiz_variance, ekf.pos_vert_variance,
            ekf.compass_variance] == pytest.approx(
        [s.gps_velocity_test_ratio, s.gps_position_test_ratio, s.baro_test_ratio,
         s.mag_test_ratio])
    gps = copter.client.request(apm.MAVLINK_MSG_ID_GPS_RAW_INT)
    assert gps.fix_type == (3 if s.gps_ok else apm.GPS_FIX_TYPE_NO_FIX)


def test_every_px4_mode_has_a_pymavlink_name():
    """DroneKit raises in its HEARTBEAT handler on a PX4 mode pymavlink cannot name; the
    paper's REFERENCE reads as OFFBOARD and DO_SET_MODE tells it apart by sub mode 1."""
    names = {mode: mavutil.interpret_px4_mode(0, px4_custom_mode(mode)) for mode in PX4_MODES}
    assert "UNKNOWN" not in names.values()
    assert names[FlightMode.REFERENCE] == "OFFBOARD"
    assert names[FlightMode.HOLD] == "LOITER" and names[FlightMode.MISSION] == "MISSION"


def test_unknown_message_ids_are_skipped_on_the_copter_link(copter):
    """An ArduPilot-only message on the PX4 link and a future one on either: counted."""
    px4 = Station()
    try:
        ekf = apm.MAVLink_ekf_status_report_message(0, 0, 0, 0, 0, 0, 0)
        for s in (px4, copter):
            s.client.send(ekf)
            s.client.sync()
        assert px4.links[0].counters.unknown == 1  # not in the common dialect
        assert copter.links[0].counters.unknown == 0  # known (and ignored) here
    finally:
        px4.close()
