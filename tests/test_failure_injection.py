"""MAV_CMD_INJECT_FAILURE from a ground tool over a real socket, as PX4: refused unless
SYS_FAILURE_EN is 1; GPS and motor failures applied inside the flight stack (fixes
dropped, the motor's output held at zero), announced, and cleared with OK; every other
unit or type refused as unsupported, changing nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.commander.failures import InjectedFailures, UnsupportedError
from tests.test_mavlink_server import ACCEPTED, DENIED, UNSUPPORTED, M, Station, texts

INJECT = M.MAV_CMD_INJECT_FAILURE
GPS, MOTOR, BARO = (M.FAILURE_UNIT_SENSOR_GPS, M.FAILURE_UNIT_SYSTEM_MOTOR,
                    M.FAILURE_UNIT_SENSOR_BARO)
OK, OFF, STUCK = M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF, M.FAILURE_TYPE_STUCK


@pytest.fixture
def station():
    s = Station()
    yield s
    s.close()


@pytest.fixture
def enabled():
    s = Station(SYS_FAILURE_EN=1.0)
    yield s
    s.close()


def _said(station: Station) -> list[str]:
    station.service()
    return texts(station.client.sync())


def test_refused_while_sys_failure_en_is_0(station):
    assert station.client.result(INJECT, GPS, OFF, 0) == (
        DENIED, ["failure injection disabled: set SYS_FAILURE_EN to 1"])
    assert not station.vehicle.failures.any


def test_gps_off_then_ok(enabled):
    assert enabled.client.result(INJECT, GPS, OFF, 0)[0] == ACCEPTED
    assert enabled.vehicle.failures.gps_off
    assert _said(enabled) == ["failure injected: GPS off"]
    assert enabled.client.result(INJECT, GPS, OK, 0)[0] == ACCEPTED
    assert not enabled.vehicle.failures.gps_off


def test_one_motor_off_holds_its_output_at_zero(enabled):
    assert enabled.client.result(INJECT, MOTOR, OFF, 2)[0] == ACCEPTED
    assert enabled.vehicle.failures.motors_off == {1}
    assert _said(enabled) == ["failure injected: motor 2 off"]
    out = enabled.vehicle.failures.motor_outputs(np.array([0.5, 0.6, 0.7, 0.8]))
    assert out.tolist() == [0.5, 0.0, 0.7, 0.8]
    assert enabled.client.result(INJECT, MOTOR, OK, 0)[0] == ACCEPTED
    assert not enabled.vehicle.failures.motors_off


@pytest.mark.parametrize("unit, kind, instance, reason", [
    (BARO, STUCK, 0, "failure barometer stuck is not supported"),
    (BARO, OFF, 2, "one barometer"),
    (M.FAILURE_UNIT_SENSOR_GYRO, OFF, 0, "failure gyro off is not supported"),
    (GPS, STUCK, 0, "failure GPS stuck is not supported"),
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


@pytest.mark.parametrize("unit, flag, name", [(BARO, "baro_off", "barometer"),
                                             (M.FAILURE_UNIT_SENSOR_MAG, "mag_off",
                                              "magnetometer")])
def test_a_sensor_off_then_ok(enabled, unit, flag, name):
    assert enabled.client.result(INJECT, unit, OFF, 0)[0] == ACCEPTED
    assert getattr(enabled.vehicle.failures, flag)
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
    vehicle.set_home(DEFAULT_HOME)
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
