"""Gustafson-Kessel fuzzy clustering (structure identification, step 1 in
docs/mathematics.md).

GK is fuzzy c-means with one adaptive norm per cluster, A_i = det(F_i)^(1/d) F_i^-1
(cluster volume rho_i = 1), so each cluster can be an ellipsoid aligned with a local
linear piece of the data: exactly what a Takagi-Sugeno model needs from its clusters.

The fuzzy covariances are regularised as Babuska, van der Veen and Kaymak (2002),
"Improved covariance estimation for Gustafson-Kessel clustering", FUZZ-IEEE:
  1. blend with a scaled identity, F_i <- (1 - gamma) F_i + gamma det(F0)^(1/d) I, where F0
     is the covariance of the whole data set (gamma = 0 switches it off);
  2. limit the eigenvalue ratio: eigenvalues below lambda_max / beta are raised to
     lambda_max / beta and F_i is rebuilt from its eigenvectors,
so F_i never becomes singular, even for flat (e.g. exactly linear) clusters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class GkResult:
    """Outcome of one GK run.

    centers: (c, d) cluster prototypes v_i.
    partition: (c, N) membership degrees mu_ik; every column sums to 1.
    covariances: (c, d, d) regularised fuzzy covariances F_i.
    n_iter: iterations done; objective: J = sum_ik mu_ik^m D_ik^2 at the end.
    """

    centers: np.ndarray
    partition: np.ndarray
    covariances: np.ndarray
    n_iter: int
    objective: float


def _validate(data: np.ndarray, n_clusters: int, fuzziness: float) -> np.ndarray:
    """Refuse inputs GK cannot cluster meaningfully, naming the problem."""
    arr = np.asarray(data, dtype=float)
    if arr.ndim != 2:
        raise ValueError(f"data must be 2-D (N x d), got {arr.ndim}-D")
    if not np.all(np.isfinite(arr)):
        raise ValueError("data contains NaN or infinite values")
    if int(n_clusters) != n_clusters or n_clusters < 2:
        raise ValueError(f"n_clusters must be an integer >= 2, got {n_clusters}")
    if arr.shape[0] <= n_clusters:
        raise ValueError(
            f"need more samples than clusters: N = {arr.shape[0]}, n_clusters = {n_clusters}"
        )
    if not np.isfinite(fuzziness) or fuzziness <= 1.0:
        raise ValueError(f"fuzziness must be > 1, got {fuzziness}")
    if not np.any(np.ptp(arr, axis=0) > 0.0):
        raise ValueError("data has no spread: every column is constant")
    return arr


def regularised_covariance(
    cov: np.ndarray, identity_scale: float, *, gamma: float, beta: float
) -> np.ndarray:
    """Babuska-van der Veen-Kaymak covariance regularisation of one fuzzy covariance.

    identity_scale is det(F0)^(1/d) of the whole data set's covariance F0.
    """
    d = cov.shape[0]
    blended = (1.0 - gamma) * cov + gamma * identity_scale * np.eye(d)
    blended = 0.5 * (blended + blended.T)
    eigval, eigvec = np.linalg.eigh(blended)
    lam_max = float(eigval.max())
    if lam_max <= 0.0:
        # A cluster collapsed onto a single point: no shape information left, use a
        # sphere of the data set's size so the next iteration can recover.
        return max(identity_scale, np.finfo(float).tiny) * np.eye(d)
    eigval = np.maximum(eigval, lam_max / beta)
    return (eigvec * eigval) @ eigvec.T


def update_partition(dist2: np.ndarray, fuzziness: float) -> np.ndarray:
    """FCM membership update from squared distances (c x N).

    A point that lies on one or more centres (zero distance) belongs to them only, split
    evenly, instead of producing 0/0. Ratios are taken to the nearest centre so that
    no power overflows.
    """
    c, n = dist2.shape
    partition = np.empty((c, n))
    zero = dist2 <= 0.0
    on_centre = zero.any(axis=0)
    if np.any(on_centre):
        hits = zero[:, on_centre].astype(float)
        partition[:, on_centre] = hits / hits.sum(axis=0)
    rest = ~on_centre
    if np.any(rest):
        d2 = dist2[:, rest]
        ratio = (d2 / d2.min(axis=0)) ** (-1.0 / (fuzziness - 1.0))
        partition[:, rest] = ratio / ratio.sum(axis=0)
    return partition


def _norm_distances(data: np.ndarray, centers: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Squared GK distances D_ik^2 = (z_k - v_i)^T A_i (z_k - v_i), A_i = det(F_i)^(1/d) F_i^-1."""
    c = centers.shape[0]
    d = data.shape[1]
    dist2 = np.empty((c, data.shape[0]))
    for i in range(c):
        sign, logdet = np.linalg.slogdet(covariances[i])
        if sign <= 0:  # cannot happen after regularisation; guard against round-off
            raise FloatingPointError(f"cluster {i} covariance is not positive definite")
        norm = np.exp(logdet / d) * np.linalg.inv(covariances[i])
        diff = data - centers[i]
        dist2[i] = np.maximum(np.einsum("kj,jl,kl->k", diff, norm, diff), 0.0)
    return dist2


def gustafson_kessel(
    data: np.ndarray,
    n_clusters: int,
    *,
    fuzziness: float = 2.0,
    max_iter: int = 300,
    tol: float = 1e-7,
    seed: int = 0,
    gamma: float = 0.0,
    beta: float = 1e15,
) -> GkResult:
    """Cluster the rows of data (N x d) into n_clusters GK clusters.

    Iteration (Babuska's form): from a random fuzzy partition, repeat
    centres -> regularised covariances -> norm distances -> partition until the largest
    change of any membership is below tol. Deterministic for a given seed.
    """
    z = _validate(data, n_clusters, fuzziness)
    if not 0.0 <= gamma <= 1.0:
        raise ValueError(f"gamma must be in [0, 1], got {gamma}")
    if not beta >= 1.0:
        raise ValueError(f"beta must be >= 1, got {beta}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    n_samples, d = z.shape
    c = int(n_clusters)

    cov0 = np.atleast_2d(np.cov(z, rowvar=False, bias=True))
    sign0, logdet0 = np.linalg.slogdet(cov0)
    identity_scale = float(np.exp(logdet0 / d)) if sign0 > 0 else 0.0

    rng = np.random.default_rng(seed)
    init = rng.uniform(size=(n_samples, c))
    partition = (init / init.sum(axis=1, keepdims=True)).T

    centers = np.empty((c, d))
    covariances = np.empty((c, d, d))
    dist2 = np.empty((c, n_samples))
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007 (n_iter is reported)
        weights = partition**fuzziness
        wsum = weights.sum(axis=1)
        centers = (weights @ z) / wsum[:, None]
        for i in range(c):
            diff = z - centers[i]
            cov = (weights[i, :, None] * diff).T @ diff / wsum[i]
            covariances[i] = regularised_covariance(cov, identity_scale, gamma=gamma, beta=beta)
        dist2 = _norm_distances(z, centers, covariances)
        new_partition = update_partition(dist2, fuzziness)
        change = float(np.max(np.abs(new_partition - partition)))
        partition = new_partition
        if change < tol:
            break

    objective = float(np.sum(partition**fuzziness * dist2))
    return GkResult(
        centers=centers,
        partition=partition,
        covariances=covariances.copy(),
        n_iter=n_iter,
        objective=objective,
    )
