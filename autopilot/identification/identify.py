"""IVFM and T1FM identification of the attitude channels (docs/mathematics.md) (pure: no I/O).

Per channel, from identification data (x, y) and validation data:
  1. cluster_product_space: GK clustering of z = [x, y];
  2. premise_mfs: for every cluster i and input j, EDA on the projected memberships
     (x_kj, mu_ik), Gaussian fits of the upper and lower points, interval repair (IVFM);
     one Gaussian fitted to all projected points (T1FM);
  3. consequents by global least squares (least_squares.fit_consequents);
  4. RMSE of both models on the identification and the validation half.

Two kinds of output: the unknown function f itself (the paper's way, when a simulator
hands it over), or a measured angular acceleration y'' = f(x) + g U, for which f and the
constant g are fitted together with U as one more least-squares column.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from autopilot.identification.dataset import (
    CHANNEL_ACCELERATION,
    CHANNEL_FUNCTION,
    CHANNEL_INPUT,
    Dataset,
)
from autopilot.identification.envelope import detect_envelopes
from autopilot.identification.gaussian_fit import fit_gaussian, repair_interval
from autopilot.identification.gk import gustafson_kessel
from autopilot.identification.least_squares import fit_consequents, rmse
from autopilot.models.regressors import CHANNEL_REGRESSORS
from autopilot.models.ts_model import (
    ChannelModel,
    FuzzyModelSet,
    It2Model,
    T1Model,
    it2_regressor_matrix,
    t1_regressor_matrix,
)

# Chosen on smooth bilinear functions like the paper's f_phi = a1 theta' psi' - a2 theta' W_r
# (4000 samples of multi-sine excitation, 5 % output noise, 2000 + 2000 split, 12 data
# sets): the IVFM validation error against the true f, in standard deviations of the
# output, is 0.29 / 0.26 / 0.25 / 0.24 for c = 3 / 4 / 5 / 6 (T1FM: 0.40 / 0.30 / 0.29 /
# 0.29), with the same trend on f_theta- and f_psi-like functions and other GK seeds.
# Past c = 5 the gain is within the spread between data sets, while every cluster adds
# 2 (n + 1) parameters the controller must adapt.
DEFAULT_N_CLUSTERS = 5
# Relative ridge of the consequent least squares (see least_squares.py). 1e-8 is enough
# for the collinear IT2 halves in most data sets, but when the interval repair scales a
# lower MF far down, that rule's lower firing is almost never active in the data, its
# column almost zero, and its consequent grows until it ruins predictions where the rule
# does fire (validation RMSE several times the output's spread in about 1 of 12 data sets
# above). 1e-5 removed every such case and cost < 2 % of RMSE elsewhere.
DEFAULT_RIDGE = 1e-5


def _check_xy(x: np.ndarray, y: np.ndarray, n_inputs: int, what: str) -> tuple[np.ndarray, ...]:
    xa = np.asarray(x, dtype=float)
    ya = np.asarray(y, dtype=float).ravel()
    if xa.ndim == 1:
        xa = xa[:, None]
    if xa.ndim != 2 or xa.shape[1] != n_inputs:
        raise ValueError(f"x_{what} must be (N, {n_inputs}), got shape {np.shape(x)}")
    if ya.shape[0] != xa.shape[0]:
        raise ValueError(f"y_{what} has {ya.shape[0]} samples, x_{what} has {xa.shape[0]}")
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
        raise ValueError(f"x_{what} or y_{what} contains NaN or infinite values")
    return xa, ya


def cluster_product_space(
    x: np.ndarray, y: np.ndarray, n_clusters: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """GK partition (c, N) of z = [x, y] and the centres (c, n + 1) in original units.

    Each column is standardised (zero mean, unit standard deviation) before clustering
    and the centres are mapped back. GK's det-normalised norm makes the partition
    independent of column scales in exact arithmetic, but the covariance regularisation
    (eigenvalue-ratio limit) and the conditioning are not: with rotor speeds in the
    hundreds of rad/s beside rates of a few rad/s, unscaled columns would let one input
    dominate. A constant output (e.g. f_psi = 0 when Ixx = Iyy) carries no structure and
    is left out of the clustering; its centre coordinate is the constant itself.
    """
    z = np.column_stack([x, y])
    mean = z.mean(axis=0)
    std = z.std(axis=0)
    varying = np.ptp(z, axis=0) > 0.0
    scaled = (z[:, varying] - mean[varying]) / std[varying]
    result = gustafson_kessel(scaled, n_clusters, seed=seed)
    centers = np.tile(z[0], (n_clusters, 1))
    centers[:, varying] = result.centers * std[varying] + mean[varying]
    return result.partition, centers


def premise_mfs(
    x: np.ndarray, partition: np.ndarray, eda_passes: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Premise MF arrays (c, n, 3): IVFM lower, IVFM upper, T1FM.

    IVFM: EDA splits each projected cloud (x_kj, mu_ik) into upper and lower points, a
    Gaussian is fitted to each and the pair is repaired so 0 <= lower <= upper <= 1 for
    every x. T1FM: one Gaussian fitted to all the projected points of the cloud.
    """
    c = partition.shape[0]
    n = x.shape[1]
    lower = np.empty((c, n, 3))
    upper = np.empty((c, n, 3))
    single = np.empty((c, n, 3))
    for i in range(c):
        for j in range(n):
            env = detect_envelopes(x[:, j], partition[i], passes=eda_passes)
            lo, up = repair_interval(
                fit_gaussian(env.lower_x, env.lower_mu), fit_gaussian(env.upper_x, env.upper_mu)
            )
            lower[i, j] = lo.as_array()
            upper[i, j] = up.as_array()
            single[i, j] = fit_gaussian(x[:, j], partition[i]).as_array()
    return lower, upper, single


