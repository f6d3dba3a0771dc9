"""What the simulator reports of its truth (pure): the true sample the truth messages
carry, perfect readings of every sensor, the rotation a gyro sees when a landing levels
the vehicle, and what the older state perturbations (noise, bias, delay on the reported
truth) make of it. The sensors' own models are ``sitl/sensors.py``.
"""

from __future__ import annotations

import collections
import math

import numpy as np
from numba import njit

from contracts.frames import (
    DEFAULT_HOME,
    Home,
    pressure_hpa,
    quat_from_euler,
    rotation_from_quat,
    vector_norm,
)
from contracts.mavlink import HIL_SENSOR_BARO, HIL_SENSOR_IMU, HIL_SENSOR_MAG
from contracts.perturbations import SensorEffects
from contracts.sim_samples import GpsSample, SensorSample, TruthSample, specific_force
from contracts.vectors import TRUTH_BODY_RATE, TRUTH_POS, TRUTH_QUAT, TRUTH_VEL
from sitl.plant import VehicleState, state_of

TEMPERATURE_C = 20.0


def truth_sample(time_us: int, state: VehicleState, accel_ned_mps2: np.ndarray,
                 position=None, velocity=None, quaternion=None, body_rate=None) -> TruthSample:
    """The true state of one sample (or the given replacements, e.g. perturbed); the
    specific force is R^T (a - g) of the kinematic acceleration."""
    q = np.asarray(state.quaternion if quaternion is None else quaternion, dtype=float)
    specific = specific_force(q, np.asarray(accel_ned_mps2, dtype=float))
    return TruthSample(
        time_us, as_floats(state.position_ned_m if position is None else position),
        as_floats(state.velocity_ned_mps if velocity is None else velocity), as_floats(q),
        as_floats(state.body_rate_rad_s if body_rate is None else body_rate), as_floats(specific))


def ideal_readings(time_us: int, state: VehicleState, accel_ned_mps2: np.ndarray,
                   home: Home = DEFAULT_HOME) -> tuple[TruthSample, SensorSample, GpsSample]:
    """One sample's truth, and perfect readings of every sensor (all fresh, a fix now)."""
    truth = truth_sample(time_us, state, accel_ned_mps2)
    rot = rotation_from_quat(np.asarray(state.quaternion, dtype=float))
    lat, lon, alt = home.geodetic_from_ned(*(float(v) for v in state.position_ned_m))
    sensor = SensorSample(time_us, truth.specific_force_frd_mps2, truth.body_rate_frd_rad_s,
                          as_floats(rot.T @ np.array(home.mag_field_ned_gauss())),
                          pressure_hpa(alt), alt, TEMPERATURE_C,
                          HIL_SENSOR_IMU | HIL_SENSOR_MAG | HIL_SENSOR_BARO)
    fix = GpsSample(time_us, lat, lon, alt, truth.velocity_ned_mps, 0.8, 1.2, 3, 14)
    return truth, sensor, fix


@njit(cache=True)
def gyro_rotation_rate(before: np.ndarray, after: np.ndarray, period_s: float,
                       out: np.ndarray) -> bool:
    """When the ground contact levelled the vehicle within the period (it does so in one
    integration step, at rest after), the rotation it made over the period as a rate
    into ``out`` (what a real gyro integrating the impact reads), and True; else False.
    ``before``, ``after``: the states' numbers (contracts/vectors.py TRUTH)."""
    if not (after[TRUTH_POS + 2] == 0.0 and before[TRUTH_POS + 2] < 0.0):
        return False
    for i in range(3):
        if after[TRUTH_VEL + i] != 0.0 or after[TRUTH_BODY_RATE + i] != 0.0:
            return False
    w0, x0, y0, z0 = (before[TRUTH_QUAT], before[TRUTH_QUAT + 1], before[TRUTH_QUAT + 2],
                      before[TRUTH_QUAT + 3])
    w1, x1, y1, z1 = (after[TRUTH_QUAT], after[TRUTH_QUAT + 1], after[TRUTH_QUAT + 2],
                      after[TRUTH_QUAT + 3])
    # conj(q_before) * q_after: the rotation in the body frame of before
    w = w0 * w1 + x0 * x1 + y0 * y1 + z0 * z1
    v = np.empty(3)
    v[0] = w0 * x1 - x0 * w1 - y0 * z1 + z0 * y1
    v[1] = w0 * y1 + x0 * z1 - y0 * w1 - z0 * x1
    v[2] = w0 * z1 - x0 * y1 + y0 * x1 - z0 * w1
    if w < 0.0:
        w = -w
        for i in range(3):
            v[i] = -v[i]
    norm = vector_norm(v)
    if norm == 0.0:
        return False
    angle = 2.0 * math.atan2(norm, w)
    for i in range(3):
        out[i] = angle * v[i] / norm / period_s
    return True


def seen_by_the_gyro(before: VehicleState, after: VehicleState, period_s: float
                     ) -> VehicleState:
    """``after`` as the IMU reads it: with the rotation the ground contact made over the
    period as its body rates when it levelled the vehicle (``gyro_rotation_rate``), else
    ``after`` itself."""
    rate = np.empty(3)
    if not gyro_rotation_rate(before.numbers(), after.numbers(), period_s, rate):
        return after
    values = after.numbers().copy()
    values[TRUTH_BODY_RATE:TRUTH_BODY_RATE + 3] = rate
    return state_of(after.time_s, values)


def as_floats(values) -> tuple[float, ...]:
    """Python floats (what the messages take), in one conversion."""
    return tuple(np.asarray(values, dtype=float).tolist())


def sensed_state(state: VehicleState, history: collections.deque[VehicleState],
                 effects: SensorEffects, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(position, velocity, quaternion, body rates) as reported under sensor noise, bias
    and delay (``history`` holds the recent true states, newest last)."""
    delay = min(effects.delay_samples, len(history) - 1)
    s = history[-1 - delay] if delay > 0 else state
    noise = rng.normal(size=12) if (effects.noise_position_m or effects.noise_velocity_mps
                                    or effects.noise_angle_rad or effects.noise_rate_rad_s) \
        else np.zeros(12)
    position = s.position_ned_m + effects.bias_position_m + \
        effects.noise_position_m * noise[0:3]
    velocity = s.velocity_ned_mps + effects.bias_velocity_mps + \
        effects.noise_velocity_mps * noise[3:6]
    euler = s.euler_rad + effects.bias_angle_rad + effects.noise_angle_rad * noise[6:9]
    rates = s.body_rate_rad_s + effects.bias_rate_rad_s + effects.noise_rate_rad_s * noise[9:12]
    return position, velocity, quat_from_euler(*euler), rates
