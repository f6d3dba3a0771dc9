"""The onboard estimator: its Jacobians against finite differences, the delayed GPS fusion
against the filter that had the fix on time, the innovation gate, alignment, convergence
and the pre-arm check, and flights on it in one process (golden numbers)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.estimation import eskf
from autopilot.estimation.estimator import Estimator, GpsFix, heading_from_mag
from contracts.frames import DEFAULT_HOME, quat_from_euler, rotation_from_quat

NOISE = eskf.FilterNoise()


def _state(euler=(0.3, -0.4, 1.2)) -> np.ndarray:
    x = np.zeros(eskf.X_SIZE)
    x[eskf.X_POS:eskf.X_POS + 3] = (1.0, -2.0, -3.0)
    x[eskf.X_VEL:eskf.X_VEL + 3] = (0.5, -0.2, 0.1)
    x[eskf.X_QUAT:eskf.X_QUAT + 4] = quat_from_euler(*euler)
    x[eskf.X_GYRO_BIAS:eskf.X_GYRO_BIAS + 3] = (0.01, -0.02, 0.005)
    x[eskf.X_ACCEL_BIAS:eskf.X_ACCEL_BIAS + 3] = (0.1, -0.05, 0.2)
    return x


def _error_between(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The error state dx with y = x (+) dx."""
    dx = np.zeros(eskf.E_SIZE)
    dx[0:6] = y[0:6] - x[0:6]
    q_x, q_y = x[eskf.X_QUAT:eskf.X_QUAT + 4], y[eskf.X_QUAT:eskf.X_QUAT + 4]
    conj = np.array([q_x[0], -q_x[1], -q_x[2], -q_x[3]])
    dq = eskf.quat_multiply(conj, q_y)
    dx[eskf.E_ANG:eskf.E_ANG + 3] = 2.0 * dq[1:4] * np.sign(dq[0])
    dx[eskf.E_GYRO_BIAS:] = y[eskf.X_GYRO_BIAS:] - x[eskf.X_GYRO_BIAS:]
    return dx


def test_the_prediction_jacobian_is_the_nominal_propagation_differentiated():
    """F of predict() against finite differences: propagate x and x (+) h e_j, compare the
    error between them with F h e_j, for every error-state component."""
    x0 = _state()
    imu = np.array([0.4, -0.7, 0.9, 1.5, -0.8, -9.0, 0.004])
    p = np.zeros((eskf.E_SIZE, eskf.E_SIZE))
    quiet = NOISE._replace(gyro_rad_s_rthz=0.0, accel_mps2_rthz=0.0,
                           gyro_bias_walk_rad_s2_rthz=0.0, accel_bias_walk_mps3_rthz=0.0,
                           baro_drift_m_rts=0.0)
    base = x0.copy()
    eskf.predict(base, p.copy(), imu, quiet)
    h = 1e-6
    for j in range(eskf.E_SIZE):
        perturbed = x0.copy()
        dx = np.zeros(eskf.E_SIZE)
        dx[j] = h
        eskf.inject(perturbed, dx)
        eskf.predict(perturbed, p.copy(), imu, quiet)
        numeric = _error_between(base, perturbed) / h
        p0 = np.zeros((eskf.E_SIZE, eskf.E_SIZE))
        p0[j, j] = 1.0
        eskf.predict(x0.copy(), p0, imu, quiet)  # p0 becomes F e_j e_j^T F^T
        column = p0[:, j] / math.sqrt(p0[j, j])  # F e_j (F_jj > 0)
        # Entries are of order 1 and dt = 4e-3; 1e-5 leaves the second-order terms the
        # filter neglects (dt^2 w / 2 on the gyro bias) and catches any missing or flipped one.
        np.testing.assert_allclose(column, numeric, rtol=1e-3, atol=1e-5, err_msg=str(j))


def test_the_magnetometer_and_heading_jacobians_are_their_derivatives():
    x = _state()
    field = np.array(DEFAULT_HOME.mag_field_ned_gauss())
    h = 1e-7
    for j in range(3):
        dx = np.zeros(eskf.E_SIZE)
        dx[eskf.E_ANG + j] = h
        y = x.copy()
        eskf.inject(y, dx)
        m_x = rotation_from_quat(x[6:10]).T @ field
        m_y = rotation_from_quat(y[6:10]).T @ field
        # dm = [m]x dtheta: column j of [m]x is m x e_j.
        np.testing.assert_allclose((m_y - m_x) / h, np.cross(m_x, np.eye(3)[j]), atol=1e-6)
        assert (eskf.yaw_of(y) - eskf.yaw_of(x)) / h == pytest.approx(
            eskf.heading_row(x)[eskf.E_ANG + j], abs=1e-6)


