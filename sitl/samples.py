"""What the simulator sends the autopilot each sample: the sensors' readings and the truth
messages, under the sensor and link effects in force.

The readings need more than the plant's state at the sample: the rotation the gyro saw
over the last period, the acceleration over it, and (for a link delay) the recent states.
``SampleSource`` keeps that memory; the simulator tells it each state the plant reaches.
"""

from __future__ import annotations

import collections
from collections.abc import Callable

import numpy as np
from numba import njit

from contracts.frames import Home
from contracts.mavlink import mavlink
from contracts.perturbations import NO_SENSOR_EFFECTS, SensorEffects
from contracts.sim_samples import FIX_SIZE, SAMPLE_BYTES, gps_fix, pack_sample, sample_frames
from contracts.vectors import TRUTH, TRUTH_BODY_RATE, TRUTH_VEL
from sitl.plant import VehicleState, state_of
from sitl.sensors import SensorProfile, SensorSuite
from sitl.truth import gyro_rotation_rate, sensed_state, truth_sample

HISTORY_SAMPLES = 101  # the longest link delay (100 samples) and the state at the sample


class SampleSource:
    """The messages of each sample, from the states the plant went through. ``seed``
    seeds the sensors' noise and, apart, the link's loss and the noise on the state sent,
    so a run sends the same bytes each time."""

    def __init__(self, profile: SensorProfile, rate_hz: float, seed: int, home: Home,
                 state: VehicleState) -> None:
        self.rng = np.random.default_rng(seed)
        self.sensors = SensorSuite(profile, rate_hz, seed, home)
        self.home = home
        # What the IMU reads (``observe``): the state's numbers, its body rates the
        # rotation a landing made (gyro_rotation_rate).
        self._imu = state.numbers().copy()
        self._history: collections.deque[VehicleState] = collections.deque(
            maxlen=HISTORY_SAMPLES)
        self._previous_velocity = state.velocity_ned_mps.copy()
        self._acceleration = np.zeros(3)
        self._home = np.array(home, dtype=np.float64)
        self._fix = np.zeros(FIX_SIZE)  # the last fix out of the receiver (FIX_*)
        self._out = np.empty(SAMPLE_BYTES, dtype=np.uint8)  # one sample's frames

    def observe(self, before: VehicleState, after: VehicleState, period_s: float) -> None:
        """The plant went from ``before`` to ``after`` over one sample period."""
        observe_period(before.numbers(), after.numbers(), period_s, self._previous_velocity,
                       self._acceleration, self._imu)
        self._history.append(after)

    def frames(self, time_us: int, state: VehicleState, effects: SensorEffects,
               mav: mavlink.MAVLink,
               on_readings: Callable[[bytes, bytes | None], None] | None = None
               ) -> bytes | None:
        """The sample at ``time_us`` (``state``: the plant's then) under ``effects``,
        packed on ``mav``; None when the link loses it. ``on_readings`` gets the HIL_SENSOR
        and HIL_GPS frames of a sample sent."""
        fix = self.sensors.read(time_us, self._imu, self._acceleration, effects)
        truth = state.numbers()
        if effects is not NO_SENSOR_EFFECTS:
            if effects.loss_fraction > 0.0 and self.rng.random() < effects.loss_fraction:
                return None
            position, velocity, quaternion, body_rate = sensed_state(
                state, self._history, effects, self.rng)
            truth = truth.copy()
            truth[TRUTH.position_ned_m], truth[TRUTH.velocity_ned_mps] = position, velocity
            truth[TRUTH.quaternion], truth[TRUTH.body_rate_rad_s] = quaternion, body_rate
        if mav.signing.sign_outgoing:  # pymavlink signs
            sent = state_of(state.time_s, truth)
            return sample_frames(
                truth_sample(time_us, sent, self._acceleration),
                self.sensors.sensor_sample(time_us), fix, self.home, mav, on_readings)
        if fix is not None:
            self._fix[:] = gps_fix(fix)
        out = self._out
        end, sensor_end, gps_end = pack_sample(
            out, mav.seq, mav.srcSystem, mav.srcComponent, self._home, time_us, truth,
            self._acceleration, self.sensors.reading, self._fix,
            -1 if fix is None else fix.time_us)
        if on_readings is not None:
            on_readings(out[gps_end:sensor_end].tobytes(),
                        out[:gps_end].tobytes() if gps_end else None)
        return out[:end].tobytes()


@njit(cache=True)
def observe_period(before: np.ndarray, after: np.ndarray, period_s: float,
                   previous_velocity: np.ndarray, acceleration: np.ndarray,
                   imu: np.ndarray) -> None:
    """One sample period from ``before`` to ``after`` (their numbers, TRUTH): what the
    IMU reads of ``after`` into ``imu`` (its body rates the landing's rotation,
    gyro_rotation_rate), the period's mean acceleration (velocity from the last period's
    end) into ``acceleration``, and ``previous_velocity`` moved on."""
    imu[:] = after
    rate = np.empty(3)
    if gyro_rotation_rate(before, after, period_s, rate):
        imu[TRUTH_BODY_RATE:TRUTH_BODY_RATE + 3] = rate
    for i in range(3):
        velocity = after[TRUTH_VEL + i]
        acceleration[i] = (velocity - previous_velocity[i]) / period_s
        previous_velocity[i] = velocity
