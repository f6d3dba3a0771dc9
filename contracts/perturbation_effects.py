"""Perturbation effects: the quantities the processes apply, and how the contributions of
the active entries combine into each.

Effects are what a process applies (the plant's scale factors and forces, the link's
noise and delay, the autopilot's reference kick); the kinds (``contracts.perturbations``)
say what an active entry contributes to them. ``EFFECTS`` says how contributions combine
(scale factors and efficiencies multiply, vectors add, noise standard deviations add in
quadrature, link delay and loss take the largest) and the range a combined plant value
is clipped to. The plant (sitl/plant.py) and the link (sitl/sensors.py) read effects by
name; the records they read them from (``Perturbations``, ``SensorEffects``) have one
field per effect of their group, checked against this table when they are defined.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

INERTIA_SCALE_RANGE = (0.1, 10.0)
WIND_RANGE_MPS = (-50.0, 50.0)
FORCE_RANGE_N = (-1000.0, 1000.0)
TORQUE_RANGE_NM = (-100.0, 100.0)

_COMBINE: dict[str, Callable[[float, float], float]] = {
    "multiply": lambda a, b: a * b,
    "add": lambda a, b: a + b,
    "quadrature": math.hypot,
    "largest": max,
}


@dataclass(frozen=True)
class Effect:
    """One quantity perturbations change: its size (0 = scalar), its value with nothing
    active, how contributions combine, and (plant effects) the range it is kept in."""

    group: str  # "plant", "link" (what the simulator sends) or "reference" (autopilot)
    size: int
    neutral: float
    combine: str
    valid: tuple[float, float] | None = None  # combined values are clipped into it
    integer: bool = False

    @property
    def neutral_value(self) -> float | tuple[float, ...]:
        value = int(self.neutral) if self.integer else self.neutral
        return tuple([value] * self.size) if self.size else value

    def combined(self, current: Any, contribution: Any) -> Any:
        op = _COMBINE[self.combine]
        if self.size:
            return tuple(op(a, b) for a, b in zip(current, contribution, strict=True))
        return op(current, contribution)

    def clipped(self, value: Any) -> Any:
        if self.valid is None:
            return value
        low, high = self.valid
        if self.size:
            return tuple(min(max(v, low), high) for v in value)
        return min(max(value, low), high)


EFFECTS: dict[str, Effect] = {
    # the plant (sitl/plant.py applies each by name)
    "inertia_scale": Effect("plant", 0, 1.0, "multiply", INERTIA_SCALE_RANGE),
    "rotor_inertia_scale": Effect("plant", 0, 1.0, "multiply", INERTIA_SCALE_RANGE),
    "mass_scale": Effect("plant", 0, 1.0, "multiply", INERTIA_SCALE_RANGE),
    "motor_efficiency": Effect("plant", 4, 1.0, "multiply", (0.0, 1.0)),
    "wind_ned_mps": Effect("plant", 3, 0.0, "add", WIND_RANGE_MPS),
    "force_ned_n": Effect("plant", 3, 0.0, "add", FORCE_RANGE_N),
    "torque_frd_nm": Effect("plant", 3, 0.0, "add", TORQUE_RANGE_NM),
    # what the simulator sends (sitl/sensors.py)
    "noise_position_m": Effect("link", 0, 0.0, "quadrature"),
    "noise_velocity_mps": Effect("link", 0, 0.0, "quadrature"),
    "noise_angle_rad": Effect("link", 0, 0.0, "quadrature"),
    "noise_rate_rad_s": Effect("link", 0, 0.0, "quadrature"),
    "bias_position_m": Effect("link", 3, 0.0, "add"),
    "bias_velocity_mps": Effect("link", 3, 0.0, "add"),
    "bias_angle_rad": Effect("link", 3, 0.0, "add"),
    "bias_rate_rad_s": Effect("link", 3, 0.0, "add"),
    "delay_samples": Effect("link", 0, 0, "largest", integer=True),
    "loss_fraction": Effect("link", 0, 0.0, "largest"),
    # ... and what the simulator's sensors read (sitl/sensors.py SensorSuite)
    "gps_outage": Effect("link", 0, 0.0, "largest"),
    "mag_field_gauss": Effect("link", 3, 0.0, "add"),
    "gyro_bias_rad_s": Effect("link", 3, 0.0, "add"),
    "accel_bias_mps2": Effect("link", 3, 0.0, "add"),
    "baro_drift_mps": Effect("link", 0, 0.0, "add"),
    # the autopilot's reference (added to the desired roll and pitch)
    "kick_rad": Effect("reference", 2, 0.0, "add"),
}


def _group(name: str) -> dict[str, Effect]:
    return {k: e for k, e in EFFECTS.items() if e.group == name}


PLANT_EFFECTS, LINK_EFFECTS = _group("plant"), _group("link")
