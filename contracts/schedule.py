"""Perturbation schedules: what the ground side may change in the plant and the
reference, and when (sim time). Shared by the scenario definitions, the simulator (plant
changes) and the autopilot (reference kicks); serialised as JSON between processes.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Perturbations:
    """Changes to the plant that tests and the ground station apply (SPEC section 7)."""

    inertia_scale: float = 1.0
    rotor_inertia_scale: float = 1.0
    mass_scale: float = 1.0
    motor_efficiency: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_ned_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_frd_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("inertia_scale", "rotor_inertia_scale", "mass_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.1 <= value <= 10.0):
                raise ValueError(f"perturbation {name} must be in [0.1, 10], got {value!r}")
        _check_vector("motor_efficiency", self.motor_efficiency, 4, 0.0, 1.0)
        _check_vector("wind_ned_mps", self.wind_ned_mps, 3, -50.0, 50.0)
        _check_vector("force_ned_n", self.force_ned_n, 3, -1000.0, 1000.0)
        _check_vector("torque_frd_nm", self.torque_frd_nm, 3, -100.0, 100.0)


def _check_vector(name: str, value: tuple, size: int, low: float, high: float) -> None:
    if len(value) != size:
        raise ValueError(f"perturbation {name} needs {size} values, got {len(value)}")
    for v in value:
        if not (math.isfinite(v) and low <= v <= high):
            raise ValueError(f"perturbation {name} values must be in [{low}, {high}], got {v!r}")



@dataclass(frozen=True)
class Window:
    """A perturbation active for start_s <= t < end_s (plant change and/or reference kick)."""

    start_s: float
    end_s: float
    plant: Perturbations | None = None
    kick_rad: tuple[float, float] = (0.0, 0.0)  # added to (phi_d, theta_d)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.start_s) and math.isfinite(self.end_s)
                and 0.0 <= self.start_s <= self.end_s):
            raise ValueError(f"window needs finite 0 <= start_s <= end_s, got "
                             f"{self.start_s!r}, {self.end_s!r}")
        _check_vector("kick_rad", self.kick_rad, 2, -1.0, 1.0)


def plant_perturbations_at(windows: tuple[Window, ...], t_s: float) -> Perturbations:
    """The plant change in force at sim time t (the last window listed wins)."""
    active = [w.plant for w in windows if w.plant and w.start_s <= t_s < w.end_s]
    return active[-1] if active else Perturbations()


def kick_at(windows: tuple[Window, ...], t_s: float) -> tuple[float, float]:
    """Sum of the reference kicks (phi_d, theta_d) in force at sim time t."""
    phi = sum(w.kick_rad[0] for w in windows if w.start_s <= t_s < w.end_s)
    theta = sum(w.kick_rad[1] for w in windows if w.start_s <= t_s < w.end_s)
    return phi, theta


_PERTURBATION_FIELDS = {f.name for f in fields(Perturbations)}


def windows_to_json(windows: tuple[Window, ...]) -> str:
    return json.dumps({"format": "ivfm-schedule", "version": 1,
                       "windows": [asdict(w) for w in windows]}, indent=1)


def windows_from_json(text: str) -> tuple[Window, ...]:
    """Parse and validate a schedule; raises ValueError naming the bad field."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"schedule is not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != "ivfm-schedule":
        raise ValueError("schedule lacks format 'ivfm-schedule'")
    out = []
    for i, item in enumerate(data.get("windows", [])):
        try:
            out.append(_window(item))
        except (TypeError, ValueError, KeyError) as exc:
            raise ValueError(f"schedule window {i}: {exc}") from None
    return tuple(out)


def _window(item: dict[str, Any]) -> Window:
    plant = item.get("plant")
    if plant is not None:
        unknown = set(plant) - _PERTURBATION_FIELDS
        if unknown:
            raise ValueError(f"unknown perturbation(s) {', '.join(sorted(unknown))}")
        plant = Perturbations(**{k: tuple(v) if isinstance(v, list) else float(v)
                                 for k, v in plant.items()})
    return Window(float(item["start_s"]), float(item["end_s"]), plant,
                  tuple(float(v) for v in item.get("kick_rad", (0.0, 0.0))))


def load_schedule(path: Path) -> tuple[Window, ...]:
    return windows_from_json(Path(path).read_text())
