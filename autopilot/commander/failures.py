"""Failures injected by ground tools (MAV_CMD_INJECT_FAILURE), as PX4 does it: only when
SYS_FAILURE_EN is 1, and inside the flight stack. A failed sensor's data is dropped as it
comes in; a failed motor's output is held at zero. Pure logic: the process applies it
to the readings and the motor commands (docs/mavlink.md).

Supported so far: OFF and OK of the GPS, the barometer, the magnetometer and the motors
(instance 0: every motor; 1-4: that one). Every other unit or type is refused with
MAV_RESULT_UNSUPPORTED and the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.refusal import RefusedError

UNITS = {0: "gyro", 1: "accelerometer", 2: "magnetometer", 3: "barometer", 4: "GPS",
         5: "optical flow", 6: "VIO", 7: "distance sensor", 8: "airspeed", 100: "battery",
         101: "motor", 102: "servo", 103: "avoidance", 104: "RC signal",
         105: "MAVLink signal"}
TYPES = {0: "ok", 1: "off", 2: "stuck", 3: "garbage", 4: "wrong", 5: "slow", 6: "delayed",
         7: "intermittent"}
MAG, BARO, GPS, MOTOR = 2, 3, 4, 101
SENSORS = {GPS: "gps_off", BARO: "baro_off", MAG: "mag_off"}  # one of each on this vehicle
OK, OFF = 0, 1
MOTORS = 4


class UnsupportedError(RefusedError):
    """A failure this vehicle cannot inject: MAV_RESULT_UNSUPPORTED."""


@dataclass
class InjectedFailures:
    """What is failed now."""

    gps_off: bool = False
    baro_off: bool = False
    mag_off: bool = False
    motors_off: frozenset[int] = frozenset()  # 0-based

    @property
    def any(self) -> bool:
        return self.gps_off or self.baro_off or self.mag_off or bool(self.motors_off)

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
        if unit_i not in (*SENSORS, MOTOR) or kind_i not in (OK, OFF):
            raise UnsupportedError(f"failure {unit_name} {kind_name} is not supported "
                                   "(GPS, barometer, magnetometer, motor: ok, off)")
        if unit_i in SENSORS:
            if instance_i not in (0, 1):
                raise UnsupportedError(f"there is one {unit_name}, not instance {instance_i}")
            setattr(self, SENSORS[unit_i], kind_i == OFF)
            return f"failure injected: {unit_name} {kind_name}"
        if not 0 <= instance_i <= MOTORS:
            raise UnsupportedError(f"motor instance {instance_i} (0 all, 1-{MOTORS})")
        chosen = frozenset(range(MOTORS)) if instance_i == 0 else frozenset({instance_i - 1})
        self.motors_off = self.motors_off | chosen if kind_i == OFF else \
            self.motors_off - chosen
        which = "every motor" if instance_i == 0 else f"motor {instance_i}"
        return f"failure injected: {which} {kind_name}"

    def motor_outputs(self, commands: np.ndarray) -> np.ndarray:
        """The commands as the failed motors give them (``commands`` unchanged)."""
        if not self.motors_off:
            return commands
        out = np.array(commands, dtype=float)
        out[sorted(self.motors_off)] = 0.0
        return out
