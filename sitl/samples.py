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

from contracts.frames import Home
from contracts.mavlink import mavlink
from contracts.perturbations import NO_SENSOR_EFFECTS, SensorEffects
from contracts.sim_samples import FIX_SIZE, SAMPLE_BYTES, gps_fix, pack_sample, sample_frames
from sitl.plant import VehicleState
from sitl.sensors import (
    SensorProfile,
    SensorSuite,
    seen_by_the_gyro,
    sensed_state,
    truth_sample,
)

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
        self._imu_state = state  # what the IMU reads (seen_by_the_gyro)
        self._history: collections.deque[VehicleState] = collections.deque(
            maxlen=HISTORY_SAMPLES)
        self._previous_velocity = state.velocity_ned_mps
        self._acceleration = np.zeros(3)
        self._home = np.array(home, dtype=np.float64)
        self._fix = np.zeros(FIX_SIZE)  # the last fix out of the receiver (FIX_*)
        self._out = np.empty(SAMPLE_BYTES, dtype=np.uint8)  # one sample's frames

    def observe(self, before: VehicleState, after: VehicleState, period_s: float) -> None:
        """The plant went from ``before`` to ``after`` over one sample period."""
        self._imu_state = seen_by_the_gyro(before, after, period_s)
        self._history.append(after)
        velocity = after.velocity_ned_mps
        self._acceleration = (velocity - self._previous_velocity) / period_s
        self._previous_velocity = velocity

    def frames(self, time_us: int, state: VehicleState, effects: SensorEffects,
               mav: mavlink.MAVLink,
               on_readings: Callable[[bytes, bytes | None], None] | None = None
               ) -> bytes | None:
        """The sample at ``time_us`` (``state``: the plant's then) under ``effects``,
        packed on ``mav``; None when the link loses it. ``on_readings`` gets the HIL_SENSOR
        and HIL_GPS frames of a sample sent."""
        fix = self.sensors.read(time_us, self._imu_state, self._acceleration, effects)
        position, velocity = state.position_ned_m, state.velocity_ned_mps
        quaternion, body_rate = state.quaternion, state.body_rate_rad_s
        if effects is not NO_SENSOR_EFFECTS:
            if effects.loss_fraction > 0.0 and self.rng.random() < effects.loss_fraction:
                return None
            position, velocity, quaternion, body_rate = sensed_state(
                state, self._history, effects, self.rng)
        if mav.signing.sign_outgoing:  # pymavlink signs
            sensor = self.sensors.sensor_sample(time_us)
            truth = truth_sample(time_us, state, self._acceleration, position, velocity,
                                 quaternion, body_rate)
            return sample_frames(truth, sensor, fix, self.home, mav, on_readings)
        if fix is not None:
            self._fix[:] = gps_fix(fix)
        out = self._out
        end, sensor_end, gps_end = pack_sample(
            out, mav.seq, mav.srcSystem, mav.srcComponent, self._home, time_us, position,
            velocity, quaternion, body_rate, self._acceleration, self.sensors.reading,
            self._fix, -1 if fix is None else fix.time_us)
        if on_readings is not None:
            on_readings(out[gps_end:sensor_end].tobytes(),
                        out[:gps_end].tobytes() if gps_end else None)
        return out[:end].tobytes()
