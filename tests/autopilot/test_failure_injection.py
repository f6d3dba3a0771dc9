"""MAV_CMD_INJECT_FAILURE from a ground tool over a real socket, as PX4: refused unless
SYS_FAILURE_EN is 1; sensor failures (off, stuck, garbage, wrong, slow, intermittent)
and motor failures applied inside the flight stack, announced, and cleared with OK;
every other unit or type refused as unsupported, changing nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.commander.failures import InjectedFailures, UnsupportedError
from tests.autopilot.test_mavlink_server import DENIED, UNSUPPORTED
from tests.mavlink_station import ACCEPTED, M, Station, texts

INJECT = M.MAV_CMD_INJECT_FAILURE
GPS, MOTOR, BARO = (M.FAILURE_UNIT_SENSOR_GPS, M.FAILURE_UNIT_SYSTEM_MOTOR,
                    M.FAILURE_UNIT_SENSOR_BARO)
OK, OFF, STUCK = M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF, M.FAILURE_TYPE_STUCK
DELAYED = M.FAILURE_TYPE_DELAYED


@pytest.fixture
def enabled(make_station):
    return make_station(SYS_FAILURE_EN=1.0)


def _said(station: Station) -> list[str]:
    station.service()
    return texts(station.client.sync())


def test_refused_while_sys_failure_en_is_0(station):
    assert station.client.result(INJECT, GPS, OFF, 0) == (
        DENIED, ["failure injection disabled: set SYS_FAILURE_EN to 1"])
    assert not station.vehicle.failures.any


def test_gps_off_then_ok(enabled):
    assert enabled.client.result(INJECT, GPS, OFF, 0)[0] == ACCEPTED
    assert enabled.vehicle.failures.failed(GPS) == OFF
    assert _said(enabled) == ["failure injected: GPS off"]
    assert enabled.client.result(INJECT, GPS, OK, 0)[0] == ACCEPTED
    assert enabled.vehicle.failures.failed(GPS) == OK


def test_one_motor_off_holds_its_output_at_zero(enabled):
    assert enabled.client.result(INJECT, MOTOR, OFF, 2)[0] == ACCEPTED
    assert enabled.vehicle.failures.motors_off == {1}
    assert _said(enabled) == ["failure injected: motor 2 off"]
    out = enabled.vehicle.failures.motor_outputs(np.array([0.5, 0.6, 0.7, 0.8]))
    assert out.tolist() == [0.5, 0.0, 0.7, 0.8]
    assert enabled.client.result(INJECT, MOTOR, OK, 0)[0] == ACCEPTED
    assert not enabled.vehicle.failures.motors_off


@pytest.mark.parametrize("unit, kind, instance, reason", [
    (BARO, DELAYED, 0, "failure barometer delayed is not supported"),
    (BARO, OFF, 2, "one barometer"),
    (M.FAILURE_UNIT_SENSOR_OPTICAL_FLOW, OFF, 0, "failure optical flow off is not supported"),
    (MOTOR, STUCK, 1, "failure motor stuck is not supported"),
    (MOTOR, OFF, 5, "motor instance 5"),
    (GPS, OFF, 2, "one GPS"),
    (math.nan, OFF, 0, "failure unit nan is not a whole number"),
    (77, OFF, 0, "failure unit 77 off is not supported")])
def test_what_cannot_be_injected_is_unsupported_and_changes_nothing(enabled, unit, kind,
                                                                    instance, reason):
    result, said = enabled.client.result(INJECT, unit, kind, instance)
    assert result == UNSUPPORTED
    assert len(said) == 1 and reason in said[0]
    assert not enabled.vehicle.failures.any


def test_the_logic_alone():
    failures = InjectedFailures()
    with pytest.raises(UnsupportedError):
        failures.inject(True, MOTOR, OFF, -1)
    assert failures.inject(True, MOTOR, OFF, 0) == "failure injected: every motor off"
    commands = np.array([0.4, 0.4, 0.4, 0.4])
    assert failures.motor_outputs(commands).tolist() == [0.0] * 4
    assert commands.tolist() == [0.4] * 4  # the controller's commands are not touched


def test_gps_off_drops_the_fixes_before_the_estimator():
    from autopilot.commander.commander import Commander
    from autopilot.control.factory import make_controller
    from autopilot.estimation.estimator import Estimator, GpsFix
    from autopilot.process.navigation import Navigation
    from autopilot.process.sim_link import GpsReading
    from contracts.airframe import PAPER

    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01,
                        {"SYS_FAILURE_EN": 1.0})
    navigation = Navigation(vehicle, Estimator())
    fix = GpsFix(np.zeros(3), np.zeros(3), 3, 12)
    navigation.measurements([GpsReading(10_000, fix)])
    assert navigation.estimator._pending_fix is fix  # taken (it waits for alignment)
    navigation.estimator._pending_fix = None
    vehicle.inject_failure(GPS, OFF, 0)
    navigation.measurements([GpsReading(20_000, fix)])
    assert navigation.estimator._pending_fix is None  # dropped


@pytest.mark.parametrize("unit, name", [(BARO, "barometer"),
                                        (M.FAILURE_UNIT_SENSOR_MAG, "magnetometer"),
                                        (M.FAILURE_UNIT_SENSOR_GYRO, "gyro"),
                                        (M.FAILURE_UNIT_SENSOR_ACCEL, "accelerometer")])
def test_a_sensor_off_then_ok(enabled, unit, name):
    assert enabled.client.result(INJECT, unit, OFF, 0)[0] == ACCEPTED
    assert enabled.vehicle.failures.failed(unit) == OFF
    assert _said(enabled) == [f"failure injected: {name} off"]
    assert enabled.client.result(INJECT, unit, OK, 1)[0] == ACCEPTED
    assert not enabled.vehicle.failures.any


def test_baro_and_mag_off_reach_the_estimator_as_no_reading():
    from autopilot.commander.commander import Commander
    from autopilot.control.factory import make_controller
    from autopilot.estimation.estimator import Estimator
    from autopilot.process.navigation import Navigation
    from autopilot.process.sim_link import ImuReading
    from contracts.airframe import PAPER
    from contracts.frames import DEFAULT_HOME

    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01,
                        {"SYS_FAILURE_EN": 1.0})
    vehicle.set_origin(DEFAULT_HOME)
    navigation = Navigation(vehicle, Estimator())
    vehicle.inject_failure(BARO, OFF, 0)
    vehicle.inject_failure(M.FAILURE_UNIT_SENSOR_MAG, OFF, 0)
    reading = ImuReading(10_000, np.zeros(3), np.array([0.0, 0.0, -9.81]),
                         DEFAULT_HOME.alt_amsl_m + 5.0, np.array([0.2, 0.0, 0.4]))
    navigation.measurements([reading])
    assert navigation.estimator._align_baro is None and navigation.estimator._align_mag is None
    vehicle.inject_failure(BARO, OK, 0)
    navigation.measurements([reading._replace(time_us=20_000)])
    assert navigation.estimator._align_baro == 5.0 and navigation.estimator._align_mag is None


def test_each_sensor_failure_type_on_the_data():
    """PX4's types on a reading: stuck keeps the value at the injection, garbage is noise
    (seeded: two vehicles draw the same), wrong a fixed plausible error, slow one in ten,
    intermittent about half; OK gives the data back untouched."""
    from autopilot.commander import failures as fl

    f = InjectedFailures()
    gyro = np.array([0.01, 0.02, 0.03])
    assert f.sensor(fl.GYRO, gyro) is gyro  # nothing failed
    f.inject(True, fl.GYRO, fl.STUCK, 0)
    first = f.sensor(fl.GYRO, gyro)
    assert f.sensor(fl.GYRO, gyro + 1.0) is first  # stuck at the first value
    f.inject(True, fl.GYRO, fl.WRONG, 0)
    assert np.allclose(f.sensor(fl.GYRO, gyro), gyro + (0.2, 0.0, 0.0))
    f.inject(True, fl.BARO, fl.WRONG, 0)
    assert f.sensor(fl.BARO, 488.0) == 508.0
    f.inject(True, fl.MAG, fl.WRONG, 0)
    turned = f.sensor(fl.MAG, np.array([0.2, 0.0, 0.4]))
    assert math.degrees(math.atan2(turned[1], turned[0])) == pytest.approx(45.0)
    f.inject(True, fl.BARO, fl.SLOW, 0)
    kept = [f.sensor(fl.BARO, float(i)) for i in range(30)]
    assert [k for k in kept if k is not None] == [0.0, 10.0, 20.0]
    f.inject(True, fl.ACCEL, fl.INTERMITTENT, 0)
    passed = sum(f.sensor(fl.ACCEL, gyro) is not None for _ in range(1000))
    assert 450 < passed < 550
    g1, g2 = InjectedFailures(), InjectedFailures()
    for g in (g1, g2):
        g.inject(True, fl.ACCEL, fl.GARBAGE, 0)
    a, b = g1.sensor(fl.ACCEL, gyro), g2.sensor(fl.ACCEL, gyro)
    assert np.array_equal(a, b) and np.max(np.abs(a - gyro)) > 1.0
    f.inject(True, fl.GYRO, fl.OK, 0)
    assert f.sensor(fl.GYRO, gyro) is gyro and f.failed(fl.GYRO) == OK
    assert f.sensor(fl.MAG, None) is None  # a reading that was not fresh stays so


def test_a_wrong_gps_moves_the_fixes_100_m_north():
    from autopilot.commander.commander import Commander
    from autopilot.control.factory import make_controller
    from autopilot.estimation.estimator import Estimator, GpsFix
    from autopilot.process.navigation import Navigation
    from autopilot.process.sim_link import GpsReading
    from contracts.airframe import PAPER

    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01,
                        {"SYS_FAILURE_EN": 1.0})
    navigation = Navigation(vehicle, Estimator())
    vehicle.inject_failure(GPS, M.FAILURE_TYPE_WRONG, 0)
    fix = GpsFix(np.array([1.0, 2.0, -3.0]), np.zeros(3), 3, 12)
    navigation.measurements([GpsReading(10_000, fix)])
    taken = navigation.estimator._pending_fix
    assert taken.position_ned_m.tolist() == [101.0, 2.0, -3.0]
    assert fix.position_ned_m.tolist() == [1.0, 2.0, -3.0]  # the reading is not touched


def test_on_the_truth_a_stuck_gyro_is_what_the_rate_loop_gets():
    from autopilot.commander import failures as fl
    from tests.sitl.test_sim_link import _answers, _autopilot_on_a_socket, _samples_with_gyro

    autopilot, theirs = _autopilot_on_a_socket(source="hil-state")
    autopilot.vehicle.set_parameter("SYS_FAILURE_EN", 1.0)
    theirs.sendall(_samples_with_gyro([0], (0.1, 0.0, 0.0),
                                      ("HIL_SENSOR", "HIL_STATE_QUATERNION")))
    autopilot._on_sim_readable()
    autopilot.vehicle.inject_failure(fl.GYRO, fl.STUCK, 0)
    theirs.sendall(_samples_with_gyro([10_000], (0.1, 0.0, 0.0),
                                      ("HIL_SENSOR", "HIL_STATE_QUATERNION")))
    autopilot._on_sim_readable()
    stuck_rate = autopilot.latest[1][9]
    theirs.sendall(_samples_with_gyro([20_000], (0.5, 0.0, 0.0),
                                      ("HIL_SENSOR", "HIL_STATE_QUATERNION")))
    autopilot._on_sim_readable()
    assert _answers(theirs) == [0, 10_000, 20_000]
    assert autopilot.latest[1][9] == pytest.approx(stuck_rate)  # 0.5 rad/s never seen


def test_dead_reckoning_past_ekf2_noaid_tout_loses_the_position_once():
    """Navigation on sim time: GPS lost is announced, the position is called lost once
    the last fix fused is older than EKF2_NOAID_TOUT (a failsafe), once only, and a fix
    fused again ends the loss."""
    import dataclasses

    from autopilot.commander.commander import Commander
    from autopilot.control.factory import make_controller
    from autopilot.estimation.estimator import EstimatorStatus
    from autopilot.process.navigation import Navigation
    from contracts.airframe import PAPER

    class StatusOnly:  # the estimator's status on a given clock, nothing else
        gps_delay_us = 0
        status_now = None

        def status(self, time_us):
            return self.status_now

    good = EstimatorStatus(True, True, True, 0.1, "", *[0.01] * 5, *[0.1] * 5, 0, 0)
    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01,
                        {"EKF2_NOAID_TOUT": 3e6})
    estimator = StatusOnly()
    navigation = Navigation(vehicle, estimator)

    def at(since_gps_s, gps_ok, t_us):
        estimator.status_now = dataclasses.replace(good, gps_ok=gps_ok,
                                                   since_gps_s=since_gps_s)
        navigation.update(t_us)

    at(0.1, True, 0)
    at(1.5, False, 1_400_000)
    assert [t for _, t in vehicle.messages] == ["GPS lost: dead reckoning"]
    at(2.9, False, 2_800_000)
    assert vehicle.failsafe is None
    at(3.1, False, 3_000_000)
    assert vehicle.failsafe == "position lost: no GPS fix for 3 s"
    at(4.0, False, 3_900_000)  # once only
    assert [t for _, t in vehicle.messages].count("position lost: no GPS fix for 3 s") == 1
    at(0.05, True, 4_000_000)
    at(3.5, False, 7_500_000)  # a new loss after the fixes came back: said again
    assert [t for _, t in vehicle.messages].count("position lost: no GPS fix for 3 s") == 2
