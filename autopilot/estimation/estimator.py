"""The onboard estimator around its numerical core (eskf.py): alignment, the GPS delay
history, health, and the measurement the controller reads. Pure: no I/O, no clock; time
is the samples' time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.estimation import eskf
from contracts.frames import DEFAULT_HOME, Home, quat_from_euler
from contracts.vectors import MEASUREMENT

# The history reaches back 0.4 s at 1000 Hz (1.6 s at 250 Hz): beyond EKF2_GPS_DELAY's
# 300 ms at any simulator rate.
HISTORY_SAMPLES = 400
GPS_TIMEOUT_S = 1.0  # no fix fused for this long: dead reckoning
# Converged: what the pre-arm check waits for (1-sigma; tilt is roll and pitch together,
# which at rest is slow to part from the accelerometer's bias).
CONVERGED_TILT_RAD = 0.02
CONVERGED_YAW_RAD = 0.1
CONVERGED_HORIZONTAL_M = 1.5
CONVERGED_VELOCITY_MPS = 0.3
SETTLE_S = 2.0  # after alignment, before the estimate may be called converged
BARO_REFERENCE_M = 0.1  # 1-sigma of the baro's offset from home's altitude at alignment


@dataclass
class GpsFix:
    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    fix_type: int  # 3 = 3D
    satellites: int


@dataclass
class EstimatorStatus:
    """What the pre-arm check, ESTIMATOR_STATUS and telemetry read."""

    aligned: bool
    converged: bool
    gps_ok: bool  # a fix fused within GPS_TIMEOUT_S
    since_gps_s: float  # since the last fix fused (inf before the first): dead reckoning
    reason: str  # why not converged ("" when it is)
    tilt_sigma_rad: float
    yaw_sigma_rad: float
    horizontal_sigma_m: float
    vertical_sigma_m: float
    velocity_sigma_mps: float
    gps_test_ratio: float  # largest of the last fix's axes (> 1: rejected)
    gps_position_test_ratio: float  # horizontal position axes
    gps_velocity_test_ratio: float
    baro_test_ratio: float
    mag_test_ratio: float
    gps_rejected: int
    gps_late: int


def heading_from_mag(mag_frd: np.ndarray, phi: float, theta: float,
                     declination_rad: float) -> float:
    """Yaw [rad] of a magnetometer reading, tilt-compensated with the estimated roll and
    pitch: the field levelled is H (cos(D - psi), sin(D - psi), .)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    mx, my, mz = (float(v) for v in mag_frd)
    level_x = cth * mx + sth * sphi * my + sth * cphi * mz
    level_y = cphi * my - sphi * mz
    return math.atan2(math.sin(declination_rad - math.atan2(level_y, level_x)),
                      math.cos(declination_rad - math.atan2(level_y, level_x)))


