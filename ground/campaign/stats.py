"""Statistics of a campaign (pure): distributions with bootstrap confidence intervals,
and paired comparisons (same draw, two controllers or two model types).

Intervals are percentile bootstrap intervals (scipy.stats.bootstrap), seeded so a report
is the same on every run; a win rate's interval is Wilson's (scipy.stats.binomtest).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 2000


def _p95(values: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.percentile(values, 95, axis=axis)


def bootstrap_ci(values: np.ndarray, statistic: Any, seed: int = 0) -> tuple[float, float]:
    """The 95 % percentile-bootstrap interval of ``statistic`` (vectorized: takes
    ``axis``); (nan, nan) for fewer than 3 values or values that are all equal."""
    values = np.asarray(values, dtype=float)
    if values.size < 3 or np.all(values == values[0]):
        value = float(statistic(values, axis=-1)) if values.size else np.nan
        return (value, value) if values.size else (np.nan, np.nan)
    result = stats.bootstrap((values,), statistic, n_resamples=RESAMPLES,
                             confidence_level=CONFIDENCE, method="percentile",
                             rng=np.random.default_rng(seed), vectorized=True)
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def summary(values: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """n, mean, median and p95 of ``values``, each with its 95 % interval."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    out: dict[str, Any] = {"n": int(values.size)}
    for name, statistic in (("mean", np.mean), ("median", np.median), ("p95", _p95)):
        out[name] = float(statistic(values, axis=-1)) if values.size else None
        low, high = bootstrap_ci(values, statistic, seed)
        out[f"{name}_ci"] = [low, high] if values.size else None
    return out


def paired(a: np.ndarray, b: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """``a`` against ``b``, draw by draw (lower is better): how often a wins, and the
    difference a - b (mean and median) and the ratio a / b (median), with intervals.
    Pairs where either is missing are left out."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    n = int(a.size)
    out: dict[str, Any] = {"n": n}
    if n == 0:
        return {**out, "wins": 0, "win_rate": None, "win_rate_ci": None,
                "mean_difference": None, "mean_difference_ci": None,
                "median_difference": None, "median_difference_ci": None,
                "median_ratio": None, "median_ratio_ci": None}
    wins = int(np.sum(a < b))
    ci = stats.binomtest(wins, n).proportion_ci(CONFIDENCE, method="wilson")
    difference = a - b
    out.update({"wins": wins, "win_rate": wins / n, "win_rate_ci": [ci.low, ci.high],
                "mean_difference": float(np.mean(difference)),
                "mean_difference_ci": list(bootstrap_ci(difference, np.mean, seed)),
                "median_difference": float(np.median(difference)),
                "median_difference_ci": list(bootstrap_ci(difference, np.median, seed))})
    ratio = a / np.where(b > 0, b, np.nan)
    ratio = ratio[np.isfinite(ratio)]
    out["median_ratio"] = float(np.median(ratio)) if ratio.size else None
    out["median_ratio_ci"] = list(bootstrap_ci(ratio, np.median, seed)) if ratio.size else None
    return out


def verdict(comparison: dict[str, Any]) -> str:
    """What a paired comparison supports: "a better" when the whole interval of the median
    difference is below 0, "b better" above, "no clear difference" otherwise."""
    ci = comparison.get("median_difference_ci")
    if not ci or ci[0] is None or not np.isfinite(ci[0]):
        return "not enough data"
    if ci[1] < 0:
        return "a better"
    if ci[0] > 0:
        return "b better"
    return "no clear difference"
