"""What the simulator's sensors read (pure, seeded): an IMU, a magnetometer, a barometer and
a GPS receiver modelled as hardware is (noise, biases that wander, their own rates, the
GPS late and wrong by decimetres), from a named profile (docs/sensors.md). What the
truth messages carry, and the older state perturbations on them, are ``sitl/truth.py``'s.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from contracts.frames import (
    DEFAULT_HOME,
    GRAVITY_MPS2,
    SEA_LEVEL_PRESSURE_HPA,
    Home,
    pressure_hpa_compiled,
    rotation_from_quat,
)
from contracts.mavlink import HIL_SENSOR_BARO, HIL_SENSOR_IMU, HIL_SENSOR_MAG
from contracts.perturbations import NO_SENSOR_EFFECTS, SensorEffects
from contracts.sim_samples import (
    READING_ACCEL,
    READING_ALT,
    READING_FIELDS,
    READING_GYRO,
    READING_MAG,
    READING_PRESSURE,
    READING_SIZE,
    READING_TEMPERATURE,
    GpsSample,
    SensorSample,
)
from contracts.toml_files import read_named_toml, shipped_names
from contracts.toml_tables import check_fields, number
from contracts.vectors import TRUTH_BODY_RATE, TRUTH_POS, TRUTH_QUAT, TRUTH_VEL
from sitl.plant import VehicleState
from sitl.truth import TEMPERATURE_C, as_floats

PROFILES_DIR = "sensor_profiles"
_GRAVITY_NED = np.array((0.0, 0.0, GRAVITY_MPS2))


@dataclass(frozen=True)
class SensorProfile:
    """One sensor suite's numbers (1-sigma); zero means perfect."""

    name: str = "ideal"
    description: str = ""
    # IMU, at the sample rate (noise densities, as datasheets and PX4's Gazebo IMU give them)
    gyro_noise_rad_s_rthz: float = 0.0
    gyro_bias_walk_rad_s2_rthz: float = 0.0
    gyro_turn_on_bias_rad_s: float = 0.0
    accel_noise_mps2_rthz: float = 0.0
    accel_bias_walk_mps3_rthz: float = 0.0
    accel_turn_on_bias_mps2: float = 0.0
    gyro_range_rad_s: float = math.radians(2000.0)
    accel_range_mps2: float = 16.0 * GRAVITY_MPS2
    # magnetometer
    mag_rate_hz: float = 100.0
    mag_noise_gauss: float = 0.0
    mag_offset_gauss: float = 0.0  # hard-iron offset left after calibration, per axis
    # barometer
    baro_rate_hz: float = 50.0
    baro_noise_m: float = 0.0
    baro_drift_m_rts: float = 0.0  # random walk of its offset [m/sqrt(s)]
    # GPS
    gps_rate_hz: float = 10.0
    gps_latency_s: float = 0.0
    gps_horizontal_m: float = 0.0  # Gauss-Markov position error
    gps_vertical_m: float = 0.0
    gps_error_time_constant_s: float = 60.0
    gps_velocity_noise_mps: float = 0.0
    gps_hdop: float = 0.8  # dilution of precision, as the receiver reports it
    gps_vdop: float = 1.2
    gps_satellites: int = 14


_RATES = {"mag_rate_hz", "baro_rate_hz", "gps_rate_hz"}
_INTS = {"gps_satellites"}
# Other than [0, inf): the rates, and the GPS latency the estimator's EKF2_GPS_DELAY matches.
_RANGES = {**{key: (0.5, 1000.0, "Hz") for key in _RATES}, "gps_latency_s": (0.0, 0.3, "s")}


class SensorProfileError(ValueError):
    """A sensor profile that breaks the format; the message names the field."""


def shipped_profile_names() -> list[str]:
    return shipped_names("sitl", PROFILES_DIR)


