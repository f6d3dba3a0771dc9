"""The onboard estimator's numerical core: an error-state Kalman filter on IMU, GPS,
barometer and magnetometer (pure, numba-compiled; docs/estimation.md).

Nominal state (17): position NED [m] 0:3, velocity NED [m/s] 3:6, quaternion body->NED
6:10, gyro bias FRD [rad/s] 10:13, accelerometer bias FRD [m/s^2] 13:16, barometer
offset [m] 16 (baro altitude = -z + offset).
Error state (16): dp, dv, dtheta (body axes: q = q_hat (x) exp(dtheta / 2)), dbg, dba,
dbaro.

The IMU drives the prediction at the sample rate; measurements are fused one scalar at a
time with a chi-square gate; the magnetometer as a vector against the Earth's field (a
heading computed with the estimated tilt would feed the tilt error back as heading).
GPS is fused at its delayed time, as PX4's EKF2 does: the filter keeps a short history of
its states and IMU samples, goes back to the fix's time, fuses it there and replays the
samples since (with the baro and magnetometer readings fused then), which is exactly the
filter that had the fix on time.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from contracts.frames import (
    GRAVITY_MPS2,
    euler_from_quat,
    euler_rates_from_body_rates,
    rotation_from_quat,
)
from contracts.vectors import MEAS_EULER, MEAS_EULER_RATE, MEAS_POS, MEAS_VEL

X_POS, X_VEL, X_QUAT, X_GYRO_BIAS, X_ACCEL_BIAS, X_BARO, X_SIZE = 0, 3, 6, 10, 13, 16, 17
E_POS, E_VEL, E_ANG, E_GYRO_BIAS, E_ACCEL_BIAS, E_BARO, E_SIZE = 0, 3, 6, 9, 12, 15, 16
# One history entry's IMU sample: gyro FRD [rad/s], specific force FRD [m/s^2], dt [s].
IMU_SIZE = 7


class FilterNoise(NamedTuple):
    """The filter's noise model (1-sigma). Defaults suit the ``typical`` sensor profile."""

    gyro_rad_s_rthz: float = 5e-4  # white noise density
    accel_mps2_rthz: float = 6e-3
    gyro_bias_walk_rad_s2_rthz: float = 4e-5
    accel_bias_walk_mps3_rthz: float = 6e-3
    baro_drift_m_rts: float = 0.01  # offset random walk [m/sqrt(s)]
    gps_horizontal_m: float = 0.5  # GPS position (its error is correlated; white here)
    gps_vertical_m: float = 1.5  # the baro is the height reference; GPS corrects its drift
    gps_velocity_mps: float = 0.15
    baro_m: float = 0.15
    mag_gauss: float = 0.01  # magnetometer, per axis (noise, offsets, disturbances)
    gate_sigma: float = 5.0  # innovations beyond this many sigma are rejected


@njit(cache=True)
def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    return out


@njit(cache=True)
def quat_from_rotation_vector(v0: float, v1: float, v2: float) -> np.ndarray:
    angle = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    out = np.empty(4)
    if angle < 1e-12:
        out[0], out[1], out[2], out[3] = 1.0, 0.5 * v0, 0.5 * v1, 0.5 * v2
    else:
        s = math.sin(0.5 * angle) / angle
        out[0], out[1], out[2], out[3] = math.cos(0.5 * angle), v0 * s, v1 * s, v2 * s
    return out / math.sqrt(np.sum(out * out))


