"""Envelope detection algorithm (EDA), docs/mathematics.md, identification step 2.

The projection of one GK cluster's memberships onto one input is a cloud of points
(x_kj, mu_ik), not a curve: the other inputs move the membership up and down. EDA turns
the cloud into two point sets, one along its top (upper MF) and one along its bottom
(lower MF), from the sign of the slope between consecutive points:

* one pass: sort the points by x; a point whose slope from its predecessor is positive
  goes to the upper set, every other point (slope <= 0) to the lower set. The first
  point has no predecessor and no slope, so it goes to neither set;
* refinement: one pass over the upper set, keeping its upper part, and one pass over
  the lower set, keeping its lower part, so the two envelopes separate.

``passes`` counts the passes along each branch, the paper's j_max: passes = 1 is the
plain split, passes = 2 (the default, "applying EDA two times") adds one refinement of
each set. A pass that would leave fewer than 3 points (too few for a Gaussian fit) is
not taken: that set keeps the previous pass's points (for the first pass, the whole
cloud, e.g. the upper set of a cloud that only falls).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_ENVELOPE_POINTS = 3


@dataclass(frozen=True, eq=False)
class Envelopes:
    """Upper and lower envelope points, each sorted by x."""

    upper_x: np.ndarray
    upper_mu: np.ndarray
    lower_x: np.ndarray
    lower_mu: np.ndarray


def eda_pass(x_sorted: np.ndarray, mu_sorted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One EDA pass over points already sorted by x: masks (upper, lower).

    The slope d(k) = (mu_k - mu_{k-1}) / (x_k - x_{k-1}) with x_k >= x_{k-1} has the sign
    of mu_k - mu_{k-1} (a repeated x gives +-inf, same sign), so the sign is read from
    the rise alone and a repeated x never divides by zero.
    """
    rise = np.diff(mu_sorted)
    upper = np.zeros(x_sorted.shape[0], dtype=bool)
    lower = np.zeros(x_sorted.shape[0], dtype=bool)
    upper[1:] = rise > 0.0
    lower[1:] = ~upper[1:]
    return upper, lower


def _branch(x: np.ndarray, mu: np.ndarray, passes: int, keep_upper: bool) -> np.ndarray:
    """Indices kept by `passes` passes on one branch (upper or lower), with the guard.

    The first pass is the common split of the whole cloud; each later pass refines the
    set the previous one kept. A pass leaving fewer than 3 points stops the branch.
    """
    keep = np.arange(x.shape[0])
    for _ in range(passes):
        upper, lower = eda_pass(x[keep], mu[keep])
        chosen = keep[upper if keep_upper else lower]
        if chosen.shape[0] < MIN_ENVELOPE_POINTS:
            break
        keep = chosen
    return keep


def detect_envelopes(x: np.ndarray, mu: np.ndarray, passes: int = 2) -> Envelopes:
    """Upper and lower envelope points of the cloud (x, mu); passes = the paper's j_max."""
    x_arr = np.asarray(x, dtype=float).ravel()
    mu_arr = np.asarray(mu, dtype=float).ravel()
    if x_arr.shape != mu_arr.shape:
        raise ValueError(f"x and mu differ in length: {x_arr.shape[0]} vs {mu_arr.shape[0]}")
    if not (np.all(np.isfinite(x_arr)) and np.all(np.isfinite(mu_arr))):
        raise ValueError("x or mu contains NaN or infinite values")
    if int(passes) != passes or passes < 1:
        raise ValueError(f"passes must be an integer >= 1, got {passes}")
    if x_arr.shape[0] < MIN_ENVELOPE_POINTS + 1:
        raise ValueError(
            f"need at least {MIN_ENVELOPE_POINTS + 1} points for envelope detection, "
            f"got {x_arr.shape[0]}"
        )
    order = np.argsort(x_arr, kind="stable")
    xs, ms = x_arr[order], mu_arr[order]
    up = _branch(xs, ms, passes, keep_upper=True)
    lo = _branch(xs, ms, passes, keep_upper=False)
    return Envelopes(upper_x=xs[up], upper_mu=ms[up], lower_x=xs[lo], lower_mu=ms[lo])