def _preliminary_gain(x: np.ndarray, y: np.ndarray, u: np.ndarray) -> float:
    """g of a global affine fit y ~ a^T x + b + g u, used only to take g u out of y before
    clustering, so that the clusters follow f's shape rather than the excitation."""
    theta = fit_consequents(np.column_stack([x, np.ones(x.shape[0])]), y, extra_columns=u)
    return float(theta[-1])


def identify_channel(
    x_ident: np.ndarray,
    y_ident: np.ndarray,
    x_valid: np.ndarray,
    y_valid: np.ndarray,
    regressor_names: tuple[str, ...] | list[str],
    *,
    n_clusters: int = DEFAULT_N_CLUSTERS,
    seed: int = 0,
    eda_passes: int = 2,
    u_ident: np.ndarray | None = None,
    u_valid: np.ndarray | None = None,
    ridge: float = DEFAULT_RIDGE,
) -> ChannelModel:
    """IVFM and T1FM of one channel from identification and validation data.

    x_*: (N, n) regressors named by regressor_names; y_*: (N,) output. Without u_* the
    output is f itself; with u_* (the control input) the output is an acceleration
    y'' = f(x) + g U and g is fitted with f (each model gets its own g).
    """
    names = tuple(regressor_names)
    n = len(names)
    xi, yi = _check_xy(x_ident, y_ident, n, "ident")
    xv, yv = _check_xy(x_valid, y_valid, n, "valid")
    if (u_ident is None) != (u_valid is None):
        raise ValueError("give both u_ident and u_valid, or neither")
    joint = u_ident is not None
    ui = uv = None
    if joint:
        ui = np.asarray(u_ident, dtype=float).ravel()
        uv = np.asarray(u_valid, dtype=float).ravel()
        if ui.shape[0] != xi.shape[0] or uv.shape[0] != xv.shape[0]:
            raise ValueError("u_ident / u_valid lengths differ from x_ident / x_valid")
        if not (np.all(np.isfinite(ui)) and np.all(np.isfinite(uv))):
            raise ValueError("u_ident or u_valid contains NaN or infinite values")
        if not np.any(ui != 0.0):
            raise ValueError("u_ident is identically zero: g cannot be identified")
    n_params = 2 * n_clusters * (n + 1) + (1 if joint else 0)
    if xi.shape[0] <= n_params:
        raise ValueError(
            f"too few identification samples: {xi.shape[0]} for {n_params} IVFM parameters"
        )
    if xv.shape[0] < 1:
        raise ValueError("no validation samples")
    for j, name in enumerate(names):
        if np.ptp(xi[:, j]) == 0.0:
            raise ValueError(f"regressor {name!r} is constant in the identification data")

    notes: list[str] = []
    y_cluster = yi
    if joint:
        g0 = _preliminary_gain(xi, yi, ui)
        y_cluster = yi - g0 * ui
    if np.ptp(y_cluster) == 0.0:
        notes.append(
            f"output is constant ({y_cluster[0]:g}) on the identification data: nothing to "
            "cluster in it; the models reproduce that constant"
        )

    partition, centers = cluster_product_space(xi, y_cluster, n_clusters, seed)
    lower, upper, single = premise_mfs(xi, partition, eda_passes)

    ranges = np.column_stack([xi.min(axis=0), xi.max(axis=0)])
    phi_it2_i = it2_regressor_matrix(xi, lower, upper)
    phi_t1_i = t1_regressor_matrix(xi, single)
    theta_it2 = fit_consequents(phi_it2_i, yi, ridge, extra_columns=ui)
    theta_t1 = fit_consequents(phi_t1_i, yi, ridge, extra_columns=ui)
    g_it2 = g_t1 = None
    if joint:
        theta_it2, g_it2 = theta_it2[:-1], float(theta_it2[-1])
        theta_t1, g_t1 = theta_t1[:-1], float(theta_t1[-1])

    def predict_output(phi: np.ndarray, theta: np.ndarray, g: float | None, u: Any) -> Any:
        out = phi @ theta
        return out if g is None else out + g * u

    ivfm = It2Model(lower, upper, theta_it2, names, ranges, g_it2)
    t1fm = T1Model(single, theta_t1, names, ranges, g_t1)
    return ChannelModel(
        ivfm=ivfm,
        t1fm=t1fm,
        n_clusters=int(n_clusters),
        output="acc" if joint else "f",
        rmse_ident_ivfm=rmse(predict_output(phi_it2_i, theta_it2, g_it2, ui), yi),
        rmse_valid_ivfm=rmse(predict_output(ivfm.regressor_matrix(xv), theta_it2, g_it2, uv), yv),
        rmse_ident_t1fm=rmse(predict_output(phi_t1_i, theta_t1, g_t1, ui), yi),
        rmse_valid_t1fm=rmse(predict_output(t1fm.regressor_matrix(xv), theta_t1, g_t1, uv), yv),
        cluster_centers=centers,
        notes=tuple(notes),
    )


