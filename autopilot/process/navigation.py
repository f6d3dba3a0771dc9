"""What the controller flies on: the simulator's truth as sent, or the onboard estimator
fed the simulated sensors (``--state-source estimator``).

The process owns the estimator (not the simulator link, which only decodes): IMU
readings step it, GPS fixes go into it, and its status reaches the vehicle: arming waits
until it has converged, and losing and regaining GPS is announced.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.commander.failures import ACCEL, BARO, GPS, GYRO, MAG
from autopilot.estimation.estimator import Estimator
from autopilot.process.sim_link import GpsReading, ImuReading, LinkReading, TruthReading
from contracts.frames import Home
from contracts.mavlink import GYRO_MATCH_US, set_body_rates


class Navigation:
    """The measurement of each sample from the link, and the estimator's news for the
    vehicle; ``estimator`` is None when flying on the simulator's truth."""

    def __init__(self, vehicle: Commander, estimator: Estimator | None) -> None:
        self.vehicle = vehicle
        self.estimator = estimator
        self._gps_ok: bool | None = None
        self._position_lost = False  # dead reckoning past EKF2_NOAID_TOUT, until a fix
        self._gyro: ImuReading | None = None  # on the truth: the latest gyro reading

    @classmethod
    def for_source(cls, vehicle: Commander, source: str) -> Navigation:
        """On the estimator when ``source`` says so, its GPS delay the vehicle's
        EKF2_GPS_DELAY."""
        estimator = (Estimator(gps_delay_s=vehicle.parameters["EKF2_GPS_DELAY"] / 1e3)
                     if source == "estimator" else None)
        return cls(vehicle, estimator)

    def measurements(self, readings: list[LinkReading]
                     ) -> list[tuple[int, np.ndarray | None]]:
        """(time_us, measurement) of each sample in ``readings``, in order: the truth as
        sent, or on the estimator each IMU reading steps it and the sample's measurement
        is the estimate (None until it has aligned); a fix goes into it and is no sample.
        All readings are taken before any sample is flown, as they came in together."""
        est = self.estimator
        if est is None:
            return self._truth_samples(readings)
        samples = []
        failed = self.vehicle.failures  # injected failures act on each sensor's data
        for reading in readings:
            if isinstance(reading, GpsReading):
                fix = failed.sensor(GPS, reading.fix)
                if fix is not None:
                    est.gps(reading.time_us, fix)
            elif isinstance(reading, ImuReading):
                gyro = failed.sensor(GYRO, reading.gyro)
                accel = failed.sensor(ACCEL, reading.accel)
                if gyro is None or accel is None:  # no IMU sample: nothing to step on
                    samples.append((reading.time_us, est.measurement() if est.aligned
                                    else None))
                    continue
                baro_alt_m = math.nan
                if self.vehicle.home_known and math.isfinite(reading.baro_alt_amsl_m):
                    baro = failed.sensor(BARO, reading.baro_alt_amsl_m)
                    baro_alt_m = math.nan if baro is None else \
                        baro - self.vehicle.places.origin.alt_amsl_m
                est.imu(reading.time_us, gyro, accel, baro_alt_m,
                        failed.sensor(MAG, reading.mag))
                samples.append((reading.time_us, est.measurement() if est.aligned else None))
            else:
                samples.append(reading)
        return samples

    def _truth_samples(self, readings: list[LinkReading]
                       ) -> list[tuple[int, np.ndarray | None]]:
        """On the simulator's truth: each truth sample, its body rates the gyro's of the
        same sample when HIL_SENSOR came with it (PX4's rate loop flies on the gyro),
        else the truth's own; an IMU reading is no sample."""
        samples = []
        for reading in readings:
            if isinstance(reading, ImuReading):
                gyro = self.vehicle.failures.sensor(GYRO, reading.gyro)
                if gyro is not None:  # a failed gyro that gives nothing: the truth's rates
                    self._gyro = reading if gyro is reading.gyro else \
                        reading._replace(gyro=gyro)
            elif isinstance(reading, TruthReading):
                gyro = self._gyro
                if gyro is not None and abs(reading.time_us - gyro.time_us) <= GYRO_MATCH_US:
                    # (a measurement just decoded, the reading's own: changed in place)
                    set_body_rates(reading.measurement, gyro.gyro)
                samples.append(reading)
        return samples

    def set_home(self, home: Home) -> None:
        """The estimator's field for ``home`` (the vehicle's own home is the vehicle's)."""
        if self.estimator is not None:
            self.estimator.set_home(home)

    def aligning(self, time_us: int) -> None:
        """A sample without a measurement: arming waits for the estimator to align."""
        self.vehicle.navigation_problem = f"estimator {self.estimator.status(time_us).reason}"

    def update(self, time_us: int) -> None:
        """Before a sample is flown: arming waits for the estimator; GPS loss and return
        are announced (on the simulator's truth there is nothing to tell)."""
        est = self.estimator
        if est is None:
            return
        v = self.vehicle
        est.gps_delay_us = round(v.parameters["EKF2_GPS_DELAY"] * 1e3)
        status = est.status(time_us)
        v.navigation_problem = None if status.converged else f"estimator {status.reason}"
        if status.gps_ok != self._gps_ok:
            if self._gps_ok is not None:
                v.say("GPS regained" if status.gps_ok else "GPS lost: dead reckoning",
                      6 if status.gps_ok else 4)
            self._gps_ok = status.gps_ok
        # PX4's EKF2_NOAID_TOUT: dead reckoning has a limit, then the position is lost.
        limit_s = v.parameters["EKF2_NOAID_TOUT"] / 1e6
        if status.gps_ok:
            self._position_lost = False
        elif status.aligned and status.since_gps_s > limit_s and not self._position_lost:
            self._position_lost = True
            v.position_lost(f"position lost: no GPS fix for {limit_s:g} s")
        v.estimator_status = status