@njit(cache=True)
def predict(x: np.ndarray, p: np.ndarray, imu: np.ndarray, noise: FilterNoise) -> None:
    """Propagate state and covariance over one IMU sample (in place)."""
    dt = imu[6]
    w = imu[0:3] - x[X_GYRO_BIAS:X_GYRO_BIAS + 3]
    a = imu[3:6] - x[X_ACCEL_BIAS:X_ACCEL_BIAS + 3]
    r = rotation_from_quat(x[X_QUAT:X_QUAT + 4])
    acc = r @ a
    acc[2] += GRAVITY_MPS2
    for i in range(3):
        x[X_POS + i] += x[X_VEL + i] * dt + 0.5 * acc[i] * dt * dt
        x[X_VEL + i] += acc[i] * dt
    x[X_QUAT:X_QUAT + 4] = quat_multiply(
        x[X_QUAT:X_QUAT + 4], quat_from_rotation_vector(w[0] * dt, w[1] * dt, w[2] * dt))
    # F = I + A dt: dp' = dv, dv' = -R [a]x dtheta - R dba, dtheta' = -[w]x dtheta - dbg
    # (and the dt^2 / 2 of the position update).
    f = np.eye(E_SIZE)
    for i in range(3):
        f[E_POS + i, E_VEL + i] = dt
        f[E_ANG + i, E_GYRO_BIAS + i] = -dt
        for j in range(3):
            f[E_VEL + i, E_ACCEL_BIAS + j] = -r[i, j] * dt
    # -R [a]x: column j is -R (e_j x a).
    ax, ay, az = a[0], a[1], a[2]
    for i in range(3):
        f[E_VEL + i, E_ANG + 0] = -(r[i, 1] * az - r[i, 2] * ay) * dt
        f[E_VEL + i, E_ANG + 1] = -(r[i, 2] * ax - r[i, 0] * az) * dt
        f[E_VEL + i, E_ANG + 2] = -(r[i, 0] * ay - r[i, 1] * ax) * dt
    # Position integrates the velocity error over the step: half of it, times dt.
    for i in range(3):
        for j in range(3):
            f[E_POS + i, E_ANG + j] = 0.5 * dt * f[E_VEL + i, E_ANG + j]
            f[E_POS + i, E_ACCEL_BIAS + j] = 0.5 * dt * f[E_VEL + i, E_ACCEL_BIAS + j]
    # The attitude error turns back by the step's rotation: exp(-[w dt]x) = R(w dt)^T.
    f[E_ANG:E_ANG + 3, E_ANG:E_ANG + 3] = rotation_from_quat(
        quat_from_rotation_vector(w[0] * dt, w[1] * dt, w[2] * dt)).T
    p[:, :] = f @ p @ f.T
    q_vel = noise.accel_mps2_rthz ** 2 * dt
    q_ang = noise.gyro_rad_s_rthz ** 2 * dt
    q_bg = noise.gyro_bias_walk_rad_s2_rthz ** 2 * dt
    q_ba = noise.accel_bias_walk_mps3_rthz ** 2 * dt
    for i in range(3):
        p[E_VEL + i, E_VEL + i] += q_vel
        p[E_ANG + i, E_ANG + i] += q_ang
        p[E_GYRO_BIAS + i, E_GYRO_BIAS + i] += q_bg
        p[E_ACCEL_BIAS + i, E_ACCEL_BIAS + i] += q_ba
    p[E_BARO, E_BARO] += noise.baro_drift_m_rts ** 2 * dt


@njit(cache=True)
def inject(x: np.ndarray, dx: np.ndarray) -> None:
    """Add an error-state correction to the nominal state."""
    for i in range(6):
        x[i] += dx[i]
    x[X_QUAT:X_QUAT + 4] = quat_multiply(
        x[X_QUAT:X_QUAT + 4], quat_from_rotation_vector(dx[E_ANG], dx[E_ANG + 1],
                                                        dx[E_ANG + 2]))
    for i in range(6):
        x[X_GYRO_BIAS + i] += dx[E_GYRO_BIAS + i]
    x[X_BARO] += dx[E_BARO]


@njit(cache=True)
def fuse_scalar(x: np.ndarray, p: np.ndarray, h: np.ndarray, innovation: float,
                variance: float, gate_sigma: float) -> float:
    """Fuse one scalar measurement z = h dx + noise with innovation z - h(x_hat).

    Returns the test ratio innovation^2 / (gate^2 S): at most 1 was fused, above 1 was
    rejected and changed nothing."""
    ph = p @ h
    s = h @ ph + variance
    ratio = innovation * innovation / (gate_sigma * gate_sigma * s)
    if not ratio <= 1.0:  # NaN too
        return ratio
    k = ph / s
    inject(x, k * innovation)
    p -= np.outer(k, ph)
    p[:, :] = 0.5 * (p + p.T)
    return ratio


