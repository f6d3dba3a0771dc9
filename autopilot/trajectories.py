"""Reference trajectories in sim time (docs/scenarios.md), with analytic derivatives: the
paper's references and the multisine excitation for identification.

The autopilot generates these itself so that a lockstep scenario is deterministic.
A reference is a flat array (``contracts.vectors.REFERENCE``) plus whether the position
loop is active. Apart from the flight tasks (REFERENCE mode flies one through
autopilot/flight_tasks/reference.py), so that ground tools and identification can design
and evaluate them without the vehicle's logic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from contracts.airframe_file import ENVELOPE_LIMITS, PAPER_ENVELOPE, Envelope
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
# A Reference's fields besides kind and altitude_m (the autopilot's --reference-option).
REFERENCE_OPTIONS = ("yaw_rad", "amplitude", "hold_start_s", "hold_end_s", "seed",
                     "rate_rad_s", "yaw_rate_rad_s")
# Those that hold the excitation's envelope, in the order of Envelope's fields.
ENVELOPE_OPTIONS = ("amplitude", "rate_rad_s", "yaw_rate_rad_s")

# The excitation for identification: multisines on the three attitude angles, designed so
# that roll and pitch get matched spectra and the flight covers the envelope the model
# will fly (docs/mathematics.md, "The excitation").
EXCITATION_RECORD_S = 40.0  # the paper's record, 4000 x 0.01 s: half identifies, half validates
# Harmonics of twice the record: over the record their odd ones are orthogonal, and its
# halves differ (with the record as the period, odd harmonics make one half the other's
# mirror image, and validation would be on points the model never saw).
EXCITATION_BASE_PERIOD_S = 2.0 * EXCITATION_RECORD_S
EXCITATION_BAND_RAD_S = (0.4, 3.0)
EXCITATION_MARGIN = 1.1  # the reference aims this far past the envelope: tracking is not exact
PHASE_CANDIDATES = 32  # phase sets drawn; the one that overshoots the envelope least is kept
COVERAGE_TAIL = 0.005  # the envelope counts as reached when 0.5 % of the samples lie beyond it


Multisine = tuple[np.ndarray, np.ndarray, np.ndarray]  # frequencies [rad/s], phases, amplitudes


def evaluate_multisine(sines: Multisine, t: float) -> tuple[float, float, float]:
    """Value and two derivatives at t."""
    freqs, phases, amps = sines
    arg = freqs * t + phases
    return (float(np.sum(amps * np.sin(arg))), float(np.sum(amps * freqs * np.cos(arg))),
            float(-np.sum(amps * freqs**2 * np.sin(arg))))


def tail_reach(signal: np.ndarray) -> float:
    """How far the signal reaches on its shorter side, at the coverage tail."""
    low, high = np.quantile(signal, [COVERAGE_TAIL, 1.0 - COVERAGE_TAIL])
    return float(min(-low, high))


def abs_reach(signal: np.ndarray) -> float:
    """How far |signal| reaches, at the coverage tail: an attitude counts either way."""
    return float(np.quantile(np.abs(signal), 1.0 - 2.0 * COVERAGE_TAIL))


def _without_drift(phases: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """The phases with the two lowest harmonics' chosen so that sum w_k exp(i phi_k) = 0
    (None if no choice does): the horizontal velocity, the integral of the tilt (g tan of
    it), then starts with no constant part and the vehicle does not drift away. Roll's
    integral has the real part as constant, pitch's (the quadrature) the imaginary."""
    rest = np.sum(weights[2:] * np.exp(1j * phases[2:]))
    target, (c0, c1) = -rest, weights[:2]
    d = abs(target)
    if not abs(c0 - c1) <= d <= c0 + c1 or d == 0.0:
        return None
    alpha = math.acos(np.clip((c0 * c0 + d * d - c1 * c1) / (2.0 * c0 * d), -1.0, 1.0))
    out = phases.copy()
    out[0] = np.angle(target) + alpha
    out[1] = np.angle(target - c0 * np.exp(1j * out[0]))
    return out