def read_profile(source: str | Path) -> SensorProfile:
    """A shipped profile by name (ideal, typical, degraded), or a TOML file by path."""
    data, where = read_named_toml(source, "sitl", PROFILES_DIR, "sensor profile",
                                  SensorProfileError)
    return parse_profile(data, where, Path(str(source)).stem)


def parse_profile(data: dict[str, Any], where: str = "sensor profile",
                  default_name: str = "custom") -> SensorProfile:
    known = {f.name for f in fields(SensorProfile)}
    check_fields(data, known, where, SensorProfileError)
    values: dict[str, Any] = {}
    for key, value in data.items():
        if key in ("name", "description"):
            if not isinstance(value, str):
                raise SensorProfileError(f"{where}: {key} must be text")
            values[key] = value
            continue
        low, high, unit = _RANGES.get(key, (0.0, math.inf, ""))
        try:
            value = number(value, f"{where}: {key}", low, high, unit=unit,
                           low_open=key == "gps_error_time_constant_s", error=SensorProfileError)
        except SensorProfileError as exc:
            if key != "gps_latency_s":
                raise
            raise SensorProfileError(f"{exc} (what the estimator's EKF2_GPS_DELAY can "
                                     "match)") from None
        values[key] = int(value) if key in _INTS else value
    values.setdefault("name", default_name)
    return SensorProfile(**values)


def profile_argument(text: str) -> str:
    """argparse type of ``--sensors PROFILE``: checked now, passed on as given."""
    import argparse

    try:
        read_profile(text)
    except SensorProfileError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