@njit(cache=True)
def yaw_of(x: np.ndarray) -> float:
    r = rotation_from_quat(x[X_QUAT:X_QUAT + 4])
    return math.atan2(r[1, 0], r[0, 0])


@njit(cache=True)
def heading_row(x: np.ndarray) -> np.ndarray:
    """d yaw / d dtheta (body-axis attitude error) of yaw = atan2(R10, R00): how well the
    filter knows its heading is h P h^T."""
    r = rotation_from_quat(x[X_QUAT:X_QUAT + 4])
    d = r[0, 0] * r[0, 0] + r[1, 0] * r[1, 0]
    h = np.zeros(E_SIZE)
    h[E_ANG + 1] = (r[1, 0] * r[0, 2] - r[0, 0] * r[1, 2]) / d
    h[E_ANG + 2] = (r[0, 0] * r[1, 1] - r[1, 0] * r[0, 1]) / d
    return h


@njit(cache=True)
def fuse_mag(x: np.ndarray, p: np.ndarray, mag_frd: np.ndarray, field_ned: np.ndarray,
             noise: FilterNoise) -> float:
    """The magnetometer's three axes against the Earth's field turned into the body:
    m = R^T B, so dm = [m]x dtheta. Returns the largest test ratio (>1 rejected)."""
    worst = 0.0
    for i in range(3):
        m = rotation_from_quat(x[X_QUAT:X_QUAT + 4]).T @ field_ned
        h = np.zeros(E_SIZE)
        if i == 0:
            h[E_ANG + 1], h[E_ANG + 2] = -m[2], m[1]
        elif i == 1:
            h[E_ANG + 0], h[E_ANG + 2] = m[2], -m[0]
        else:
            h[E_ANG + 0], h[E_ANG + 1] = -m[1], m[0]
        worst = max(worst, fuse_scalar(x, p, h, mag_frd[i] - m[i], noise.mag_gauss ** 2,
                                       noise.gate_sigma))
    return worst


@njit(cache=True)
def fuse_baro(x: np.ndarray, p: np.ndarray, baro_alt_m: float, noise: FilterNoise) -> float:
    h = np.zeros(E_SIZE)
    h[E_POS + 2] = -1.0
    h[E_BARO] = 1.0
    return fuse_scalar(x, p, h, baro_alt_m - (-x[X_POS + 2] + x[X_BARO]), noise.baro_m ** 2,
                       noise.gate_sigma)


@njit(cache=True)
def fuse_gps(x: np.ndarray, p: np.ndarray, gps: np.ndarray, noise: FilterNoise,
             ratios: np.ndarray) -> None:
    """Position NED and velocity NED of a fix (gps[0:6]), axis by axis; the test ratios
    go to ``ratios`` (6)."""
    for i in range(6):
        h = np.zeros(E_SIZE)
        h[i] = 1.0
        if i < 2:
            sigma = noise.gps_horizontal_m
        elif i == 2:
            sigma = noise.gps_vertical_m
        else:
            sigma = noise.gps_velocity_mps
        ratios[i] = fuse_scalar(x, p, h, gps[i] - x[i], sigma * sigma, noise.gate_sigma)


@njit(cache=True)
def step(x: np.ndarray, p: np.ndarray, imu: np.ndarray, baro_alt_m: float,
         mag_frd: np.ndarray, field_ned: np.ndarray, noise: FilterNoise,
         ratios: np.ndarray) -> None:
    """One sample: predict with the IMU, then fuse the baro and the magnetometer when the
    sample has them (NaN: none). Test ratios go to ratios[0] (baro), ratios[1] (mag)."""
    predict(x, p, imu, noise)
    if not math.isnan(baro_alt_m):
        ratios[0] = fuse_baro(x, p, baro_alt_m, noise)
    if not math.isnan(mag_frd[0]):
        ratios[1] = fuse_mag(x, p, mag_frd, field_ned, noise)


