"""The simulator's sensors (sitl/sensors.py): noise and bias statistics, their own rates,
GPS latency and wander, perturbations of the sensors, profiles, and the messages that
carry them (bad readings refused at the autopilot's end)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME, altitude_from_pressure_m, pressure_hpa, quat_from_euler
from contracts.mavlink import (
    HIL_SENSOR_BARO,
    HIL_SENSOR_IMU,
    HIL_SENSOR_MAG,
    LinkDataError,
    fix_from_hil_gps,
    imu_from_hil_sensor,
    mavlink,
)
from contracts.perturbations import SensorEffects
from contracts.sim_samples import gps_message, sensor_message
from sitl.plant import VehicleState
from sitl.sensors import (
    SensorProfile,
    SensorProfileError,
    SensorSuite,
    parse_profile,
    read_profile,
    shipped_profile_names,
)

RATE_HZ = 250.0


def _at_rest(altitude_m: float = 1.0) -> VehicleState:
    return VehicleState(0.0, np.array([0.0, 0.0, -altitude_m]), np.zeros(3), np.zeros(3),
                        np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))


def _readings(profile: SensorProfile, n: int, seed: int = 0, effects=None,
              state: VehicleState | None = None):
    suite = SensorSuite(profile, RATE_HZ, seed)
    state = state or _at_rest()
    out = [suite.sample(round(k * 1e6 / RATE_HZ), state, np.zeros(3), effects)
           for k in range(n)]
    return suite, out


def test_the_shipped_profiles_read_and_ideal_is_perfect():
    assert shipped_profile_names() == ["degraded", "ideal", "typical"]
    typical = read_profile("typical")
    assert typical.gyro_noise_rad_s_rthz == 3.4e-4 and typical.gps_latency_s == 0.11
    _suite, out = _readings(read_profile("ideal"), 50)
    sensor, _fix = out[10]
    np.testing.assert_allclose(sensor.accel_frd_mps2, (0.0, 0.0, -9.81), atol=1e-12)
    assert sensor.gyro_frd_rad_s == (0.0, 0.0, 0.0)


def test_imu_white_noise_has_the_profiles_density():
    profile = SensorProfile(gyro_noise_rad_s_rthz=3.4e-4, accel_noise_mps2_rthz=4e-3)
    _suite, out = _readings(profile, 20000)
    gyro = np.array([s.gyro_frd_rad_s for s, _ in out])
    accel = np.array([s.accel_frd_mps2 for s, _ in out])
    # sigma per sample = density * sqrt(rate): 5.4e-3 rad/s and 0.063 m/s^2 at 250 Hz.
    np.testing.assert_allclose(gyro.std(axis=0), 3.4e-4 * math.sqrt(RATE_HZ), rtol=0.03)
    np.testing.assert_allclose(accel.std(axis=0), 4e-3 * math.sqrt(RATE_HZ), rtol=0.03)


def test_turn_on_biases_are_drawn_per_seed_and_repeat_with_it():
    profile = SensorProfile(gyro_turn_on_bias_rad_s=0.01, accel_turn_on_bias_mps2=0.2)
    a, out_a = _readings(profile, 5, seed=1)
    b, out_b = _readings(profile, 5, seed=1)
    c, _ = _readings(profile, 5, seed=2)
    assert out_a == out_b  # bit for bit
    assert not np.allclose(a.gyro_bias, c.gyro_bias)
    np.testing.assert_allclose(out_a[3][0].gyro_frd_rad_s, a.gyro_bias, atol=1e-15)


def test_bias_random_walk_grows_with_the_square_root_of_time():
    profile = SensorProfile(gyro_bias_walk_rad_s2_rthz=1e-3)
    finals = []
    for seed in range(200):
        suite, _ = _readings(profile, 250, seed=seed)  # 1 s
        finals.append(suite.gyro_bias)
    # After 1 s the bias has spread by 1e-3 rad/s per axis.
    assert np.std(finals) == pytest.approx(1e-3, rel=0.1)


def test_each_sensor_comes_at_its_own_rate_and_says_so():
    _suite, out = _readings(read_profile("typical"), 250)  # 1 s at 250 Hz
    updated = [s.fields_updated for s, _ in out]
    assert all(u & HIL_SENSOR_IMU == HIL_SENSOR_IMU for u in updated)
    assert sum(u & HIL_SENSOR_MAG == HIL_SENSOR_MAG for u in updated) == 100
    assert sum(u & HIL_SENSOR_BARO == HIL_SENSOR_BARO for u in updated) == 50
    # GPS: 10 fixes a second, each 110 ms old on arrival, plus the one the receiver had
    # before the start; stamped with their arrival time.
    arrivals = [k for k, (_s, fix) in enumerate(out) if fix is not None]
    assert arrivals[0] == 0
    assert arrivals[1:4] == [28, 53, 78]  # 110 ms = 27.5 samples: the next sample
    assert all(out[k][1].time_us == round(k * 1e6 / RATE_HZ) for k in arrivals)


def test_gps_error_is_gauss_markov_with_the_profiles_sigma_and_time():
    profile = SensorProfile(gps_horizontal_m=0.3, gps_vertical_m=0.5,
                            gps_error_time_constant_s=1.0, gps_rate_hz=10.0)
    errors = []
    suite = SensorSuite(profile, 10.0, seed=3)
    state = _at_rest(0.0)
    for k in range(20000):
        suite.sample(k * 100_000, state, np.zeros(3))
        errors.append(suite.gps_error.copy())
    e = np.array(errors)
    np.testing.assert_allclose(e.std(axis=0), (0.3, 0.3, 0.5), rtol=0.1)
    # Correlation after one time constant (10 fixes): 1/e.
    lag = np.mean([np.corrcoef(e[:-10, i], e[10:, i])[0, 1] for i in range(3)])
    assert lag == pytest.approx(math.exp(-1.0), abs=0.05)


def _typical_gps_north_m(seed: int, rate_hz: float, n: int) -> np.ndarray:
    suite = SensorSuite(read_profile("typical"), rate_hz, seed)
    state = _at_rest(2.0)
    out = np.empty((n, 2))
    for k in range(n):
        suite.sample(round(k * 1e6 / rate_hz), state, np.zeros(3))
        out[k] = suite.gps_error[0:2]
    return out


def test_typical_gps_wanders_as_designed_and_seed_0_north_is_pinned():
    """``typical``'s GPS error over 25 s, seeds 0-59: it keeps its 0.3 m and changes by what
    a Gauss-Markov of tau 60 s does (e(25) - e(0) exp(-25/60): sigma sqrt(1 - exp(-50/60))
    = 0.226 m). Seed 0's north error, as gps-outage flies it (100 Hz samples), goes from
    -0.21 to -0.14 m: a change of 0.00 sigma, well inside the model (docs/sensors.md)."""
    paths = np.array([_typical_gps_north_m(seed, 10.0, 251) for seed in range(60)])
    decay = math.exp(-25.0 / 60.0)
    change_sigma_m = 0.3 * math.sqrt(1.0 - decay * decay)
    change = paths[:, 250] - decay * paths[:, 0]
    assert paths[:, 0].std() == pytest.approx(0.3, rel=0.1)
    assert paths[:, 250].std() == pytest.approx(0.3, rel=0.1)
    assert change.std() == pytest.approx(change_sigma_m, rel=0.1)
    assert np.abs(change / change_sigma_m).max() < 3.0
    flown = _typical_gps_north_m(0, 100.0, 2500)
    assert flown[0, 0] == pytest.approx(-0.2088, abs=1e-4)
    assert flown[999, 0] == pytest.approx(-0.1030, abs=1e-4)  # t = 9.99 s
    assert flown[2499, 0] == pytest.approx(-0.1377, abs=1e-4)  # t = 24.99 s
    tail = (flown[2499, 0] - math.exp(-24.9 / 60.0) * flown[0, 0]) / (
        0.3 * math.sqrt(1.0 - math.exp(-2.0 * 24.9 / 60.0)))
    assert tail == pytest.approx(0.00, abs=0.01)


def test_sensor_perturbations_act_on_what_the_sensors_read():
    ideal = read_profile("ideal")
    effects = SensorEffects(gps_outage=1.0, mag_field_gauss=(0.1, 0.0, 0.0),
                            gyro_bias_rad_s=(0.0, 0.02, 0.0), accel_bias_mps2=(0.3, 0.0, 0.0),
                            baro_drift_mps=0.5)
    _suite, plain = _readings(ideal, 251)
    _suite, out = _readings(ideal, 251, effects=effects)
    assert all(fix.fix_type == 0 for _s, fix in out if fix is not None)
    assert all(fix.fix_type == 3 for _s, fix in plain if fix is not None)
    s, p = out[250][0], plain[250][0]
    np.testing.assert_allclose(np.subtract(s.mag_frd_gauss, p.mag_frd_gauss), (0.1, 0, 0),
                               atol=1e-12)
    np.testing.assert_allclose(np.subtract(s.gyro_frd_rad_s, p.gyro_frd_rad_s), (0, 0.02, 0),
                               atol=1e-12)
    np.testing.assert_allclose(np.subtract(s.accel_frd_mps2, p.accel_frd_mps2), (0.3, 0, 0),
                               atol=1e-12)
    assert s.pressure_alt_m - p.pressure_alt_m == pytest.approx(0.5, rel=0.01)  # 1 s


def test_bad_profiles_are_refused_naming_the_field(tmp_path):
    for data, message in ((dict(gyro_noise=1.0), "unknown field(s) gyro_noise"),
                          (dict(gps_rate_hz=0.0), "gps_rate_hz must be a number in [0.5, 1000] Hz"),
                          (dict(baro_noise_m=-1.0), "baro_noise_m must be a finite number >= 0"),
                          (dict(mag_noise_gauss=math.nan), "mag_noise_gauss must be"),
                          (dict(gps_latency_s=0.5),
                           "gps_latency_s must be a number in [0, 0.3] s, got 0.5 (what the "
                           "estimator's EKF2_GPS_DELAY can match)"),
                          (dict(name=3), "name must be text")):
        with pytest.raises(SensorProfileError, match=None) as info:
            parse_profile(data, "sensor profile file mine.toml")
        assert message in str(info.value) and "mine.toml" in str(info.value)
    (tmp_path / "mine.toml").write_text('gps_horizontal_m = 2.0\n')
    mine = read_profile(str(tmp_path / "mine.toml"))
    assert mine.name == "mine" and mine.gps_horizontal_m == 2.0
    assert mine == replace(SensorProfile(), name="mine", gps_horizontal_m=2.0)
    with pytest.raises(SensorProfileError, match="unknown sensor profile 'noisy'"):
        read_profile("noisy")


def _packed(msg):
    link = mavlink.MAVLink(None, 1, 51)
    return link.parse_buffer(msg.pack(link))[0]


def test_the_autopilot_reads_hil_sensor_and_hil_gps_as_sent():
    _suite, out = _readings(read_profile("typical"), 30)
    sensor, _ = out[0]
    gyro, accel, baro, mag = imu_from_hil_sensor(_packed(sensor_message(sensor)))
    np.testing.assert_allclose(gyro, sensor.gyro_frd_rad_s, rtol=1e-6)
    np.testing.assert_allclose(accel, sensor.accel_frd_mps2, rtol=1e-6)
    assert baro == pytest.approx(sensor.pressure_alt_m, abs=0.05)
    assert mag is not None
    no_baro = next(s for s, _ in out if not s.fields_updated & HIL_SENSOR_BARO)
    assert math.isnan(imu_from_hil_sensor(_packed(sensor_message(no_baro)))[2])
    fix = next(f for _s, f in out[1:] if f is not None)
    position, velocity, fix_type, satellites = fix_from_hil_gps(_packed(gps_message(fix)),
                                                                DEFAULT_HOME)
    assert fix_type == 3 and satellites == 14
    assert np.all(np.abs(position - (0.0, 0.0, -1.0)) < 1.5)
    assert altitude_from_pressure_m(pressure_hpa(488.0)) == pytest.approx(488.0, abs=1e-6)


@pytest.mark.parametrize("change, message", [
    (dict(xgyro=math.nan), "IMU holds NaN"),
    (dict(zacc=math.inf), "IMU holds NaN"),
    (dict(fields_updated=HIL_SENSOR_MAG), "without its IMU fields"),
    (dict(abs_pressure=0.0), "is not a pressure in the air"),
    (dict(xmag=math.nan), "magnetometer holds NaN"),
])
def test_bad_hil_sensor_readings_are_refused(change, message):
    _suite, out = _readings(read_profile("ideal"), 1)
    msg = _packed(sensor_message(out[0][0]))
    for field, value in change.items():
        setattr(msg, field, value)
    with pytest.raises(LinkDataError, match=message):
        imu_from_hil_sensor(msg)


def test_a_fix_off_the_earth_is_refused():
    _suite, out = _readings(read_profile("ideal"), 1)
    msg = _packed(gps_message(out[0][1]))
    msg.lat = 91 * 10**7
    with pytest.raises(LinkDataError, match="not on Earth"):
        fix_from_hil_gps(msg, DEFAULT_HOME)


def test_a_profile_beside_a_scenario_file_is_found_from_it(tmp_path):
    from ground.scenario.scenario_file import load_scenario

    (tmp_path / "noisy.toml").write_text("gyro_noise_rad_s_rthz = 1e-3\n")
    scenario_text = (
        'name = "mine"\n[reference]\nkind = "hover"\n[plant]\nsensors = "noisy.toml"\n')
    (tmp_path / "mine.toml").write_text(scenario_text)
    scenario = load_scenario(tmp_path / "mine.toml")
    assert scenario.sensors == str(tmp_path / "noisy.toml")
    assert read_profile(scenario.sensors).name == "noisy"  # a file's name is its stem


def test_a_touchdown_that_levels_the_vehicle_shows_in_the_gyro():
    """The plant levels a vehicle that touches down tilted within one integration step and
    leaves it at rest; the gyro of that sample reads the rotation it made over the period
    (as a gyro integrating the impact would), so an estimator integrating it levels too.
    In the air the gyro reads the body rate as it is."""
    import dataclasses

    from sitl.truth import seen_by_the_gyro

    roll = -0.17
    tilted = VehicleState(0.0, np.array([0.0, 0.0, -0.005]), np.array([0.0, 0.0, 0.7]),
                          np.array([roll, 0.0, 0.3]), np.zeros(3),
                          np.array([-1.3, 0.0, 0.0]),
                          np.array(quat_from_euler(roll, 0.0, 0.3)))
    level = VehicleState(0.01, np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 0.3]),
                         np.zeros(3), np.zeros(3), np.array(quat_from_euler(0.0, 0.0, 0.3)))
    seen = seen_by_the_gyro(tilted, level, 0.01)
    np.testing.assert_allclose(seen.body_rate_rad_s, (0.17 / 0.01, 0.0, 0.0), atol=1e-9)
    for name in ("position_ned_m", "velocity_ned_mps", "euler_rad", "euler_rate_rad_s",
                 "quaternion", "rotor_rad_s"):  # only the gyro's reading changes
        np.testing.assert_array_equal(getattr(seen, name), getattr(level, name))
    flying = dataclasses.replace(level, position_ned_m=np.array([0.0, 0.0, -1.0]))
    assert seen_by_the_gyro(tilted, flying, 0.01) is flying


def test_the_noise_block_size_changes_no_number(monkeypatch):
    """Drawn a block at a time or a sample at a time, the same numbers (numpy draws a
    block as the samples one by one): the block size is a speed, not a result."""
    import sitl.sensors as sensors

    typical = read_profile("typical")
    _suite, blocks = _readings(typical, 700, seed=4)
    monkeypatch.setattr(sensors, "NOISE_BLOCK_SAMPLES", 1)
    _suite, one_by_one = _readings(typical, 700, seed=4)
    assert blocks == one_by_one


def test_each_sensor_has_its_own_stream():
    """Another magnetometer, barometer or GPS (their noise, rates) moves neither the
    gyro's nor the accelerometer's numbers; another seed moves them all."""
    typical = read_profile("typical")
    other = replace(typical, mag_noise_gauss=0.05, mag_rate_hz=50.0, baro_noise_m=2.0,
                    gps_rate_hz=5.0, gps_velocity_noise_mps=1.0)
    _suite, first = _readings(typical, 300, seed=9)
    _suite, second = _readings(other, 300, seed=9)
    _suite, reseeded = _readings(typical, 300, seed=10)
    imu = [(s.gyro_frd_rad_s, s.accel_frd_mps2) for s, _fix in first]
    assert imu == [(s.gyro_frd_rad_s, s.accel_frd_mps2) for s, _fix in second]
    assert [s.mag_frd_gauss for s, _fix in first] != [s.mag_frd_gauss for s, _fix in second]
    assert all(a != b for a, b in zip(imu, [(s.gyro_frd_rad_s, s.accel_frd_mps2)
                                             for s, _fix in reseeded], strict=True))