def excitation_sines(rng: np.random.Generator, envelope: Envelope = PAPER_ENVELOPE
                     ) -> list[Multisine]:
    """Roll, pitch and yaw multisines (phases drawn from ``rng``).

    Roll and pitch share the odd harmonics of the base period inside the band, with the
    same amplitudes and phases; pitch is roll's quadrature (each sine a cosine), so the two
    have the same spectrum and are uncorrelated over the record. Every harmonic has the
    same rate amplitude. The scale makes the half of the record that identifies reach past
    the envelope (rates on both sides, attitudes either way); of PHASE_CANDIDATES seeded
    phase sets, the one whose peaks then overshoot the envelope least is kept. Yaw gets
    the even harmonics, scaled to its rate."""
    w0 = 2.0 * math.pi / EXCITATION_BASE_PERIOD_S
    harmonics = np.arange(math.ceil(EXCITATION_BAND_RAD_S[0] / w0),
                          math.floor(EXCITATION_BAND_RAD_S[1] / w0) + 1)
    t = np.arange(0.0, EXCITATION_RECORD_S, 0.01)
    half = len(t) // 2

    freqs = harmonics[harmonics % 2 == 1] * w0
    unit = 1.0 / freqs  # angle amplitudes for a rate amplitude of 1
    best = None
    for _ in range(PHASE_CANDIDATES):  # 7 draws in 10 can be made drift-free
        phases = _without_drift(rng.uniform(0.0, 2.0 * np.pi, len(freqs)), unit / freqs)
        if phases is None:
            continue
        sin, cos = np.sin(np.outer(t, freqs) + phases), np.cos(np.outer(t, freqs) + phases)
        attitudes = (sin @ unit, cos @ unit)  # roll, pitch
        rates = (cos @ (unit * freqs), -sin @ (unit * freqs))
        scale = EXCITATION_MARGIN * max(
            envelope.attitude_rad / min(abs_reach(x[:half]) for x in attitudes),
            envelope.rate_rad_s / min(tail_reach(x[:half]) for x in rates))
        overshoot = scale * max(max(np.max(np.abs(x)) for x in attitudes) / envelope.attitude_rad,
                                max(np.max(np.abs(x)) for x in rates) / envelope.rate_rad_s)
        if best is None or overshoot < best[0]:
            best = (overshoot, phases, scale)
    if best is None:  # all of them: a chance of 0.3^32
        raise RuntimeError("no phase set of the excitation could be made drift-free")
    _, phases, scale = best

    yaw_freqs = harmonics[harmonics % 2 == 0] * w0
    yaw_phases = rng.uniform(0.0, 2.0 * np.pi, len(yaw_freqs))
    yaw_rate = np.cos(np.outer(t[:half], yaw_freqs) + yaw_phases).sum(axis=1)
    yaw_scale = EXCITATION_MARGIN * envelope.yaw_rate_rad_s / tail_reach(yaw_rate)
    return [(freqs, phases, scale * unit), (freqs, phases + 0.5 * np.pi, scale * unit),
            (yaw_freqs, yaw_phases, yaw_scale / yaw_freqs)]


@functools.lru_cache(maxsize=8)
def _seeded_excitation(seed: int, envelope: Envelope) -> list[Multisine]:
    return excitation_sines(np.random.default_rng(seed), envelope)


@dataclass(frozen=True)
class Reference:
    """A reference kind with its parameters (the paper's values by default)."""

    kind: str
    altitude_m: float = 1.0
    yaw_rad: float = 0.2
    amplitude: float = 1.0  # rad for attitude, m for position; excitation: attitude envelope
    hold_start_s: float = 10.0
    hold_end_s: float = 12.0
    seed: float = 0.0  # excitation: the multisines' seed (a whole number)
    rate_rad_s: float = 1.0  # excitation: roll and pitch rate envelope
    yaw_rate_rad_s: float | None = None  # excitation: yaw rate envelope (None: half the rate)

    def __post_init__(self) -> None:
        if self.yaw_rate_rad_s is None:
            object.__setattr__(self, "yaw_rate_rad_s", 0.5 * self.rate_rad_s)
        if self.kind not in REFERENCE_KINDS:
            raise ValueError(
                f"unknown reference kind {self.kind!r}; known: {', '.join(REFERENCE_KINDS)}"
            )
        for name in ("altitude_m", *REFERENCE_OPTIONS):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"reference {name} must be finite")
        if self.seed != int(self.seed) or self.seed < 0:
            raise ValueError(f"reference seed must be a whole number >= 0, got {self.seed!r}")
        if self.kind == "excitation":
            for what, value, limit in (
                    ("amplitude (the attitude envelope)", self.amplitude, "attitude_rad"),
                    ("rate_rad_s", self.rate_rad_s, "rate_rad_s"),
                    ("yaw_rate_rad_s", self.yaw_rate_rad_s, "yaw_rate_rad_s")):
                top = ENVELOPE_LIMITS[limit]
                if not 0.0 < value <= top:
                    raise ValueError(f"excitation {what} must be in (0, {top}], got {value!r}")
            _seeded_excitation(int(self.seed), self.envelope)  # designed now (60 ms), not
                                                                # in the control loop

    @property
    def envelope(self) -> Envelope:
        """The excitation's envelope: attitude ``amplitude``, rates ``rate_rad_s`` and
        ``yaw_rate_rad_s``."""
        return Envelope(self.amplitude, self.rate_rad_s, self.yaw_rate_rad_s)

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
            for axis, sines in enumerate(_seeded_excitation(int(self.seed), self.envelope)):
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