class _Every:
    """A sensor at its own rate on sample time: due at 0, 1/rate, 2/rate, ..."""

    def __init__(self, rate_hz: float) -> None:
        self.period_us = round(1e6 / rate_hz)
        self.next_us = 0

    def due(self, time_us: int) -> bool:
        if time_us < self.next_us:
            return False
        self.next_us += self.period_us * max(1, (time_us - self.next_us) // self.period_us + 1)
        return True


# Noise: each sensor has its own random stream, spawned from the seed (SeedSequence), so
# that a new sensor, or another rate for one, moves no other sensor's numbers. The numbers
# each sample takes are drawn NOISE_BLOCK_SAMPLES samples at a time by numpy (a block
# holds the numbers drawing the samples one by one gives), outside the compiled read: the
# same numbers on every path (numba's own generators are not numpy's, bit for bit).
SENSOR_STREAMS = ("gyro", "accel", "mag", "baro", "gps")
NOISE_BLOCK_SAMPLES = 256
# A sample's numbers (z), in the order the compiled read takes them: gyro and
# accelerometer bias walks, their noise, the magnetometer's noise, the barometer's
# offset walk and noise.
_DRAWS = 17
_BARO_WALK, _BARO_NOISE = 15, 16
# The suite's float state, one array the compiled read takes: biases, offsets, the field
# at home, the sensor effects' offsets, ranges, the barometer's offset and drift, the
# readings held between the slower sensors' updates.
_GYRO_BIAS, _ACCEL_BIAS, _MAG_OFFSET, _FIELD_NED = 0, 3, 6, 9
_EXTRA_GYRO, _EXTRA_ACCEL, _EXTRA_MAG = 12, 15, 18
_GYRO_RANGE, _ACCEL_RANGE, _BARO_OFFSET, _BARO_DRIFT, _HOME_ALT = 21, 22, 23, 24, 25
_STATE_SIZE = 26
# Its integer state: each slower sensor's period and next due time [us].
_MAG_PERIOD, _MAG_NEXT, _BARO_PERIOD, _BARO_NEXT = 0, 1, 2, 3


@njit(cache=True)
def _due(timers: np.ndarray, period: int, at: int, time_us: int) -> bool:
    """A sensor at its own rate on sample time: due at 0, 1/rate, 2/rate, ..."""
    next_us = timers[at]
    if time_us < next_us:
        return False
    timers[at] = next_us + timers[period] * max(1, (time_us - next_us) // timers[period] + 1)
    return True


@njit(cache=True)
def _read_sensors(time_us: int, truth: np.ndarray, accel_ned: np.ndarray, noise: np.ndarray,
                  row: int, state: np.ndarray, timers: np.ndarray, reading: np.ndarray
                  ) -> None:
    """One sample's HIL_SENSOR reading (contracts/sim_samples.py READING_*) into
    ``reading``: gyro and accelerometer (specific force R^T (a - g)) each sample, the
    magnetometer (R^T B) and barometer when due, else their last; the biases and the
    barometer's offset walk by z[0:6] and z[15] (in ``state``); z[6:15] and z[16] are
    this sample's noise (z: the row ``row`` of ``noise``). ``truth``: the state the IMU
    reads (contracts/vectors.py TRUTH)."""
    z = noise[row]
    rot = rotation_from_quat(truth[TRUTH_QUAT:TRUTH_QUAT + 4])
    for i in range(3):
        state[_GYRO_BIAS + i] += z[i]
        state[_ACCEL_BIAS + i] += z[3 + i]
    fields = HIL_SENSOR_IMU
    mag_due = _due(timers, _MAG_PERIOD, _MAG_NEXT, time_us)
    for i in range(3):
        specific = rot[0, i] * accel_ned[0] + rot[1, i] * accel_ned[1] + \
            rot[2, i] * (accel_ned[2] - GRAVITY_MPS2)
        gyro = truth[TRUTH_BODY_RATE + i] + state[_GYRO_BIAS + i] + z[6 + i] + \
            state[_EXTRA_GYRO + i]
        accel = specific + state[_ACCEL_BIAS + i] + z[9 + i] + state[_EXTRA_ACCEL + i]
        gyro_range, accel_range = state[_GYRO_RANGE], state[_ACCEL_RANGE]
        reading[READING_GYRO + i] = min(max(gyro, -gyro_range), gyro_range)
        reading[READING_ACCEL + i] = min(max(accel, -accel_range), accel_range)
        if mag_due:
            field = rot[0, i] * state[_FIELD_NED] + rot[1, i] * state[_FIELD_NED + 1] + \
                rot[2, i] * state[_FIELD_NED + 2]
            reading[READING_MAG + i] = field + state[_MAG_OFFSET + i] + z[12 + i] + \
                state[_EXTRA_MAG + i]
    if mag_due:
        fields |= HIL_SENSOR_MAG
    state[_BARO_OFFSET] += z[_BARO_WALK] + state[_BARO_DRIFT]
    if _due(timers, _BARO_PERIOD, _BARO_NEXT, time_us):
        baro_alt = state[_HOME_ALT] - truth[TRUTH_POS + 2] + state[_BARO_OFFSET] + \
            z[_BARO_NOISE]
        reading[READING_PRESSURE] = pressure_hpa_compiled(baro_alt)
        reading[READING_ALT] = baro_alt
        fields |= HIL_SENSOR_BARO
    reading[READING_TEMPERATURE] = TEMPERATURE_C
    reading[READING_FIELDS] = fields


class SensorSuite:
    """The sensors of one vehicle: their biases and errors evolve sample by sample.

    Seeded: the same seed and the same true states give the same readings, bit for bit.
    """

    def __init__(self, profile: SensorProfile, sample_rate_hz: float, seed: int = 0,
                 home: Home = DEFAULT_HOME) -> None:
        self.profile = profile
        self.home = home
        self.dt = 1.0 / sample_rate_hz
        p = profile
        # One random stream per sensor (module docstring, "Noise").
        self.streams = dict(zip(SENSOR_STREAMS, map(np.random.default_rng, np.random.SeedSequence(
            [seed, 0x5E2502]).spawn(len(SENSOR_STREAMS))), strict=True))
        gyro, accel, mag, gps = (self.streams[name] for name in ("gyro", "accel", "mag", "gps"))
        state = self._state = np.zeros(_STATE_SIZE)
        state[_GYRO_BIAS:_GYRO_BIAS + 3] = gyro.normal(size=3) * p.gyro_turn_on_bias_rad_s
        state[_ACCEL_BIAS:_ACCEL_BIAS + 3] = accel.normal(size=3) * p.accel_turn_on_bias_mps2
        state[_MAG_OFFSET:_MAG_OFFSET + 3] = mag.normal(size=3) * p.mag_offset_gauss
        self.gps_error = gps.normal(size=3) * (p.gps_horizontal_m, p.gps_horizontal_m,
                                               p.gps_vertical_m)
        state[_FIELD_NED:_FIELD_NED + 3] = home.mag_field_ned_gauss()
        state[_GYRO_RANGE], state[_ACCEL_RANGE] = p.gyro_range_rad_s, p.accel_range_mps2
        state[_HOME_ALT] = home.alt_amsl_m
        self._timers = np.array([round(1e6 / p.mag_rate_hz), 0, round(1e6 / p.baro_rate_hz), 0],
                                dtype=np.int64)
        self._gps = _Every(p.gps_rate_hz)
        root_dt = math.sqrt(self.dt)
        # The standard deviation, over one sample, of each of the numbers drawn each sample.
        self._scales = np.array(
            [p.gyro_bias_walk_rad_s2_rthz * root_dt] * 3
            + [p.accel_bias_walk_mps3_rthz * root_dt] * 3
            + [p.gyro_noise_rad_s_rthz / root_dt] * 3 + [p.accel_noise_mps2_rthz / root_dt] * 3
            + [p.mag_noise_gauss] * 3 + [p.baro_drift_m_rts * root_dt, p.baro_noise_m])
        self._noise = np.empty((NOISE_BLOCK_SAMPLES, _DRAWS))  # this block's, scaled
        self._row = NOISE_BLOCK_SAMPLES  # the next sample's row in it: none left
        # This sample's reading (READING_*): the magnetometer and barometer hold their
        # last until due again.
        self.reading = np.zeros(READING_SIZE)
        self.reading[READING_PRESSURE] = SEA_LEVEL_PRESSURE_HPA
        self._effects_of: SensorEffects | None = None  # the effects ``_state`` holds
        # Fixes waiting out the receiver's latency: (release time, fix).
        self._gps_queue: collections.deque[tuple[int, GpsSample]] = collections.deque()
        self._started = False

    @property
    def gyro_bias(self) -> np.ndarray:
        return self._state[_GYRO_BIAS:_GYRO_BIAS + 3]

    @property
    def accel_bias(self) -> np.ndarray:
        return self._state[_ACCEL_BIAS:_ACCEL_BIAS + 3]

    @property
    def baro_offset_m(self) -> float:
        return float(self._state[_BARO_OFFSET])

    def read(self, time_us: int, truth: np.ndarray, accel_ned_mps2: np.ndarray,
             effects: SensorEffects) -> GpsSample | None:
        """This sample's HIL_SENSOR reading into ``reading`` (contracts/sim_samples.py
        READING_*) of the state the sensors see (``truth``: its numbers,
        contracts/vectors.py TRUTH) and, when a fix comes out of the receiver, its
        HIL_GPS; ``effects``: the sensor perturbations in force (biases, a field, an
        outage)."""
        if self._row == NOISE_BLOCK_SAMPLES:
            self._draw_block()
        row = self._row
        self._row += 1
        if effects is not self._effects_of:  # effects are replaced whole (frozen)
            self._effects_of = effects
            s = self._state
            s[_EXTRA_GYRO:_EXTRA_GYRO + 3] = effects.gyro_bias_rad_s
            s[_EXTRA_ACCEL:_EXTRA_ACCEL + 3] = effects.accel_bias_mps2
            s[_EXTRA_MAG:_EXTRA_MAG + 3] = effects.mag_field_gauss
            s[_BARO_DRIFT] = effects.baro_drift_mps * self.dt
        _read_sensors(time_us, truth, accel_ned_mps2, self._noise, row, self._state,
                      self._timers, self.reading)
        return self._gps_sample(time_us, truth, effects.gps_outage > 0)

    def _draw_block(self) -> None:
        """The next NOISE_BLOCK_SAMPLES samples' numbers, each sensor's from its own
        stream, scaled (the IMU, magnetometer and barometer draw each sample, whatever is
        fresh: their streams do not depend on those sensors' rates)."""
        n, noise, st = NOISE_BLOCK_SAMPLES, self._noise, self.streams
        gyro, accel = st["gyro"].standard_normal((n, 6)), st["accel"].standard_normal((n, 6))
        noise[:, 0:3], noise[:, 6:9] = gyro[:, 0:3], gyro[:, 3:6]  # walk, noise
        noise[:, 3:6], noise[:, 9:12] = accel[:, 0:3], accel[:, 3:6]
        noise[:, 12:15] = st["mag"].standard_normal((n, 3))
        noise[:, 15:17] = st["baro"].standard_normal((n, 2))  # walk, noise
        noise *= self._scales
        self._row = 0

    def sample(self, time_us: int, state: VehicleState, accel_ned_mps2: np.ndarray,
               effects: SensorEffects | None = None) -> tuple[SensorSample, GpsSample | None]:
        """``read`` as a sensor sample and a fix (or None)."""
        fix = self.read(time_us, state.numbers(), np.asarray(accel_ned_mps2, dtype=np.float64),
                        effects if effects is not None else NO_SENSOR_EFFECTS)
        return self.sensor_sample(time_us), fix

    def sensor_sample(self, time_us: int) -> SensorSample:
        """The last ``read`` as a sensor sample."""
        r = self.reading.tolist()
        return SensorSample(time_us, tuple(r[READING_ACCEL:READING_ACCEL + 3]),
                            tuple(r[READING_GYRO:READING_GYRO + 3]),
                            tuple(r[READING_MAG:READING_MAG + 3]), r[READING_PRESSURE],
                            r[READING_ALT], r[READING_TEMPERATURE], int(r[READING_FIELDS]))

    def _gps_sample(self, time_us: int, truth: np.ndarray,
                    outage: bool) -> GpsSample | None:
        p = self.profile
        if not self._started:
            # The receiver ran before the simulation did: a fix of the same state is out.
            self._started = True
            if p.gps_latency_s > 0:
                self._gps_queue.append((time_us, self._fix(time_us, truth)))
        if self._gps.due(time_us):
            decay = math.exp(-self._gps.period_us / 1e6 / p.gps_error_time_constant_s)
            sigma = np.array([p.gps_horizontal_m, p.gps_horizontal_m, p.gps_vertical_m])
            self.gps_error = self.gps_error * decay + self.streams["gps"].normal(size=3) * sigma * \
                math.sqrt(1.0 - decay * decay)
            fix = self._fix(time_us, truth)
            if outage:
                fix = fix._replace(fix_type=0, satellites=0, hdop=99.99, vdop=99.99)
            self._gps_queue.append((time_us + round(p.gps_latency_s * 1e6), fix))
        out = None
        while self._gps_queue and self._gps_queue[0][0] <= time_us:
            _release, fix = self._gps_queue.popleft()
            out = fix._replace(time_us=time_us)  # stamped on arrival, as PX4 stamps it
        return out

    def _fix(self, time_us: int, truth: np.ndarray) -> GpsSample:
        p = self.profile
        position = truth[TRUTH_POS:TRUTH_POS + 3] + self.gps_error
        velocity = truth[TRUTH_VEL:TRUTH_VEL + 3] + self.streams["gps"].normal(size=3) * \
            p.gps_velocity_noise_mps
        lat, lon, alt = self.home.geodetic_from_ned(*(float(v) for v in position))
        return GpsSample(time_us, lat, lon, alt, as_floats(velocity), p.gps_hdop, p.gps_vdop,
                         3, p.gps_satellites)
