"""Gaussian membership functions: fitting to envelope points and interval repair.

docs/mathematics.md, identification step 3. The upper and lower envelopes found by EDA
are fitted with
mu(x) = h exp(-(x - c)^2 / (2 s^2)). An interval type-2 set needs
0 <= lower(x) <= upper(x) <= 1 for every real x, not only where there was data (the
controller evaluates the model wherever the vehicle flies), so the check and the repair
below are analytic rather than sampled.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.optimize import OptimizeWarning, curve_fit

from autopilot.models.membership import Gaussian, max_log_ratio

SIGMA_FLOOR_FRACTION = 0.01  # smallest sigma, as a fraction of the data's x range
SIGMA_CEIL_FRACTION = 10.0  # largest sigma (flat over the data), as a fraction of the range
CENTER_MARGIN_FRACTION = 2.0  # centres may sit this many ranges outside the data
HEIGHT_MIN = 1e-9  # h > 0 keeps ln h finite in the log-domain firing
REPAIR_MARGIN = 1.0 - 1e-12  # keeps a repaired pair strictly inside, despite round-off
_LOG_TINY = math.log(np.finfo(float).tiny)  # below this a scaled height underflows


def _gaussian(x: np.ndarray, h: float, c: float, s: float) -> np.ndarray:
    return h * np.exp(-((x - c) ** 2) / (2.0 * s * s))


def fit_gaussian(x: np.ndarray, mu: np.ndarray) -> Gaussian:
    """Least-squares Gaussian through the points (x, mu), 0 < h <= 1, s > 0.

    The initial guess is the membership-weighted mean and spread of x, which is already
    close for a bell-shaped cloud. Bounds keep the fit meaningful on awkward clouds:
    sigma >= 1 % of the x range (no spike on a single point), sigma <= 10 ranges (an
    input the cluster does not depend on gives a flat MF, not an overflow), centre
    within 2 ranges of the data (an edge cluster's MF may peak outside it). If the
    optimiser fails, the moment-based guess is returned: a usable bell, never NaN.
    """
    xa = np.asarray(x, dtype=float).ravel()
    ma = np.asarray(mu, dtype=float).ravel()
    if xa.shape != ma.shape:
        raise ValueError(f"x and mu differ in length: {xa.shape[0]} vs {ma.shape[0]}")
    if xa.shape[0] < 3:
        raise ValueError(f"need at least 3 points to fit a Gaussian, got {xa.shape[0]}")
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ma))):
        raise ValueError("x or mu contains NaN or infinite values")
    x_range = float(np.ptp(xa))
    if x_range <= 0.0:
        raise ValueError("all x are equal: a Gaussian's centre and width are undefined")

    lo_b = np.array(
        [HEIGHT_MIN, xa.min() - CENTER_MARGIN_FRACTION * x_range, SIGMA_FLOOR_FRACTION * x_range]
    )
    hi_b = np.array(
        [1.0, xa.max() + CENTER_MARGIN_FRACTION * x_range, SIGMA_CEIL_FRACTION * x_range]
    )

    w = np.clip(ma, 0.0, None)
    if w.sum() > 0.0:
        c0 = float(np.sum(w * xa) / w.sum())
        s0 = float(np.sqrt(np.sum(w * (xa - c0) ** 2) / w.sum()))
    else:
        c0, s0 = float(np.mean(xa)), 0.25 * x_range
    p0 = np.clip([float(ma.max()), c0, s0], lo_b, hi_b)
    # strictly inside the bounds, as the trust-region solver requires
    p0 = np.minimum(np.maximum(p0, lo_b + 1e-12 * (hi_b - lo_b)), hi_b - 1e-12 * (hi_b - lo_b))

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizeWarning)
            popt, _ = curve_fit(
                _gaussian, xa, ma, p0=p0, bounds=(lo_b, hi_b), method="trf", maxfev=5000
            )
    except (RuntimeError, ValueError):
        popt = p0
    if not np.all(np.isfinite(popt)):
        popt = p0
    return Gaussian(h=float(popt[0]), c=float(popt[1]), s=float(popt[2]))


def repair_interval(lower: Gaussian, upper: Gaussian) -> tuple[Gaussian, Gaussian]:
    """Smallest change to the lower MF that puts it under the upper MF everywhere.

    Steps: upper height capped at 1; a lower sigma wider than the upper one is narrowed
    to it (otherwise the lower tails always cross); equal sigmas need equal centres;
    then, if the closed-form maximum of ln(lower/upper) is positive, the lower height is
    scaled down by exp(-max) (times 1 - 1e-12 against round-off). If that scaling would
    underflow (the lower bell sits so far out in the upper's tail that the factor is
    below the smallest float), the lower centre is also moved onto the upper centre,
    which bounds the factor by h_u / h_l; this keeps h_l > 0 and ln h_l finite.
    """
    if upper.h <= 0.0:
        raise ValueError("upper MF height must be > 0")
    up = Gaussian(h=min(upper.h, 1.0), c=upper.c, s=upper.s)
    lo_s = min(lower.s, up.s)
    lo_c = up.c if lo_s == up.s else lower.c
    lo = Gaussian(h=lower.h, c=lo_c, s=lo_s)
    excess = max_log_ratio(lo, up)
    if excess > 0.0:
        if math.log(lo.h) - excess <= _LOG_TINY + 1.0:
            lo = Gaussian(h=lo.h, c=up.c, s=lo.s)
            excess = max_log_ratio(lo, up)
        if excess > 0.0:
            lo = Gaussian(h=lo.h * math.exp(-excess) * REPAIR_MARGIN, c=lo.c, s=lo.s)
    return lo, up