def estimate_input_gain(residual: np.ndarray, u: np.ndarray) -> float | None:
    """Constant g minimising |residual - g u|^2 (residual = acc - f^(x)); None if u is 0."""
    energy = float(np.dot(u, u))
    if energy == 0.0:
        return None
    return float(np.dot(u, residual) / energy)


def identify_dataset(
    dataset: Dataset,
    channels: tuple[str, ...] | list[str] = ("phi", "theta", "psi"),
    split: float = 0.5,
    *,
    n_clusters: int = DEFAULT_N_CLUSTERS,
    seed: int = 0,
    eda_passes: int = 2,
    ridge: float = DEFAULT_RIDGE,
    metadata: dict[str, Any] | None = None,
) -> FuzzyModelSet:
    """Identify every requested channel; the first `split` of the rows identifies, the
    rest validates (the paper: 2000 + 2000 samples).

    With an f_<channel> column the models are fitted to f (the paper's way), and g is
    then estimated per model by least squares of (acc - f^(x)) on U (None when U or the
    acceleration is identically zero). Without it, f and g are fitted together to the
    acceleration column with U as an extra regressor.
    """
    if not 0.0 < split < 1.0:
        raise ValueError(f"split must be in (0, 1), got {split}")
    n_ident = int(round(split * dataset.n_rows))
    if n_ident < 1 or n_ident >= dataset.n_rows:
        raise ValueError(f"split {split} leaves an empty half of {dataset.n_rows} rows")
    ident = slice(0, n_ident)
    valid = slice(n_ident, None)
    models: dict[str, ChannelModel] = {}
    for ch in channels:
        if ch not in CHANNEL_REGRESSORS:
            raise ValueError(f"unknown channel {ch!r} (known: {list(CHANNEL_REGRESSORS)})")
        x = dataset.matrix(CHANNEL_REGRESSORS[ch])
        u = dataset.column(CHANNEL_INPUT[ch])
        acc = dataset.column(CHANNEL_ACCELERATION[ch])
        kwargs = dict(n_clusters=n_clusters, seed=seed, eda_passes=eda_passes, ridge=ridge)
        f_name = CHANNEL_FUNCTION[ch]
        if dataset.has(f_name):
            f = dataset.column(f_name)
            model = identify_channel(
                x[ident], f[ident], x[valid], f[valid], CHANNEL_REGRESSORS[ch], **kwargs
            )
            notes = list(model.notes)
            if np.any(acc[ident] != 0.0) and np.any(u[ident] != 0.0):
                g_it2 = estimate_input_gain(acc[ident] - model.ivfm.predict_f(x[ident]), u[ident])
                g_t1 = estimate_input_gain(acc[ident] - model.t1fm.predict_f(x[ident]), u[ident])
            else:
                g_it2 = g_t1 = None
                notes.append("g not identified: acceleration or input column is all zero")
            model = dataclasses.replace(
                model,
                ivfm=dataclasses.replace(model.ivfm, g=g_it2),
                t1fm=dataclasses.replace(model.t1fm, g=g_t1),
                notes=tuple(notes),
            )
        else:
            model = identify_channel(
                x[ident],
                acc[ident],
                x[valid],
                acc[valid],
                CHANNEL_REGRESSORS[ch],
                u_ident=u[ident],
                u_valid=u[valid],
                **kwargs,
            )
        models[ch] = model
    meta: dict[str, Any] = {
        "seed": seed,
        "split": split,
        "n_rows": dataset.n_rows,
        "source": dataset.source,
        "eda_passes": eda_passes,
        "ridge": ridge,
    }
    meta.update(metadata or {})
    return FuzzyModelSet(channels=models, metadata=meta)
