"""Gaussian membership functions and the check that an interval of two is one.

The premises of every fuzzy model: the flight controller evaluates them, the offline
identification fits them (autopilot/identification/gaussian_fit.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Gaussian:
    """mu(x) = h exp(-(x - c)^2 / (2 s^2)); h height, c centre, s sigma (input's units)."""

    h: float
    c: float
    s: float

    def __post_init__(self) -> None:
        for name in ("h", "c", "s"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"Gaussian {name} must be finite, got {value}")
            object.__setattr__(self, name, float(value))
        if self.s <= 0.0:
            raise ValueError(f"Gaussian sigma must be > 0, got {self.s}")
        if self.h < 0.0:
            raise ValueError(f"Gaussian height must be >= 0, got {self.h}")

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        """Membership degree at x."""
        xa = np.asarray(x, dtype=float)
        return self.h * np.exp(-((xa - self.c) ** 2) / (2.0 * self.s**2))

    def as_array(self) -> np.ndarray:
        """[h, c, s], the layout of the (c, n, 3) MF arrays."""
        return np.array([self.h, self.c, self.s])


def max_log_ratio(lower: Gaussian, upper: Gaussian) -> float:
    """sup over real x of ln(lower(x) / upper(x)), in closed form.

    ln(lower/upper) = ln(h_l/h_u) - (x-c_l)^2/(2 s_l^2) + (x-c_u)^2/(2 s_u^2) is a quadratic
    in x. s_l > s_u: convex, unbounded (+inf). s_l = s_u: linear, +inf unless c_l = c_u,
    then the constant ln(h_l/h_u). s_l < s_u: concave, with maximum
    ln(h_l/h_u) + (c_l - c_u)^2 / (2 (s_u^2 - s_l^2)).
    """
    if upper.h <= 0.0:
        return math.inf if lower.h > 0.0 else -math.inf
    if lower.h <= 0.0:
        return -math.inf
    log_h = math.log(lower.h) - math.log(upper.h)
    if lower.s > upper.s:
        return math.inf
    if lower.s == upper.s:
        return log_h if lower.c == upper.c else math.inf
    return log_h + (lower.c - upper.c) ** 2 / (2.0 * (upper.s**2 - lower.s**2))


def interval_holds(lower: Gaussian, upper: Gaussian) -> bool:
    """True when 0 <= lower(x) <= upper(x) <= 1 for every real x (analytic check)."""
    if not (0.0 < upper.h <= 1.0 and lower.h >= 0.0):
        return False
    return max_log_ratio(lower, upper) <= 0.0