@njit(cache=True)
def step_recorded(i: int, time_us: int, gyro: np.ndarray, accel: np.ndarray, dt: float,
                  baro_alt_m: float, mag_frd: np.ndarray, field_ned: np.ndarray,
                  hist_t: np.ndarray, hist_x: np.ndarray, hist_p: np.ndarray,
                  hist_imu: np.ndarray, hist_baro: np.ndarray, hist_mag: np.ndarray,
                  x: np.ndarray, p: np.ndarray, noise: FilterNoise, ratios: np.ndarray) -> None:
    """:func:`step`, and the sample and its result kept in history entry ``i`` (for GPS
    fixes that arrive late)."""
    imu = hist_imu[i]
    imu[0:3] = gyro
    imu[3:6] = accel
    imu[6] = dt
    hist_mag[i] = mag_frd
    hist_baro[i] = baro_alt_m
    step(x, p, imu, baro_alt_m, hist_mag[i], field_ned, noise, ratios)
    hist_t[i] = time_us
    hist_x[i] = x
    hist_p[i] = p


@njit(cache=True)
def measurement_of(x: np.ndarray, gyro: np.ndarray, out: np.ndarray) -> None:
    """The controller's measurement layout (contracts.vectors.MEASUREMENT: position,
    velocity, Euler angles, Euler rates) of the estimate; the rates are the gyro's less
    the estimated bias."""
    for i in range(3):
        out[MEAS_POS + i] = x[X_POS + i]
        out[MEAS_VEL + i] = x[X_VEL + i]
    euler = euler_from_quat(x[X_QUAT:X_QUAT + 4])
    out[MEAS_EULER:MEAS_EULER + 3] = euler
    out[MEAS_EULER_RATE:MEAS_EULER_RATE + 3] = euler_rates_from_body_rates(
        euler[0], euler[1], gyro[0] - x[X_GYRO_BIAS], gyro[1] - x[X_GYRO_BIAS + 1],
        gyro[2] - x[X_GYRO_BIAS + 2])


@njit(cache=True)
def replay_from(start: int, newest: int, size: int, hist_x: np.ndarray, hist_p: np.ndarray,
                hist_imu: np.ndarray, hist_baro: np.ndarray, hist_mag: np.ndarray,
                field_ned: np.ndarray, x: np.ndarray, p: np.ndarray,
                noise: FilterNoise) -> None:
    """Re-run the samples after ring index ``start`` up to ``newest`` from (x, p), storing
    each step's result in the history; x, p end at the newest."""
    ratios = np.zeros(2)
    i = start
    while i != newest:
        i = (i + 1) % size
        step(x, p, hist_imu[i], hist_baro[i], hist_mag[i], field_ned, noise, ratios)
        hist_x[i] = x
        hist_p[i] = p


@njit(cache=True)
def fuse_gps_delayed(fix_time_us: int, gps: np.ndarray, newest: int, count: int,
                     hist_t: np.ndarray, hist_x: np.ndarray, hist_p: np.ndarray,
                     hist_imu: np.ndarray, hist_baro: np.ndarray, hist_mag: np.ndarray,
                     field_ned: np.ndarray, x: np.ndarray, p: np.ndarray,
                     noise: FilterNoise, ratios: np.ndarray) -> bool:
    """Fuse a GPS fix valid at ``fix_time_us`` at that time: from the newest history entry
    not after it, then replay to now. False (nothing changed) if the history does not
    reach back that far."""
    size = hist_t.size
    i = newest
    for _ in range(count):
        if hist_t[i] <= fix_time_us:
            x[:] = hist_x[i]
            p[:, :] = hist_p[i]
            fuse_gps(x, p, gps, noise, ratios)
            hist_x[i] = x
            hist_p[i] = p
            replay_from(i, newest, size, hist_x, hist_p, hist_imu, hist_baro, hist_mag,
                        field_ned, x, p, noise)
            return True
        i = (i - 1) % size
    return False
