"""What the commander and the telemetry need of a controller: IVFC, T1FC, SMC and PID
all fly through this interface (autopilot/control/factory.py makes them)."""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np

from contracts.airframe import Airframe


@runtime_checkable
class Controller(Protocol):
    """A cascaded attitude / position controller with its own state.

    ``telemetry`` holds one row of internals per channel (contracts/vectors.py's
    CHANNEL_INTERNALS: sliding surface, equivalent control, ...); ``theta_g`` and
    ``theta_f`` are the adaptive weights, None for a controller that has none (PID).
    """

    airframe: Airframe
    telemetry: np.ndarray

    @property
    def theta_g(self) -> np.ndarray | None: ...

    @property
    def theta_f(self) -> tuple[np.ndarray, ...] | None: ...

    def step(self, meas: np.ndarray, ref: np.ndarray, position_mode: bool,
             kick: np.ndarray | None = None, collective_thrust_n: float = math.nan,
             total_tilt: bool = False) -> np.ndarray:
        """Motor commands in [0, 1] for one control period."""
        ...

    def apply_parameters(self, parameters: dict[str, float]) -> None:
        """New gains in flight, without losing the controller's state."""
        ...

    def reset(self) -> None:
        """Back to the state it was made with (a new flight: arming)."""
        ...
