"""What the simulator's sensors read (pure): the IMU, magnetometer, barometer and GPS
readings of one sample from the true state, and what sensor perturbations (noise, bias,
delay) do to the state it reports.
"""

from __future__ import annotations

import collections

import numpy as np

from contracts.frames import GRAVITY_MPS2, geodetic_from_ned, quat_from_euler, world_to_body
from contracts.mavlink import SensorSample
from contracts.perturbations import SensorEffects
from sitl.plant import VehicleState

# Earth field at home (Zurich), gauss in NED, for the magnetometer.
MAG_FIELD_NED_GAUSS = (0.216, 0.006, 0.424)
SEA_LEVEL_PRESSURE_HPA = 1013.25
TEMPERATURE_C = 20.0


def pressure_hpa(alt_amsl_m: float) -> float:
    """International standard atmosphere below 11 km."""
    return SEA_LEVEL_PRESSURE_HPA * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


def read_sensors(time_us: int, position_ned_m: np.ndarray, velocity_ned_mps: np.ndarray,
                 quaternion: np.ndarray, body_rate_rad_s: np.ndarray,
                 accel_ned_mps2: np.ndarray) -> SensorSample:
    """Ideal readings of one sample. ``accel_ned_mps2`` is the kinematic acceleration; the
    accelerometer reads the specific force R^T (a - g) in FRD."""
    w, x, y, z = (float(v) for v in quaternion)
    ax, ay, az = (float(v) for v in accel_ned_mps2)
    n, e, d = (float(v) for v in position_ned_m)
    lat, lon, alt = geodetic_from_ned(n, e, d)
    return SensorSample(
        time_us=time_us,
        accel_frd_mps2=world_to_body(w, x, y, z, ax, ay, az - GRAVITY_MPS2),
        gyro_frd_rad_s=tuple(float(v) for v in body_rate_rad_s),
        mag_frd_gauss=world_to_body(w, x, y, z, *MAG_FIELD_NED_GAUSS),
        pressure_hpa=pressure_hpa(alt), pressure_alt_m=alt, temperature_c=TEMPERATURE_C,
        lat_deg=lat, lon_deg=lon, alt_amsl_m=alt, position_ned_m=(n, e, d),
        velocity_ned_mps=tuple(float(v) for v in velocity_ned_mps),
        quaternion=(w, x, y, z))


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
