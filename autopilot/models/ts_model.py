"""Interval type-2 (IVFM) and type-1 (T1FM) Takagi-Sugeno models, identification steps
4-5 in docs/mathematics.md.

Rules "if x is A_i then y_i = a_i^T x + b_i", i = 1..c, with Gaussian premise MFs stored
as arrays shaped (c, n, 3) holding [h, c, s] per cluster i and input j.

IT2 firing and output (the paper's phi = 1/2 (xi_l + xi_r)):
    f_i = prod_j lower_ij(x_j),  F_i = prod_j upper_ij(x_j),
    xi_l = f / sum(f),  xi_r = F / sum(F),
    phi_f(x) = 1/2 [xi_l (x) [x; 1] ; xi_r (x) [x; 1]],  f^(x) = theta_f^T phi_f(x),
    theta_f = [w_l; w_r], w_l = [a_l1; b_l1; a_l2; b_l2; ...] (likewise w_r).
T1: phi(x) = xi (x) [x; 1], xi = normalised product firing of the single MFs.

The normalised firings are computed in the log domain, ln f_i = sum_j [ln h_ij -
(x_j - c_ij)^2 / (2 s_ij^2)], then exp(ln f - max) / sum: far outside the data every
Gaussian underflows to 0 and the direct quotient would be 0/0, while the log-domain
weights stay finite, sum to 1 and pick the rule whose MFs reach furthest.

The single-sample regressors are numba-compiled (the controller calls them every
control period); the batch versions are plain numpy for identification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

# ---------------------------------------------------------------- single sample (numba)


@njit(cache=True)
def normalised_firing(x: np.ndarray, mfs: np.ndarray) -> np.ndarray:
    """Normalised product firing xi (c,) of the MFs (c, n, 3) at x (n,), log domain."""
    c = mfs.shape[0]
    n = mfs.shape[1]
    log_f = np.empty(c)
    for i in range(c):
        acc = 0.0
        for j in range(n):
            d = x[j] - mfs[i, j, 1]
            s = mfs[i, j, 2]
            acc += math.log(mfs[i, j, 0]) - d * d / (2.0 * s * s)
        log_f[i] = acc
    top = log_f.max()
    xi = np.empty(c)
    if top == -np.inf:  # every rule has a zero-height MF: no preference, share evenly
        xi[:] = 1.0 / c
        return xi
    total = 0.0
    for i in range(c):
        xi[i] = math.exp(log_f[i] - top)
        total += xi[i]
    for i in range(c):
        xi[i] /= total
    return xi


@njit(cache=True)
def it2_regressor(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """phi_f(x) = 1/2 [xi_l (x) [x;1] ; xi_r (x) [x;1]], length 2 c (n + 1)."""
    c = lower.shape[0]
    n = lower.shape[1]
    xi_l = normalised_firing(x, lower)
    xi_r = normalised_firing(x, upper)
    block = n + 1
    half = c * block
    phi = np.empty(2 * half)
    for i in range(c):
        base = i * block
        for j in range(n):
            phi[base + j] = 0.5 * xi_l[i] * x[j]
            phi[half + base + j] = 0.5 * xi_r[i] * x[j]
        phi[base + n] = 0.5 * xi_l[i]
        phi[half + base + n] = 0.5 * xi_r[i]
    return phi


@njit(cache=True)
def t1_regressor(x: np.ndarray, mfs: np.ndarray) -> np.ndarray:
    """phi(x) = xi (x) [x;1], length c (n + 1)."""
    c = mfs.shape[0]
    n = mfs.shape[1]
    xi = normalised_firing(x, mfs)
    block = n + 1
    phi = np.empty(c * block)
    for i in range(c):
        base = i * block
        for j in range(n):
            phi[base + j] = xi[i] * x[j]
        phi[base + n] = xi[i]
    return phi


# ---------------------------------------------------------------- batches (numpy)


def normalised_firing_batch(x: np.ndarray, mfs: np.ndarray) -> np.ndarray:
    """Normalised firings (N, c) for samples x (N, n); same log-domain rule as above."""
    xa = np.atleast_2d(np.asarray(x, dtype=float))
    h, cen, sig = mfs[..., 0], mfs[..., 1], mfs[..., 2]
    with np.errstate(divide="ignore"):
        log_h = np.log(h)
    d = xa[:, None, :] - cen[None, :, :]
    log_f = np.sum(log_h[None] - d * d / (2.0 * sig * sig)[None], axis=2)
    top = log_f.max(axis=1, keepdims=True)
    dead = ~np.isfinite(top[:, 0]) & (top[:, 0] < 0)
    top[dead] = 0.0
    w = np.exp(log_f - top)
    w[dead] = 1.0
    return w / w.sum(axis=1, keepdims=True)


def _kron_rows(xi: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Row-wise xi (x) [x;1]: (N, c) and (N, n) -> (N, c (n + 1))."""
    xa = np.hstack([x, np.ones((x.shape[0], 1))])
    return (xi[:, :, None] * xa[:, None, :]).reshape(x.shape[0], -1)