class Estimator:
    """IMU + GPS + baro + magnetometer -> the controller's measurement."""

    def __init__(self, noise: eskf.FilterNoise | None = None, gps_delay_s: float = 0.11,
                 home: Home = DEFAULT_HOME) -> None:
        self.noise = noise or eskf.FilterNoise()
        self.gps_delay_us = round(gps_delay_s * 1e6)
        self.set_home(home)
        self.x = np.zeros(eskf.X_SIZE)
        self.x[eskf.X_QUAT] = 1.0
        self.p = np.eye(eskf.E_SIZE)
        n = HISTORY_SAMPLES
        self._hist_t = np.zeros(n, dtype=np.int64)
        self._hist_x = np.zeros((n, eskf.X_SIZE))
        self._hist_p = np.zeros((n, eskf.E_SIZE, eskf.E_SIZE))
        self._hist_imu = np.zeros((n, eskf.IMU_SIZE))
        self._hist_baro = np.full(n, np.nan)
        self._hist_mag = np.full((n, 3), np.nan)
        self._newest = -1
        self._count = 0
        self._ratios = np.zeros(2)
        self._gps_ratios = np.zeros(6)
        self._gyro = np.zeros(3)
        self._last_time_us: int | None = None
        self._pending_fix: GpsFix | None = None  # the fix alignment waits for
        self._waiting: list[tuple[int, GpsFix]] = []  # fixes ahead of the IMU
        self._aligned_at_us: int | None = None
        self._last_fused_gps_us: int | None = None
        self._no_mag = np.full(3, np.nan)
        self._out = np.empty(MEASUREMENT.size)
        self._align_mag: np.ndarray | None = None
        self._align_baro: float | None = None
        self.gps_rejected = 0
        self.gps_late = 0
        self._converged = False

    def set_home(self, home: Home) -> None:
        """The field at home, as PX4 looks it up for its position (the world magnetic
        model); a home taken from the simulator's first message arrives this way."""
        self.field_ned = np.array(home.mag_field_ned_gauss())
        self.declination_rad = home.mag_declination_rad()

    @property
    def aligned(self) -> bool:
        return self._aligned_at_us is not None

    # -- inputs ---------------------------------------------------------------------------

    def gps(self, received_us: int, fix: GpsFix) -> None:
        """A fix that arrived at ``received_us``; valid gps_delay earlier (EKF2_GPS_DELAY)."""
        if fix.fix_type < 3:
            return
        if not self.aligned:
            self._pending_fix = fix
            return
        fix_time = received_us - self.gps_delay_us
        if fix_time > self._hist_t[self._newest]:
            # Newer than the last IMU sample: fused once the filter has reached its time.
            self._waiting.append((received_us, fix))
            return
        self._fuse_gps(received_us, fix_time, fix)

    def _fuse_gps(self, received_us: int, fix_time: int, fix: GpsFix) -> None:
        gps = np.concatenate([fix.position_ned_m, fix.velocity_ned_mps])
        fused = eskf.fuse_gps_delayed(
            fix_time, gps, self._newest, self._count, self._hist_t, self._hist_x,
            self._hist_p, self._hist_imu, self._hist_baro, self._hist_mag, self.field_ned,
            self.x, self.p, self.noise, self._gps_ratios)
        if not fused:
            self.gps_late += 1
        elif np.any(self._gps_ratios > 1.0):
            self.gps_rejected += 1
        # GPS counts as in use while its horizontal position is fused.
        if fused and np.all(self._gps_ratios[0:2] <= 1.0):
            self._last_fused_gps_us = received_us

    def imu(self, time_us: int, gyro_frd_rad_s: np.ndarray, accel_frd_mps2: np.ndarray,
            baro_alt_m: float = math.nan, mag_frd_gauss: np.ndarray | None = None) -> None:
        """One sample of the IMU, with the baro altitude and magnetometer when the sample
        has fresh ones. Time must increase."""
        gyro = np.asarray(gyro_frd_rad_s, dtype=np.float64)
        accel = np.asarray(accel_frd_mps2, dtype=np.float64)
        self._gyro = gyro
        if not self.aligned:
            if mag_frd_gauss is not None:
                self._align_mag = np.asarray(mag_frd_gauss, dtype=float)
            if not math.isnan(baro_alt_m):
                self._align_baro = baro_alt_m
            if self._pending_fix is not None and self._align_mag is not None and \
                    self._align_baro is not None:
                self._align(time_us, accel, self._align_mag, self._align_baro)
            return
        dt = (time_us - self._last_time_us) / 1e6
        self._last_time_us = time_us
        if not 0.0 < dt <= 0.1:
            return
        i = (self._newest + 1) % HISTORY_SAMPLES
        eskf.step_recorded(i, time_us, gyro, accel, dt, baro_alt_m,
                           self._no_mag if mag_frd_gauss is None else mag_frd_gauss,
                           self.field_ned, self._hist_t, self._hist_x, self._hist_p,
                           self._hist_imu, self._hist_baro, self._hist_mag, self.x, self.p,
                           self.noise, self._ratios)
        self._newest = i
        self._count = min(self._count + 1, HISTORY_SAMPLES)
        while self._waiting and self._waiting[0][0] - self.gps_delay_us <= time_us:
            received_us, fix = self._waiting.pop(0)
            self._fuse_gps(received_us, received_us - self.gps_delay_us, fix)

    def _align(self, time_us: int, accel: np.ndarray, mag: np.ndarray, baro_alt_m: float) -> None:
        """Attitude from gravity and the magnetometer, horizontal position and velocity
        from the fix, height from the barometer: as PX4's EKF2 (EKF2_HGT_REF baro), the
        baro is the height reference, its altitude above home read in the standard
        atmosphere; the GPS's vertical error (often a metre) would otherwise be the
        vehicle's height error from the start."""
        fix = self._pending_fix
        ax, ay, az = accel
        phi = math.atan2(-ay, -az)
        theta = math.atan2(ax, math.hypot(ay, az))
        psi = heading_from_mag(mag, phi, theta, self.declination_rad)
        x = self.x
        x[:] = 0.0
        x[eskf.X_POS:eskf.X_POS + 2] = fix.position_ned_m[0:2]
        x[eskf.X_POS + 2] = -baro_alt_m
        x[eskf.X_VEL:eskf.X_VEL + 3] = fix.velocity_ned_mps
        x[eskf.X_QUAT:eskf.X_QUAT + 4] = quat_from_euler(phi, theta, psi)
        x[eskf.X_BARO] = 0.0
        n = self.noise
        sigma = np.array([n.gps_horizontal_m] * 2 + [n.baro_m]
                         + [n.gps_velocity_mps * 2] * 3 + [0.05, 0.05, 0.2]
                         + [0.01] * 3 + [0.2] * 3 + [BARO_REFERENCE_M])
        self.p = np.diag(sigma**2)
        self._last_time_us = time_us
        self._aligned_at_us = time_us
        self._last_fused_gps_us = time_us
        self._pending_fix = None
        i = (self._newest + 1) % HISTORY_SAMPLES
        self._hist_t[i] = time_us
        self._hist_x[i] = self.x
        self._hist_p[i] = self.p
        self._hist_imu[i] = 0.0
        self._hist_baro[i] = math.nan
        self._hist_mag[i] = math.nan
        self._newest = i
        self._count = 1

    # -- outputs --------------------------------------------------------------------------

    def measurement(self) -> np.ndarray:
        """The controller's measurement (contracts.vectors.MEASUREMENT) of the estimate;
        Euler rates from the latest gyro reading less the estimated bias."""
        eskf.measurement_of(self.x, self._gyro, self._out)
        return self._out.copy()

    def quaternion(self) -> np.ndarray:
        return self.x[eskf.X_QUAT:eskf.X_QUAT + 4].copy()

    def status(self, time_us: int) -> EstimatorStatus:
        p = self.p
        tilt = math.sqrt(max(p[eskf.E_ANG, eskf.E_ANG] + p[eskf.E_ANG + 1, eskf.E_ANG + 1],
                             0.0))
        yaw = self._yaw_sigma()
        horizontal = math.sqrt(max(p[0, 0] + p[1, 1], 0.0))
        vertical = math.sqrt(max(p[2, 2], 0.0))
        velocity = math.sqrt(max(p[3, 3] + p[4, 4] + p[5, 5], 0.0))
        gps_ok = self._last_fused_gps_us is not None and \
            time_us - self._last_fused_gps_us <= GPS_TIMEOUT_S * 1e6
        # Hysteresis: once converged, an uncertainty has to double before it counts again.
        margin = 2.0 if self._converged else 1.0
        reason = ""
        if not self.aligned:
            reason = "waiting for GPS fix, baro and magnetometer to align"
        elif time_us - self._aligned_at_us < SETTLE_S * 1e6:
            reason = "settling after alignment"
        elif not gps_ok:
            reason = "no GPS fix fused for over 1 s"
        elif tilt > margin * CONVERGED_TILT_RAD:
            reason = f"tilt not converged ({math.degrees(tilt):.1f} deg 1-sigma)"
        elif yaw > margin * CONVERGED_YAW_RAD:
            reason = f"heading not converged ({math.degrees(yaw):.1f} deg 1-sigma)"
        elif horizontal > margin * CONVERGED_HORIZONTAL_M:
            reason = f"position not converged ({horizontal:.1f} m 1-sigma)"
        elif velocity > margin * CONVERGED_VELOCITY_MPS:
            reason = f"velocity not converged ({velocity:.2f} m/s 1-sigma)"
        self._converged = reason == ""
        return EstimatorStatus(
            aligned=self.aligned, converged=reason == "", gps_ok=gps_ok,
            since_gps_s=(math.inf if self._last_fused_gps_us is None
                         else (time_us - self._last_fused_gps_us) / 1e6), reason=reason,
            tilt_sigma_rad=tilt, yaw_sigma_rad=yaw, horizontal_sigma_m=horizontal,
            vertical_sigma_m=vertical, velocity_sigma_mps=velocity,
            gps_test_ratio=float(np.max(self._gps_ratios)),
            gps_position_test_ratio=float(np.max(self._gps_ratios[0:2])),
            gps_velocity_test_ratio=float(np.max(self._gps_ratios[3:6])),
            baro_test_ratio=float(self._ratios[0]), mag_test_ratio=float(self._ratios[1]),
            gps_rejected=self.gps_rejected, gps_late=self.gps_late)

    def _yaw_sigma(self) -> float:
        h = eskf.heading_row(self.x)
        return math.sqrt(max(float(h @ self.p @ h), 0.0))