def test_heading_from_a_tilted_magnetometer():
    field = np.array(DEFAULT_HOME.mag_field_ned_gauss())
    for euler in ((0.0, 0.0, 0.5), (0.3, -0.2, 1.0), (0.5, 0.4, -2.0)):
        mag = rotation_from_quat(quat_from_euler(*euler)).T @ field
        assert heading_from_mag(mag, euler[0], euler[1], DEFAULT_HOME.mag_declination_rad()) == \
            pytest.approx(euler[2], abs=1e-12)


def _hover_imu(rng: np.random.Generator, tilt=(0.0, 0.0, 0.3)):
    rot = rotation_from_quat(quat_from_euler(*tilt))
    accel = rot.T @ np.array([0.0, 0.0, -9.81]) + rng.normal(size=3) * 0.05
    gyro = rng.normal(size=3) * 0.003
    mag = rot.T @ np.array(DEFAULT_HOME.mag_field_ned_gauss()) + rng.normal(size=3) * 0.003
    return gyro, accel, mag


def _fly_static(gps_delay_s: float, delay_samples_late: int, n: int = 400,
                outlier_at: int | None = None) -> Estimator:
    """A vehicle at rest, tilted; fixes every 50 samples of 4 ms (5 Hz), arriving
    ``delay_samples_late`` samples after they were valid."""
    rng = np.random.default_rng(4)
    est = Estimator(gps_delay_s=gps_delay_s)
    # The fix the filter aligns on, there before the first sample in both.
    est.gps(gps_delay_s and round(gps_delay_s * 1e6), GpsFix(
        np.array([0.3, -0.2, -1.0]), np.zeros(3), 3, 12))
    fixes = []
    for k in range(n):
        t_us = k * 4000
        if k % 50 == 0 and k > 0:
            position = np.array([0.3, -0.2, -1.0]) + rng.normal(size=3) * 0.2
            if outlier_at is not None and k == outlier_at:
                position += 100.0
            fixes.append((k + delay_samples_late, GpsFix(position, rng.normal(size=3) * 0.05,
                                                         3, 12)))
        for due, fix in [f for f in fixes if f[0] == k]:
            est.gps(due * 4000, fix)
        gyro, accel, mag = _hover_imu(rng)
        est.imu(t_us, gyro, accel, 1.0 + rng.normal() * 0.1 if k % 5 == 0 else math.nan,
                mag if k % 2 == 0 else None)
    return est