def it2_regressor_matrix(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Rows phi_f(x_k) of the IT2 model for samples x (N, n): (N, 2 c (n + 1))."""
    xa = np.atleast_2d(np.asarray(x, dtype=float))
    xi_l = normalised_firing_batch(xa, lower)
    xi_r = normalised_firing_batch(xa, upper)
    return 0.5 * np.hstack([_kron_rows(xi_l, xa), _kron_rows(xi_r, xa)])


def t1_regressor_matrix(x: np.ndarray, mfs: np.ndarray) -> np.ndarray:
    """Rows phi(x_k) of the type-1 model for samples x (N, n): (N, c (n + 1))."""
    xa = np.atleast_2d(np.asarray(x, dtype=float))
    return _kron_rows(normalised_firing_batch(xa, mfs), xa)


def predict(theta: np.ndarray, regressor: np.ndarray) -> np.ndarray | float:
    """theta^T phi for one regressor (p,) or every row of a regressor matrix (N, p)."""
    out = np.asarray(regressor, dtype=float) @ np.asarray(theta, dtype=float)
    return float(out) if np.ndim(out) == 0 else out


# ---------------------------------------------------------------- model containers


def _as_mf_array(a: Any) -> np.ndarray:
    # C-contiguous float64 so numba compiles one specialisation only
    return np.ascontiguousarray(np.asarray(a, dtype=float))


@dataclass(frozen=True, eq=False)
class It2Model:
    """Interval type-2 TS model of one channel's f (and the constant g when identified).

    lower, upper: (c, n, 3) MF arrays; theta_f: (2 c (n + 1),); input_ranges: (n, 2)
    [min, max] of each regressor over the identification data; g: input gain estimate
    (theta_g's initial value) or None when the data could not identify it.
    """

    lower: np.ndarray
    upper: np.ndarray
    theta_f: np.ndarray
    regressor_names: tuple[str, ...]
    input_ranges: np.ndarray
    g: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "lower", _as_mf_array(self.lower))
        object.__setattr__(self, "upper", _as_mf_array(self.upper))
        object.__setattr__(self, "theta_f", _as_mf_array(self.theta_f))
        object.__setattr__(self, "input_ranges", _as_mf_array(self.input_ranges))
        object.__setattr__(self, "regressor_names", tuple(self.regressor_names))

    @property
    def n_clusters(self) -> int:
        return int(self.lower.shape[0])

    def regressor(self, x: np.ndarray) -> np.ndarray:
        """phi_f(x) for one sample (numba)."""
        return it2_regressor(np.ascontiguousarray(x, dtype=float), self.lower, self.upper)

    def regressor_matrix(self, x: np.ndarray) -> np.ndarray:
        """phi_f rows for samples x (N, n)."""
        return it2_regressor_matrix(x, self.lower, self.upper)

    def predict_f(self, x: np.ndarray) -> np.ndarray:
        """f^(x_k) for samples x (N, n)."""
        return self.regressor_matrix(x) @ self.theta_f


@dataclass(frozen=True, eq=False)
class T1Model:
    """Type-1 TS counterpart: mfs (c, n, 3), theta_f (c (n + 1),), as It2Model otherwise."""

    mfs: np.ndarray
    theta_f: np.ndarray
    regressor_names: tuple[str, ...]
    input_ranges: np.ndarray
    g: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "mfs", _as_mf_array(self.mfs))
        object.__setattr__(self, "theta_f", _as_mf_array(self.theta_f))
        object.__setattr__(self, "input_ranges", _as_mf_array(self.input_ranges))
        object.__setattr__(self, "regressor_names", tuple(self.regressor_names))

    @property
    def n_clusters(self) -> int:
        return int(self.mfs.shape[0])

    def regressor(self, x: np.ndarray) -> np.ndarray:
        """phi(x) for one sample (numba)."""
        return t1_regressor(np.ascontiguousarray(x, dtype=float), self.mfs)

    def regressor_matrix(self, x: np.ndarray) -> np.ndarray:
        """phi rows for samples x (N, n)."""
        return t1_regressor_matrix(x, self.mfs)

    def predict_f(self, x: np.ndarray) -> np.ndarray:
        """f^(x_k) for samples x (N, n)."""
        return self.regressor_matrix(x) @ self.theta_f


@dataclass(frozen=True, eq=False)
class ChannelModel:
    """Both identified models of one channel, with how well they did.

    output: "f" when the unknown function itself was the output (the paper's way),
    "acc" when f and g were fitted together to a measured acceleration; the RMSEs are
    of that output. cluster_centers: (c, n + 1) GK centres [x, y] in original units.
    notes: plain-language remarks for the report (e.g. a constant output).
    """

    ivfm: It2Model
    t1fm: T1Model
    n_clusters: int
    output: str
    rmse_ident_ivfm: float
    rmse_valid_ivfm: float
    rmse_ident_t1fm: float
    rmse_valid_t1fm: float
    cluster_centers: np.ndarray
    notes: tuple[str, ...] = ()

    @property
    def g(self) -> float | None:
        """theta_g's initial value for the IVFM controller."""
        return self.ivfm.g

    @property
    def regressor_names(self) -> tuple[str, ...]:
        return self.ivfm.regressor_names


@dataclass(eq=False)
class FuzzyModelSet:
    """What the identification produces and the autopilot loads: one model per channel."""

    channels: dict[str, ChannelModel]
    metadata: dict[str, Any] = field(default_factory=dict)
