"""Consequent parameters by global (ridge-regularised) least squares, identification
step 4 in docs/mathematics.md.

Why a ridge: the IT2 regressor is 1/2 [xi_l (x) [x;1] ; xi_r (x) [x;1]], and xi_l and xi_r
both sum to 1 over the rules, so sum_i xi_l,i [x;1] = sum_i xi_r,i [x;1] = [x;1] for every
x: the regressor matrix is exactly rank deficient by n + 1. Adding the same vector v to
every lower consequent w_l,i and subtracting it from every upper one w_r,i changes no
prediction; the data cannot tell these solutions apart. Beyond that, xi_l and xi_r are
usually close to each other, so the two halves are also nearly collinear. Unregularised,
least squares may return huge, opposite w_l and w_r whose difference fits noise; they
predict well on the identification data but extrapolate badly and are a poor starting
point for the controller's adaptation. A small ridge picks the solution of small norm
(the minimum-norm one as ridge -> 0) and changes the fit itself negligibly. The same holds
for a rule whose (lower) firing is almost never active in the data: its columns are
nearly zero and, unpenalised, its consequent grows without bound.

The ridge is relative to the regressor scale: lambda = ridge * N * mean(Phi^2), one scale
for the whole fuzzy block. (Scaling each column by its own RMS would make the penalty
vanish on exactly those nearly-zero columns.) Plain extra columns such as U are scaled by
their own RMS, so the penalty on g does not depend on U's units.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


def fit_consequents(
    regressor_matrix: np.ndarray,
    y: np.ndarray,
    ridge: float = 1e-8,
    *,
    extra_columns: np.ndarray | None = None,
) -> np.ndarray:
    """theta minimising |Phi theta - y|^2 + ridge N |S theta|^2 (S: regressor scales).

    extra_columns (N,) or (N, k): plain regressors appended after the fuzzy ones, e.g. the
    control input U when the output is a measured acceleration y'' = f(x) + g U; their
    coefficients (g) come last in theta.
    """
    phi = np.asarray(regressor_matrix, dtype=float)
    target = np.asarray(y, dtype=float).ravel()
    if phi.ndim != 2:
        raise ValueError(f"regressor_matrix must be 2-D, got {phi.ndim}-D")
    n_fuzzy = phi.shape[1]
    if extra_columns is not None:
        extra = np.asarray(extra_columns, dtype=float)
        extra = extra.reshape(extra.shape[0], -1)
        if extra.shape[0] != phi.shape[0]:
            raise ValueError(
                f"extra_columns has {extra.shape[0]} rows, regressor_matrix {phi.shape[0]}"
            )
        phi = np.hstack([phi, extra])
    n_rows, n_params = phi.shape
    if target.shape[0] != n_rows:
        raise ValueError(f"y has {target.shape[0]} samples, regressor_matrix {n_rows} rows")
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(target))):
        raise ValueError("regressors or output contain NaN or infinite values")
    if not np.isfinite(ridge) or ridge < 0.0:
        raise ValueError(f"ridge must be a finite number >= 0, got {ridge}")

    # fuzzy block: one scale for all its columns (see the module docstring); plain extra
    # columns: each its own RMS, so g's penalty does not depend on U's units
    scale = np.full(n_params, np.sqrt(np.mean(phi[:, :n_fuzzy] ** 2)) if n_fuzzy else 1.0)
    if n_params > n_fuzzy:
        scale[n_fuzzy:] = np.sqrt(np.mean(phi[:, n_fuzzy:] ** 2, axis=0))
    scale[scale == 0.0] = 1.0  # all-zero columns get coefficient 0 (minimum norm)
    phi_s = phi / scale
    if ridge > 0.0:
        # augmented system [Phi_s; sqrt(ridge N) I] theta_s = [y; 0]: ridge without forming
        # the squared-conditioned normal equations
        a = np.vstack([phi_s, np.sqrt(ridge * n_rows) * np.eye(n_params)])
        b = np.concatenate([target, np.zeros(n_params)])
    else:
        a, b = phi_s, target
    theta_s, *_ = scipy.linalg.lstsq(a, b)
    return theta_s / scale


def rmse(prediction: np.ndarray, target: np.ndarray) -> float:
    """Root mean square error."""
    err = np.asarray(prediction, dtype=float) - np.asarray(target, dtype=float)
    return float(np.sqrt(np.mean(err * err)))
