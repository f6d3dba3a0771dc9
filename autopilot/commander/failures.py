"""Failures injected by ground tools (MAV_CMD_INJECT_FAILURE), as PX4 does it: only when
SYS_FAILURE_EN is 1, and inside the flight stack, on each sensor's data as it comes in
and on the motors' outputs. Pure logic: the process passes every reading through
``sensor`` and the motor commands through ``motor_outputs`` (docs/mavlink.md).

Sensors (gyro, accelerometer, magnetometer, barometer, GPS; one of each), with PX4's
failure types: OFF (no data), STUCK (the value at the injection, for ever), GARBAGE
(random values, seeded), WRONG (plausible but wrong: a fixed error, below), SLOW (one
reading in ten), INTERMITTENT (each reading dropped with probability one half, seeded);
OK clears. Motors: OFF (output 0) and OK. DELAYED and every other unit are refused
with MAV_RESULT_UNSUPPORTED and the reason.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from autopilot.refusal import RefusedError

UNITS = {0: "gyro", 1: "accelerometer", 2: "magnetometer", 3: "barometer", 4: "GPS",
         5: "optical flow", 6: "VIO", 7: "distance sensor", 8: "airspeed", 100: "battery",
         101: "motor", 102: "servo", 103: "avoidance", 104: "RC signal",
         105: "MAVLink signal"}
TYPES = {0: "ok", 1: "off", 2: "stuck", 3: "garbage", 4: "wrong", 5: "slow", 6: "delayed",
         7: "intermittent"}
GYRO, ACCEL, MAG, BARO, GPS, MOTOR = 0, 1, 2, 3, 4, 101
SENSOR_UNITS = (GYRO, ACCEL, MAG, BARO, GPS)
OK, OFF, STUCK, GARBAGE, WRONG, SLOW, INTERMITTENT = 0, 1, 2, 3, 4, 5, 7
SENSOR_TYPES = (OK, OFF, STUCK, GARBAGE, WRONG, SLOW, INTERMITTENT)
MOTORS = 4
SLOW_EVERY = 10  # SLOW: one reading in this many gets through
FAILURE_SEED = 20_260_1  # GARBAGE and INTERMITTENT draw from this, so runs repeat

# WRONG: what each sensor gets wrong (plausible values, not noise).
WRONG_GYRO_RAD_S = np.array([0.2, 0.0, 0.0])  # a roll-rate bias
WRONG_ACCEL_MPS2 = np.array([2.0, 0.0, 0.0])  # a forward specific-force bias
WRONG_MAG_YAW_RAD = math.radians(45.0)  # the field turned: the heading 45 deg off
WRONG_BARO_M = 20.0  # the altitude 20 m high
WRONG_GPS_NORTH_M = 100.0  # the position 100 m north (a spoofed fix)
# GARBAGE: uniform noise of these half-widths around the true value.
GARBAGE_SPAN = {GYRO: 10.0, ACCEL: 50.0, MAG: 2.0, BARO: 1000.0, GPS: 5000.0}


class UnsupportedError(RefusedError):
    """A failure this vehicle cannot inject: MAV_RESULT_UNSUPPORTED."""


@dataclass
class InjectedFailures:
    """What is failed now, and the state the failures keep (stuck values, counters)."""

    sensors: dict[int, int] = field(default_factory=dict)  # unit -> failure type
    motors_off: frozenset[int] = frozenset()  # 0-based
    _stuck: dict[int, Any] = field(default_factory=dict)
    _count: dict[int, int] = field(default_factory=dict)
    _rng: np.random.Generator = field(
        default_factory=lambda: np.random.default_rng(FAILURE_SEED))

    @property
    def any(self) -> bool:
        return bool(self.sensors) or bool(self.motors_off)

    def failed(self, unit: int) -> int:
        """The failure type of a sensor unit now (OK when it works)."""
        return self.sensors.get(unit, OK)

    def inject(self, enabled: bool, unit: float, kind: float, instance: float) -> str:
        """Apply one request (the command's param1-3); the text to announce. Raises
        RefusedError (DENIED) when failure injection is off, UnsupportedError for a unit,
        type or instance this vehicle does not have."""
        if not enabled:
            raise RefusedError("failure injection disabled: set SYS_FAILURE_EN to 1")
        for value, name in ((unit, "unit"), (kind, "type"), (instance, "instance")):
            if not (math.isfinite(value) and value == int(value)):
                raise UnsupportedError(f"failure {name} {value!r} is not a whole number")
        unit_i, kind_i, instance_i = int(unit), int(kind), int(instance)
        unit_name = UNITS.get(unit_i, f"unit {unit_i}")
        kind_name = TYPES.get(kind_i, f"type {kind_i}")
        if unit_i in SENSOR_UNITS and kind_i in SENSOR_TYPES:
            if instance_i not in (0, 1):
                raise UnsupportedError(f"there is one {unit_name}, not instance {instance_i}")
            self.sensors.pop(unit_i, None)
            self._stuck.pop(unit_i, None)
            self._count.pop(unit_i, None)
            if kind_i != OK:
                self.sensors[unit_i] = kind_i
            return f"failure injected: {unit_name} {kind_name}"
        if unit_i == MOTOR and kind_i in (OK, OFF):
            if not 0 <= instance_i <= MOTORS:
                raise UnsupportedError(f"motor instance {instance_i} (0 all, 1-{MOTORS})")
            chosen = frozenset(range(MOTORS)) if instance_i == 0 else \
                frozenset({instance_i - 1})
            self.motors_off = self.motors_off | chosen if kind_i == OFF else \
                self.motors_off - chosen
            which = "every motor" if instance_i == 0 else f"motor {instance_i}"
            return f"failure injected: {which} {kind_name}"
        raise UnsupportedError(f"failure {unit_name} {kind_name} is not supported (gyro, "
                               "accelerometer, magnetometer, barometer, GPS: ok, off, stuck, "
                               "garbage, wrong, slow, intermittent; motor: ok, off)")

    def sensor(self, unit: int, value: Any) -> Any:
        """A reading as the failed sensor gives it: the value, a failed one, or None (no
        data). ``value`` is a 3-vector (gyro, accelerometer, magnetometer FRD), the
        barometer's altitude [m] or a GPS fix; None (a reading that is not fresh) stays
        None."""
        kind = self.sensors.get(unit, OK)
        if kind == OK or value is None:
            return value
        if kind == OFF:
            return None
        if kind == STUCK:
            return self._stuck.setdefault(unit, value)
        if kind == SLOW:
            n = self._count[unit] = self._count.get(unit, -1) + 1
            return value if n % SLOW_EVERY == 0 else None
        if kind == INTERMITTENT:
            return value if self._rng.random() >= 0.5 else None
        if kind == GARBAGE:
            return _garbage(unit, value, self._rng)
        return _wrong(unit, value)  # WRONG

    def motor_outputs(self, commands: np.ndarray) -> np.ndarray:
        """The commands as the failed motors give them (``commands`` unchanged)."""
        if not self.motors_off:
            return commands
        out = np.array(commands, dtype=float)
        out[sorted(self.motors_off)] = 0.0
        return out


def _garbage(unit: int, value: Any, rng: np.random.Generator) -> Any:
    span = GARBAGE_SPAN[unit]
    if unit == BARO:
        return float(value) + rng.uniform(-span, span)
    if unit == GPS:
        return dataclasses.replace(
            value, position_ned_m=value.position_ned_m + rng.uniform(-span, span, 3),
            velocity_ned_mps=rng.uniform(-50.0, 50.0, 3))
    return np.asarray(value, dtype=float) + rng.uniform(-span, span, 3)


def _wrong(unit: int, value: Any) -> Any:
    if unit == GYRO:
        return np.asarray(value, dtype=float) + WRONG_GYRO_RAD_S
    if unit == ACCEL:
        return np.asarray(value, dtype=float) + WRONG_ACCEL_MPS2
    if unit == MAG:  # the field turned about the body's z axis
        c, s = math.cos(WRONG_MAG_YAW_RAD), math.sin(WRONG_MAG_YAW_RAD)
        x, y, z = (float(v) for v in value)
        return np.array([c * x - s * y, s * x + c * y, z])
    if unit == BARO:
        return float(value) + WRONG_BARO_M
    return dataclasses.replace(
        value, position_ned_m=value.position_ned_m + np.array([WRONG_GPS_NORTH_M, 0, 0]))
