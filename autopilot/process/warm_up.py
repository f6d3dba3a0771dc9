"""Loading the compiled code before the control loop starts.

A first call of a numba function takes ~0.1 s from numba's cache (seconds to compile on
a fresh install): inside the loop that would be a deadline miss, or in real time a
simulator-link loss. So each compiled path a step takes runs once on scratch objects
first: the control law, the setpoint shaper, the conversions, a first decoded sample,
and on a scratch estimator, aligned, its filter steps.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.estimation.estimator import Estimator, GpsFix
from autopilot.flight_tasks import shaper
from autopilot.process.navigation import Navigation
from autopilot.process.sim_link import SimLink
from contracts.airframe import max_thrust_n
from contracts.frames import (
    DEFAULT_HOME,
    GRAVITY_MPS2,
    euler_from_quat,
    wrap_pi,
)
from contracts.mavlink import HIL_SENSOR_ALL_FIELDS, STATE_SOURCES
from contracts.sim_samples import GpsSample, SensorSample, TruthSample, sample_messages
from contracts.vectors import MEAS_Z, MEASUREMENT_SIZE, REF_SIZE


def load_compiled_code(vehicle: Commander, period_s: float, link: SimLink,
                       filter_steps: bool = True) -> None:
    """Run each compiled path once, on a scratch controller, estimator and samples (the
    vehicle and ``link`` are not changed: ``link`` only says which messages are read).
    ``filter_steps``: and, when ``link`` reads for the estimator, its filter's steps (0.1 s
    from numba's cache; the process loader leaves them to the runs on the estimator)."""
    scratch = vehicle.make_controller(vehicle.parameters)
    hover = np.zeros(MEASUREMENT_SIZE)
    hover[MEAS_Z] = -1.0
    scratch.step(hover, np.zeros(REF_SIZE), True, np.zeros(2))
    scratch.step(hover, np.zeros(REF_SIZE), True, np.zeros(2), math.nan, True)
    scratch.step(hover, np.zeros(REF_SIZE), False, np.zeros(2), 10.0, True)
    shaper.warm_up(vehicle.state.limits, period_s)
    wrap_pi(1.0)
    euler_from_quat(np.array([1.0, 0.0, 0.0, 0.0]))
    max_thrust_n(scratch.airframe)
    # A first decoded sample costs milliseconds; the estimator's compiled steps load on a
    # scratch estimator.
    scratch_navigation = Navigation(vehicle, Estimator())
    on_the_truth = Navigation(vehicle, None)  # the gyro's rates into the truth's measurement
    decoder = link.twin_at(DEFAULT_HOME)  # the link's own home is the simulator's to give
    for k in range(3):
        truth = TruthSample(k * 10_000, (0.0, 0.0, -1.0), (0.0, 0.0, 0.0),
                            (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -GRAVITY_MPS2))
        sensor = SensorSample(k * 10_000, (0.0, 0.0, -GRAVITY_MPS2), (0.0, 0.0, 0.0),
                              (0.2, 0.0, 0.4), 950.0, 500.0, 20.0, HIL_SENSOR_ALL_FIELDS)
        fix = GpsSample(k * 10_000, *DEFAULT_HOME.geodetic_from_ned(0.0, 0.0, -1.0),
                        (0.0, 0.0, 0.0), 0.8, 1.2, 3, 12)
        msgs = sample_messages(truth, sensor, fix, DEFAULT_HOME)
        for msg in msgs:
            if msg.get_type() in link.source_types:
                reading = decoder.decode(msg)
                scratch_navigation.measurements([reading])
                on_the_truth.measurements([reading])
        # The compiled reading of the frames and the compiled answer.
        decoder.readings_of(b"".join(m.pack(decoder.mav) for m in msgs))
        decoder.actuators_frame(k * 10_000, np.zeros(4), False, True)
    if filter_steps and link.source_types == STATE_SOURCES["estimator"]:
        _align_and_step(Estimator())


def _align_and_step(estimator: Estimator) -> None:
    """The filter's steps, fusions and output on a scratch estimator, aligned on a fix, the
    baro and the field at the default home. The navigation above cannot align its own
    before the vehicle knows its home (no baro without it), so these loaded at alignment,
    inside the loop."""
    estimator.set_home(DEFAULT_HOME)
    fix = GpsFix(np.zeros(3), np.zeros(3), 3, 12)
    estimator.gps(0, fix)
    for k in range(3):
        estimator.imu(k * 10_000, np.zeros(3), np.array([0.0, 0.0, -GRAVITY_MPS2]), 0.0,
                      np.array([0.2, 0.0, 0.4]))
        estimator.gps(k * 10_000 + estimator.gps_delay_us, fix)
        estimator.measurement()