def test_a_late_fix_is_fused_as_if_it_had_come_on_time():
    """The same readings, fixes arriving 28 samples (112 ms) late with the delay known,
    give the state and covariance of the filter that had them on time."""
    # 400 samples: the last fix (sample 350) reaches the late filter at sample 378, and
    # no fix is still on its way at the end.
    on_time = _fly_static(gps_delay_s=0.0, delay_samples_late=0)
    late = _fly_static(gps_delay_s=0.112, delay_samples_late=28)
    assert late.gps_late == 0 and on_time.gps_late == 0
    np.testing.assert_allclose(late.x, on_time.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(late.p, on_time.p, rtol=0, atol=1e-12)


def test_an_outlier_is_rejected_and_changes_nothing():
    """A fix 100 m off: each position axis fails the gate and leaves state and covariance
    as they were; the velocity axes, which agree, are fused."""
    est = _fly_static(0.0, 0, n=240)
    x, p = est.x.copy(), est.p.copy()
    ratios = np.zeros(6)
    gps = np.concatenate([x[0:3] + 100.0, x[3:6]])
    eskf.fuse_gps(x, p, gps, NOISE, ratios)
    assert np.all(ratios[:3] > 1.0) and np.all(ratios[3:] <= 1.0)
    np.testing.assert_allclose(x[0:3], est.x[0:3], atol=1e-12)  # velocities moved nothing
    # ... and at the estimator: counted, and the estimate is not pulled off.
    flown = _fly_static(0.0, 0, n=260, outlier_at=250)
    assert flown.gps_rejected == 1
    assert np.all(np.abs(flown.x[0:3] - (0.3, -0.2, -1.0)) < 0.5)
    assert flown.status(260 * 4000).gps_test_ratio > 1.0


def test_alignment_convergence_and_the_reasons_before_it():
    rng = np.random.default_rng(7)
    est = Estimator(gps_delay_s=0.0)
    assert est.status(0).reason.startswith("waiting for GPS")
    est.imu(0, *_hover_imu(rng, (0.1, -0.05, 2.0))[:2])
    assert not est.aligned  # no fix, baro or magnetometer yet
    tilt = (0.1, -0.05, 2.0)
    reasons = []
    for k in range(1, 1500):  # 6 s at 250 Hz
        t_us = k * 4000
        if k % 25 == 1:
            est.gps(t_us, GpsFix(np.array([0.0, 0.0, 0.0]) + rng.normal(size=3) * 0.2,
                                 rng.normal(size=3) * 0.05, 3, 12))
        gyro, accel, mag = _hover_imu(rng, tilt)
        est.imu(t_us, gyro, accel, rng.normal() * 0.1 if k % 5 == 0 else math.nan,
                mag if k % 2 == 0 else None)
        reasons.append(est.status(t_us).reason)
    assert est.aligned
    assert "settling after alignment" in reasons
    status = est.status(1499 * 4000)
    assert status.converged, status
    euler = est.measurement()[6:9]
    np.testing.assert_allclose(euler, tilt, atol=0.01)


def test_bad_readings_do_not_reach_the_filter():
    est = _fly_static(0.0, 0, n=100)
    before = est.x.copy()
    est.imu(100 * 4000, np.array([math.nan, 0.0, 0.0]), np.array([0.0, 0.0, -9.81]))
    # A non-finite IMU reading is refused at the link (contracts.mavlink); the filter's
    # own guard is its time step: a repeated time does nothing.
    est2 = _fly_static(0.0, 0, n=100)
    est2.imu(99 * 4000, np.zeros(3), np.array([0.0, 0.0, -9.81]))
    np.testing.assert_array_equal(est2.x, before)


def test_a_gyro_bias_step_is_learned():
    """At rest, the gyro's z bias steps by 0.02 rad/s (an imu_bias_step): the filter learns
    it from the magnetometer (85 % of it 15 s later: the bias is modelled as a slow random
    walk, as PX4's EKF2 models it) and the yaw estimate stays put meanwhile."""
    rng = np.random.default_rng(11)
    est = Estimator(gps_delay_s=0.0)
    tilt = (0.05, -0.03, 1.0)
    for k in range(250 * 20):  # 20 s at 250 Hz, the step at 5 s
        t_us = k * 4000
        if k % 25 == 0:
            est.gps(t_us, GpsFix(rng.normal(size=3) * 0.2, rng.normal(size=3) * 0.05, 3, 12))
        gyro, accel, mag = _hover_imu(rng, tilt)
        if k >= 250 * 5:
            gyro = gyro + (0.0, 0.0, 0.02)
        est.imu(t_us, gyro, accel, rng.normal() * 0.1 if k % 5 == 0 else math.nan,
                mag if k % 2 == 0 else None)
    assert est.x[eskf.X_GYRO_BIAS + 2] == pytest.approx(0.0169, rel=0.03)
    assert est.measurement()[8] == pytest.approx(tilt[2], abs=0.01)


FIRST_ESTIMATES = """
import numpy as np
from numba.core.dispatcher import Dispatcher
from autopilot.__main__ import build_parser, make_vehicle, preload
from autopilot.estimation import eskf
from autopilot.estimation.estimator import Estimator, GpsFix
from autopilot.process.sim_link import SimLink
from autopilot.process.warm_up import load_compiled_code
from contracts.frames import DEFAULT_HOME, GRAVITY_MPS2


def loaded():  # the overloads of the filter's own compiled functions (not its imports)
    return {n: len(d.overloads) for n, d in vars(eskf).items()
            if isinstance(d, Dispatcher) and d.py_func.__module__ == eskf.__name__}


preload()  # the process loader's
in_the_loader = sum(loaded().values())
vehicle = make_vehicle(build_parser().parse_args(["--state-source", "estimator"]))
load_compiled_code(vehicle, 0.01, SimLink("127.0.0.1", 0, "estimator"))  # its warm-up
before = loaded()
est = Estimator()
est.set_home(DEFAULT_HOME)
fix = GpsFix(np.zeros(3), np.zeros(3), 3, 12)
est.gps(0, fix)
for k in range(30):
    est.imu(k * 10_000, np.zeros(3), np.array([0.0, 0.0, -GRAVITY_MPS2]), 0.0,
            np.array([0.2, 0.0, 0.4]))
    est.gps(k * 10_000 + est.gps_delay_us, fix)
    est.measurement()
after = loaded()
print(in_the_loader, sorted(name for name in after if after[name] != before.get(name, 0)))
"""


@pytest.mark.process
def test_an_estimator_runs_warm_up_leaves_no_compiled_code_to_its_first_estimates():
    """An autopilot on the estimator loads its filter's steps in its warm-up
    (autopilot/process/warm_up.py), before the loop: an aligned estimator's first steps
    and fixes then load nothing from numba's cache. They did load there, at alignment,
    inside the loop: the warm-up's own estimator never aligned. The process loader
    leaves them out (0.1 s every run would pay). A fresh interpreter: in this one, other
    tests may have loaded it all."""
    import subprocess
    import sys
    from pathlib import Path

    done = subprocess.run([sys.executable, "-c", FIRST_ESTIMATES], capture_output=True,
                          text=True, check=True, cwd=Path(__file__).parents[2])
    assert done.stdout.strip() == "0 []"
