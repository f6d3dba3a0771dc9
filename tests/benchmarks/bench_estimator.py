"""What the onboard estimator costs (the issue's aim: an IMU step under 20 us).

    python tests/benchmarks/bench_estimator.py

Feeds the estimator the typical sensor profile's readings of a hovering vehicle at
250 Hz (GPS 10 Hz, 110 ms late) and times, separately:

* the IMU step: ``Estimator.imu`` (predict, and baro / magnetometer when fresh), and its
  compiled core ``eskf.step`` alone;
* the GPS step: ``Estimator.gps`` with a fix 110 ms late (back 28 samples, fuse, replay);
* ``Estimator.measurement`` (what the controller reads each period).

Prints medians and 99th percentiles; asserts nothing.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from autopilot.estimation import eskf  # noqa: E402
from autopilot.estimation.estimator import Estimator, GpsFix  # noqa: E402
from contracts.frames import DEFAULT_HOME  # noqa: E402
from contracts.mavlink import HIL_SENSOR_BARO, HIL_SENSOR_MAG  # noqa: E402
from sitl.plant import VehicleState  # noqa: E402
from sitl.sensors import SensorSuite, read_profile  # noqa: E402

RATE_HZ = 250.0
SECONDS = 60


def percentiles(samples: list[float]) -> str:
    us = sorted(s * 1e6 for s in samples)
    return f"median {statistics.median(us):6.2f} us   p99 {us[int(0.99 * len(us))]:7.2f} us"


def main() -> None:
    suite = SensorSuite(read_profile("typical"), RATE_HZ, seed=0)
    state = VehicleState(0.0, np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3),
                         np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    est = Estimator(gps_delay_s=0.11)
    imu_times, core_times, gps_times, out_times = [], [], [], []
    x, p, ratios = est.x.copy(), est.p.copy(), np.zeros(2)
    field = est.field_ned
    for k in range(int(SECONDS * RATE_HZ)):
        t_us = round(k * 1e6 / RATE_HZ)
        sensor, fix = suite.sample(t_us, state, np.zeros(3))
        if fix is not None:
            position = np.array(DEFAULT_HOME.ned_from_geodetic(fix.lat_deg, fix.lon_deg,
                                                                fix.alt_amsl_m))
            start = time.perf_counter()
            est.gps(t_us, GpsFix(position, np.array(fix.velocity_ned_mps), 3, 14))
            if est.aligned:
                gps_times.append(time.perf_counter() - start)
        baro = sensor.pressure_alt_m - 488.0 if sensor.fields_updated & HIL_SENSOR_BARO \
            else float("nan")
        mag = np.array(sensor.mag_frd_gauss) if sensor.fields_updated & HIL_SENSOR_MAG \
            else None
        gyro, accel = np.array(sensor.gyro_frd_rad_s), np.array(sensor.accel_frd_mps2)
        start = time.perf_counter()
        est.imu(t_us, gyro, accel, baro, mag)
        imu_times.append(time.perf_counter() - start)
        start = time.perf_counter()
        est.measurement()
        out_times.append(time.perf_counter() - start)
        if est.aligned:
            imu = np.array([*gyro, *accel, 1.0 / RATE_HZ])
            mag_core = mag if mag is not None else np.full(3, np.nan)
            if k == 10:
                x, p = est.x.copy(), est.p.copy()
            start = time.perf_counter()
            eskf.step(x, p, imu, baro, mag_core, field, est.noise, ratios)
            core_times.append(time.perf_counter() - start)
    skip = int(RATE_HZ)  # the first second: compilation from the cache, alignment
    print(f"Estimator at {RATE_HZ:g} Hz, typical sensors, {SECONDS} s of hover:")
    print(f"  IMU step (Estimator.imu)         {percentiles(imu_times[skip:])}")
    print(f"  IMU step core (eskf.step)        {percentiles(core_times[skip:])}")
    print(f"  GPS step, 110 ms late (28 back)  {percentiles(gps_times[10:])}")
    print(f"  measurement()                    {percentiles(out_times[skip:])}")
    print(f"  GPS fixes: {len(gps_times)}, rejected {est.gps_rejected}, late {est.gps_late}")


if __name__ == "__main__":
    main()
