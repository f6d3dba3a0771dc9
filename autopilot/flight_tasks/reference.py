"""Reference trajectories in sim time (docs/scenarios.md), with analytic derivatives.

The autopilot generates these itself so that a lockstep scenario is deterministic.
A reference is a flat array (``contracts.vectors.REFERENCE``) plus whether the position
loop is active.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from autopilot.flight_tasks.task import BaseTask, Shaped, TaskOutput
from contracts.modes import FlightMode
from contracts.vectors import (
    REF_ACC,
    REF_EULER,
    REF_EULER_ACC,
    REF_EULER_RATE,
    REF_POS,
    REF_SIZE,
    REF_VEL,
)

REFERENCE_KINDS = ("attitude-sine", "attitude-hold", "position-sine", "hover", "excitation")

# The excitation for identification: seeded multisines on the three attitude angles.
N_SINES = 4
ATTITUDE_AMPLITUDE_RAD = 0.5
YAW_AMPLITUDE_RAD = 0.4


def multisine(rng: np.random.Generator, amplitude: float) -> tuple[np.ndarray, ...]:
    """Frequencies [rad/s], phases and amplitudes of one seeded multisine."""
    freqs = rng.uniform(0.4, 3.0, N_SINES)
    phases = rng.uniform(0.0, 2.0 * np.pi, N_SINES)
    amps = amplitude * rng.dirichlet(np.ones(N_SINES))
    return freqs, phases, amps


def evaluate_multisine(sines: tuple[np.ndarray, ...], t: float) -> tuple[float, float, float]:
    """Value and two derivatives at t."""
    freqs, phases, amps = sines
    arg = freqs * t + phases
    return (float(np.sum(amps * np.sin(arg))), float(np.sum(amps * freqs * np.cos(arg))),
            float(-np.sum(amps * freqs**2 * np.sin(arg))))


def excitation_sines(rng: np.random.Generator) -> list[tuple[np.ndarray, ...]]:
    """Roll, pitch and yaw multisines, drawn in that order from ``rng``."""
    return [multisine(rng, ATTITUDE_AMPLITUDE_RAD), multisine(rng, ATTITUDE_AMPLITUDE_RAD),
            multisine(rng, YAW_AMPLITUDE_RAD)]


@functools.lru_cache(maxsize=8)
def _seeded_excitation(seed: int) -> list[tuple[np.ndarray, ...]]:
    return excitation_sines(np.random.default_rng(seed))


@dataclass(frozen=True)
class Reference:
    """A reference kind with its parameters (the paper's values by default)."""

    kind: str
    altitude_m: float = 1.0
    yaw_rad: float = 0.2
    amplitude: float = 1.0  # rad for attitude, m for position
    hold_start_s: float = 10.0
    hold_end_s: float = 12.0
    seed: float = 0.0  # excitation: the multisines' seed (a whole number)

    def __post_init__(self) -> None:
        if self.kind not in REFERENCE_KINDS:
            raise ValueError(
                f"unknown reference kind {self.kind!r}; known: {', '.join(REFERENCE_KINDS)}"
            )
        for name in ("altitude_m", "yaw_rad", "amplitude", "hold_start_s", "hold_end_s",
                     "seed"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"reference {name} must be finite")
        if self.seed != int(self.seed) or self.seed < 0:
            raise ValueError(f"reference seed must be a whole number >= 0, got {self.seed!r}")

    @property
    def position_mode(self) -> bool:
        """True when roll and pitch come from the position loop."""
        return self.kind in ("position-sine", "hover")

    def at(self, t_s: float) -> np.ndarray:
        """The reference vector at sim time ``t_s``."""
        ref = np.zeros(REF_SIZE)
        ref[REF_POS + 2] = -self.altitude_m
        ref[REF_EULER + 2] = self.yaw_rad
        a = self.amplitude
        s, c = math.sin(t_s), math.cos(t_s)
        if self.kind == "position-sine":
            # x_d = a sin t, y_d = a sin(t + pi) = -a sin t.
            ref[REF_POS], ref[REF_POS + 1] = a * s, -a * s
            ref[REF_VEL], ref[REF_VEL + 1] = a * c, -a * c
            ref[REF_ACC], ref[REF_ACC + 1] = -a * s, a * s
        elif self.kind == "excitation":
            for axis, sines in enumerate(_seeded_excitation(int(self.seed))):
                (ref[REF_EULER + axis], ref[REF_EULER_RATE + axis],
                 ref[REF_EULER_ACC + axis]) = evaluate_multisine(sines, t_s)
        elif self.kind in ("attitude-sine", "attitude-hold"):
            holding = self.kind == "attitude-hold" and self.hold_start_s <= t_s < self.hold_end_s
            if not holding:
                # theta_d = a sin t, phi_d = a sin(t + pi) = -a sin t.
                ref[REF_EULER], ref[REF_EULER + 1] = -a * s, a * s
                ref[REF_EULER_RATE], ref[REF_EULER_RATE + 1] = -a * c, a * c
                ref[REF_EULER_ACC], ref[REF_EULER_ACC + 1] = a * s, -a * s
        return ref


class ReferenceTask(BaseTask):
    """The paper's reference (REFERENCE mode), in sim time from when it began; not shaped
    (the paper's controller is tuned on it as it is)."""

    start_s = 0.0

    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.begin()

    def begin(self) -> None:
        self.start_s = self.state.sim_t_s

    def update(self) -> TaskOutput:
        s, reference = self.state, self.env.reference
        s.shaped = Shaped.NONE
        return TaskOutput(reference.at(s.sim_t_s - self.start_s), reference.position_mode,
                          math.nan)
