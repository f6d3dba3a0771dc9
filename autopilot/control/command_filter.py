"""Second-order command filter with rate and acceleration limits.

x'' = sat_a(w^2 (u - x) - 2 zeta w sat_r(x')) gives the desired angles and their first
two derivatives without differencing the position loop's output (Farrell et al.,
command-filtered backstepping). The limits matter: the position loop can ask for a
large tilt at once, and a plain linear filter would hand the attitude loop an angular
acceleration far beyond what the rotors can give.
"""

from __future__ import annotations

import numpy as np
from numba import njit

SUBSTEPS = 10  # semi-implicit Euler substeps per control period


@njit(cache=True)
def command_filter_step(
    state: np.ndarray,
    command: float,
    period_s: float,
    omega_rad_s: float,
    zeta: float,
    rate_max: float,
    acc_max: float,
) -> tuple[float, float, float]:
    """Advance one control period; returns (value, rate, acceleration) after it."""
    h = period_s / SUBSTEPS
    acc = 0.0
    for _ in range(SUBSTEPS):
        acc = omega_rad_s * omega_rad_s * (command - state[0]) - 2.0 * zeta * omega_rad_s * state[1]
        acc = max(-acc_max, min(acc_max, acc))
        state[1] = max(-rate_max, min(rate_max, state[1] + h * acc))
        state[0] += h * state[1]
    return state[0], state[1], acc
