"""Tests of the offline IVFM identification (docs/mathematics.md)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from autopilot.identification.dataset import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    Dataset,
    DatasetError,
    read_dataset,
    write_dataset,
)
from autopilot.identification.envelope import detect_envelopes
from autopilot.identification.gaussian_fit import fit_gaussian, repair_interval
from autopilot.identification.gk import gustafson_kessel, update_partition
from autopilot.identification.identify import identify_channel, identify_dataset
from autopilot.identification.least_squares import fit_consequents
from autopilot.models.membership import Gaussian, interval_holds, max_log_ratio
from autopilot.models.model_file import (
    ModelFileError,
    load_model,
    model_set_to_dict,
    save_model,
)
from autopilot.models.regressors import CHANNEL_REGRESSORS
from autopilot.models.ts_model import (
    it2_regressor,
    it2_regressor_matrix,
    normalised_firing,
    normalised_firing_batch,
    t1_regressor,
    t1_regressor_matrix,
)

# ---------------------------------------------------------------- helpers


def smooth_signal(rng: np.random.Generator, n: int, amplitude: float, fmax_hz: float = 1.0):
    """A multi-sine excitation sampled at 100 Hz, peak value `amplitude`."""
    t = np.arange(n) * 0.01
    s = np.zeros(n)
    for _ in range(5):
        f = rng.uniform(0.05, fmax_hz)
        s += rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return amplitude * s / np.max(np.abs(s))


def bilinear_data(seed: int, n: int = 4000, noise: float = 0.05):
    """The paper's f_phi shape, f = 0.5 a b - 0.0073 a w, with 5 % output noise."""
    rng = np.random.default_rng(seed)
    x = np.column_stack(
        [smooth_signal(rng, n, 2.0), smooth_signal(rng, n, 2.0), smooth_signal(rng, n, 40.0)]
    )
    f = 0.5 * x[:, 0] * x[:, 1] - 0.0073 * x[:, 0] * x[:, 2]
    y = f + noise * np.ptp(f) / 2 * rng.normal(size=n)
    return x, f, y


def elongated_blobs(seed: int = 1):
    rng = np.random.default_rng(seed)
    parts, labels = [], []
    specs = [([0, 0], 0.3, 3.0, 0.3), ([10, 5], -0.8, 3.0, 0.3), ([-5, 10], 1.2, 2.5, 0.2)]
    for k, (center, angle, sx, sy) in enumerate(specs):
        rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        parts.append((rng.normal(size=(300, 2)) * [sx, sy]) @ rot.T + center)
        labels.append(np.full(300, k))
    return np.vstack(parts), np.concatenate(labels)


def random_mfs(rng: np.random.Generator, c: int, n: int, spread: float = 2.0) -> np.ndarray:
    mfs = np.empty((c, n, 3))
    mfs[..., 0] = rng.uniform(0.3, 1.0, (c, n))
    mfs[..., 1] = rng.uniform(-spread, spread, (c, n))
    mfs[..., 2] = rng.uniform(0.4, 1.5, (c, n))
    return mfs


def random_interval_mfs(rng: np.random.Generator, c: int, n: int):
    upper = random_mfs(rng, c, n)
    lower = upper.copy()
    lower[..., 0] *= rng.uniform(0.3, 0.8, (c, n))
    lower[..., 2] *= rng.uniform(0.5, 0.9, (c, n))
    return lower, upper


def grid_check(lower: Gaussian, upper: Gaussian) -> bool:
    """0 <= lower <= upper <= 1 on a dense grid reaching 60 sigmas out.

    lower <= upper is compared in the log domain everywhere (the way the model evaluates
    firings) and in the linear domain wherever upper is a normal float: below ~1e-308 the
    subnormals have too few digits to compare two nearly equal values.
    """
    lo_edge = min(lower.c - 60 * lower.s, upper.c - 60 * upper.s)
    hi_edge = max(lower.c + 60 * lower.s, upper.c + 60 * upper.s)
    x = np.linspace(lo_edge, hi_edge, 20001)
    lo, up = lower(x), upper(x)
    with np.errstate(divide="ignore"):
        log_lo = np.log(lower.h) - (x - lower.c) ** 2 / (2 * lower.s**2)
    log_up = np.log(upper.h) - (x - upper.c) ** 2 / (2 * upper.s**2)
    normal = up >= np.finfo(float).tiny
    return bool(
        np.all(lo >= 0.0)
        and np.all(up <= 1.0)
        and np.all(log_lo <= log_up)
        and np.all(lo[normal] <= up[normal])
    )


# ---------------------------------------------------------------- GK


def test_gk_separates_elongated_clusters():
    data, labels = elongated_blobs()
    result = gustafson_kessel(data, 3, seed=3)
    pred = result.partition.argmax(axis=0)
    confusion = np.zeros((3, 3))
    np.add.at(confusion, (labels, pred), 1)
    rows, cols = linear_sum_assignment(-confusion)
    assert confusion[rows, cols].sum() / labels.size > 0.98
    np.testing.assert_allclose(result.partition.sum(axis=0), 1.0, atol=1e-12)
    assert result.covariances.shape == (3, 2, 2)


def test_gk_matches_fcmeans_gk():
    from fcmeans import GK

    data, _ = elongated_blobs()
    ours = gustafson_kessel(data, 3, seed=3, tol=1e-11, max_iter=1000)
    ref = GK(n_clusters=3, reg=1e-14, error=1e-9, max_iter=1000, random_state=5)
    ref.fit(data)
    cost = np.linalg.norm(ours.centers[:, None] - ref.centers[None], axis=2)
    rows, cols = linear_sum_assignment(cost)
    np.testing.assert_allclose(ours.centers[rows], ref.centers[cols], atol=1e-8)
    np.testing.assert_allclose(ours.partition[rows], ref.u.T[cols], atol=1e-8)


def test_gk_full_identity_blend_is_fcm():
    """gamma = 1 replaces every covariance by det(F0)^(1/d) I: GK becomes fuzzy c-means."""
    from fcmeans import FCM

    data, _ = elongated_blobs()
    ours = gustafson_kessel(data, 3, seed=3, gamma=1.0, tol=1e-11, max_iter=1000)
    ref = FCM(n_clusters=3, error=1e-9, max_iter=1000, random_state=5)
    ref.fit(data)
    cost = np.linalg.norm(ours.centers[:, None] - ref.centers[None], axis=2)
    rows, cols = linear_sum_assignment(cost)
    np.testing.assert_allclose(ours.centers[rows], ref.centers[cols], atol=1e-8)
    scale = np.exp(np.linalg.slogdet(np.cov(data.T, bias=True))[1] / 2)
    np.testing.assert_allclose(ours.covariances, np.tile(scale * np.eye(2), (3, 1, 1)))


def test_gk_eigenvalue_limit_keeps_flat_clusters_regular():
    rng = np.random.default_rng(2)
    t = rng.uniform(-1, 1, 400)
    data = np.column_stack([t, 2 * t, -t])  # exactly a line in 3-D: singular covariances
    data[200:] += [5.0, 0.0, 0.0]
    beta = 1e6
    result = gustafson_kessel(data, 2, seed=0, beta=beta)
    assert np.all(np.isfinite(result.partition)) and np.all(np.isfinite(result.centers))
    for cov in result.covariances:
        eig = np.linalg.eigvalsh(cov)
        assert eig.max() / eig.min() <= beta * (1 + 1e-6)


def test_gk_deterministic_and_seeded():
    data, _ = elongated_blobs()
    a = gustafson_kessel(data, 3, seed=7)
    b = gustafson_kessel(data, 3, seed=7)
    assert np.array_equal(a.partition, b.partition) and np.array_equal(a.centers, b.centers)
    assert a.n_iter >= 1 and math.isfinite(a.objective)


def test_partition_update_handles_point_on_a_centre():
    dist2 = np.array([[0.0, 1.0, 0.0, 4.0], [2.0, 1.0, 0.0, 1e-300], [3.0, 1.0, 5.0, 1.0]])
    u = update_partition(dist2, 2.0)
    assert np.all(np.isfinite(u))
    np.testing.assert_allclose(u.sum(axis=0), 1.0)
    np.testing.assert_array_equal(u[:, 0], [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(u[:, 2], [0.5, 0.5, 0.0])
    np.testing.assert_allclose(u[:, 1], 1 / 3)


def test_gk_with_data_point_on_every_centre_stays_finite():
    # two tight groups of identical points: centres converge onto data points exactly
    data = np.array([[0.0, 0.0]] * 10 + [[1.0, 1.0]] * 10 + [[0.0, 0.1], [1.0, 1.1]])
    result = gustafson_kessel(data, 2, seed=0)
    assert np.all(np.isfinite(result.partition))
    np.testing.assert_allclose(result.partition.sum(axis=0), 1.0)


@pytest.mark.parametrize(
    ("data", "kwargs", "message"),
    [
        (np.ones(10), {}, "2-D"),
        (np.array([[0.0, 1.0], [np.nan, 2.0], [1.0, 1.0]]), {}, "NaN"),
        (np.array([[0.0, 1.0], [np.inf, 2.0], [1.0, 1.0]]), {}, "NaN or infinite"),
        (np.arange(6.0).reshape(3, 2), {"n_clusters": 3}, "more samples than clusters"),
        (np.arange(20.0).reshape(10, 2), {"n_clusters": 1}, "n_clusters"),
        (np.arange(20.0).reshape(10, 2), {"fuzziness": 1.0}, "fuzziness"),
        (np.ones((10, 2)), {}, "no spread"),
    ],
)
def test_gk_rejects_bad_input(data, kwargs, message):
    args = {"n_clusters": 2} | kwargs
    with pytest.raises(ValueError, match=message):
        gustafson_kessel(data, args.pop("n_clusters"), **args)


# ---------------------------------------------------------------- EDA


def test_eda_single_pass_rule_on_a_hand_example():
    x = np.arange(8.0)
    mu = np.array([0.1, 0.5, 0.3, 0.6, 0.2, 0.7, 0.65, 0.9])
    one = detect_envelopes(x, mu, passes=1)
    np.testing.assert_array_equal(one.upper_x, [1, 3, 5, 7])
    np.testing.assert_array_equal(one.lower_x, [2, 4, 6])
    two = detect_envelopes(x, mu, passes=2)
    np.testing.assert_array_equal(two.upper_x, [3, 5, 7])  # upper of the upper set
    np.testing.assert_array_equal(two.lower_x, [2, 4, 6])  # 1 point left: keep previous
    perm = np.random.default_rng(0).permutation(8)
    shuffled = detect_envelopes(x[perm], mu[perm], passes=2)
    np.testing.assert_array_equal(shuffled.upper_x, two.upper_x)
    np.testing.assert_array_equal(shuffled.lower_mu, two.lower_mu)


def test_eda_degenerate_branch_keeps_previous_set():
    x = np.arange(10.0)
    mu = np.linspace(1.0, 0.1, 10)  # only falls: no point has a positive slope
    env = detect_envelopes(x, mu, passes=2)
    np.testing.assert_array_equal(env.upper_x, x)  # empty upper set: keep the whole cloud
    # each pass drops its first point (no predecessor, no slope): two passes drop two
    np.testing.assert_array_equal(env.lower_x, x[2:])


def test_eda_envelopes_on_noisy_gaussian_cloud():
    rng = np.random.default_rng(0)
    x = rng.uniform(-3, 3, 1500)
    mu = np.exp(-(x**2) / 2) * rng.uniform(0.4, 1.0, x.size)
    grid = np.linspace(-2.5, 2.5, 200)
    gaps = []
    for passes in (1, 2):
        env = detect_envelopes(x, mu, passes=passes)
        points = set(zip(x.tolist(), mu.tolist(), strict=True))
        assert set(zip(env.upper_x.tolist(), env.upper_mu.tolist(), strict=True)) <= points
        assert set(zip(env.lower_x.tolist(), env.lower_mu.tolist(), strict=True)) <= points
        assert np.all(np.diff(env.upper_x) >= 0) and np.all(np.diff(env.lower_x) >= 0)
        up = np.interp(grid, env.upper_x, env.upper_mu)
        lo = np.interp(grid, env.lower_x, env.lower_mu)
        assert np.mean(up >= lo) > 0.97
        gaps.append(np.mean(up - lo))
    assert gaps[1] > gaps[0] > 0.05  # the second pass separates the envelopes further


def test_eda_rejects_bad_input():
    with pytest.raises(ValueError, match="differ in length"):
        detect_envelopes(np.arange(5.0), np.ones(4))
    with pytest.raises(ValueError, match="NaN"):
        detect_envelopes(np.array([0, 1, 2, np.nan]), np.ones(4))
    with pytest.raises(ValueError, match="passes"):
        detect_envelopes(np.arange(5.0), np.ones(5), passes=0)


# ---------------------------------------------------------------- Gaussian fit and repair


def test_fit_gaussian_recovers_parameters():
    x = np.linspace(-4, 6, 300)
    g = fit_gaussian(x, 0.8 * np.exp(-((x - 1.2) ** 2) / (2 * 0.7**2)))
    assert g.h == pytest.approx(0.8, abs=1e-8)
    assert g.c == pytest.approx(1.2, abs=1e-8)
    assert g.s == pytest.approx(0.7, abs=1e-8)


def test_fit_gaussian_respects_bounds():
    x = np.linspace(-1, 1, 50)
    g = fit_gaussian(x, 1.5 * np.exp(-(x**2) / 0.5))  # taller than 1: h capped
    assert 0 < g.h <= 1.0 and g.s >= 0.01 * 2.0
    spike = np.where(np.arange(50) == 25, 1.0, 0.0)  # a single-point spike: sigma floored
    assert fit_gaussian(x, spike).s >= 0.01 * 2.0 * (1 - 1e-12)
    with pytest.raises(ValueError, match="all x are equal"):
        fit_gaussian(np.ones(5), np.ones(5))


@pytest.mark.parametrize(
    ("lower", "upper"),
    [
        (Gaussian(0.5, 0.0, 2.0), Gaussian(0.9, 0.0, 1.0)),  # s_l > s_u
        (Gaussian(0.6, 1.5, 0.8), Gaussian(0.9, 0.0, 1.0)),  # shifted centres
        (Gaussian(0.95, 0.0, 0.5), Gaussian(0.7, 0.0, 1.0)),  # h_l > h_u
        (Gaussian(0.5, 0.3, 1.0), Gaussian(0.9, 0.0, 1.0)),  # equal sigma, shifted
        (Gaussian(0.9, 4.0, 3.0), Gaussian(0.6, -1.0, 0.5)),  # everything wrong at once
        (Gaussian(0.5, 80.0, 0.999), Gaussian(0.9, 0.0, 1.0)),  # would underflow
    ],
)
def test_repair_fixes_crafted_crossings(lower, upper):
    assert not interval_holds(lower, upper)
    assert not grid_check(lower, upper) or max_log_ratio(lower, upper) > 0
    lo, up = repair_interval(lower, upper)
    assert interval_holds(lo, up)
    assert grid_check(lo, up)
    assert lo.h > 0.0 and up == upper


def test_repair_leaves_valid_pairs_alone():
    lower, upper = Gaussian(0.4, 0.1, 0.6), Gaussian(0.9, 0.0, 1.0)
    assert interval_holds(lower, upper)
    assert repair_interval(lower, upper) == (lower, upper)


def test_repair_property_random_pairs():
    rng = np.random.default_rng(42)
    for _ in range(2000):
        upper = Gaussian(rng.uniform(1e-3, 1.0), rng.normal(0, 3), rng.uniform(0.05, 5))
        lower = Gaussian(rng.uniform(0.0, 1.0), rng.normal(0, 3), rng.uniform(0.05, 5))
        lo, up = repair_interval(lower, upper)
        assert interval_holds(lo, up), (lower, upper, lo, up)
        assert grid_check(lo, up), (lower, upper, lo, up)
        if interval_holds(lower, upper):
            assert (lo, up) == (lower, upper)


# ---------------------------------------------------------------- regressors


def test_numba_regressors_equal_numpy_batches():
    rng = np.random.default_rng(3)
    lower, upper = random_interval_mfs(rng, 4, 3)
    mfs = random_mfs(rng, 4, 3)
    x = rng.normal(0, 2, (50, 3))
    batch_it2 = it2_regressor_matrix(x, lower, upper)
    batch_t1 = t1_regressor_matrix(x, mfs)
    assert batch_it2.shape == (50, 2 * 4 * 4) and batch_t1.shape == (50, 4 * 4)
    for k in range(50):
        np.testing.assert_allclose(it2_regressor(x[k], lower, upper), batch_it2[k], atol=1e-14)
        np.testing.assert_allclose(t1_regressor(x[k], mfs), batch_t1[k], atol=1e-14)


def test_it2_regressor_layout():
    """phi = 1/2 [xi_l (x) [x;1] ; xi_r (x) [x;1]] with xi the normalised product firing."""
    rng = np.random.default_rng(4)
    lower, upper = random_interval_mfs(rng, 3, 2)
    x = np.array([0.3, -0.7])

    def xi(mfs):
        f = np.prod(mfs[..., 0] * np.exp(-((x - mfs[..., 1]) ** 2) / (2 * mfs[..., 2] ** 2)), 1)
        return f / f.sum()

    xa = np.append(x, 1.0)
    expected = 0.5 * np.concatenate([np.kron(xi(lower), xa), np.kron(xi(upper), xa)])
    np.testing.assert_allclose(it2_regressor(x, lower, upper), expected, rtol=1e-12)


@pytest.mark.parametrize("far", [1e6, -1e6])
def test_regressor_weights_finite_far_outside(far):
    rng = np.random.default_rng(5)
    lower, upper = random_interval_mfs(rng, 5, 3)
    for x in (np.full(3, far), np.array([far, -far, 0.0])):
        xi = normalised_firing(x, lower)
        assert np.all(np.isfinite(xi)) and xi.sum() == pytest.approx(1.0)
        phi = it2_regressor(x, lower, upper)
        assert np.all(np.isfinite(phi))
        ones = phi.reshape(2, 5, 4)[:, :, 3]  # the [x;1] constant slots carry xi / 2
        np.testing.assert_allclose(ones.sum(axis=1), [0.5, 0.5])
        phi_t1 = t1_regressor(x, upper)
        assert np.all(np.isfinite(phi_t1))
        assert phi_t1.reshape(5, 4)[:, 3].sum() == pytest.approx(1.0)
        np.testing.assert_allclose(normalised_firing_batch(x[None], lower)[0], xi)


# ---------------------------------------------------------------- least squares


def it2_null_space(c: int, n: int) -> np.ndarray:
    """The n + 1 directions that no IT2 prediction sees: +v on every w_l,i, -v on every w_r,i."""
    basis = np.zeros((2 * c * (n + 1), n + 1))
    for k in range(n + 1):
        for i in range(c):
            basis[i * (n + 1) + k, k] = 1.0
            basis[c * (n + 1) + i * (n + 1) + k, k] = -1.0
    return basis


def min_norm_representative(theta: np.ndarray, null: np.ndarray) -> np.ndarray:
    return theta - null @ np.linalg.solve(null.T @ null, null.T @ theta)


def ridge_bias_bound(phi: np.ndarray, theta: np.ndarray, ridge: float = 1e-8) -> float:
    """Ridge theory: |theta_ridge - theta| <= lam / (s_min^2 + lam) |theta| for theta in the
    row space, with lam = ridge N and s_min the smallest non-zero singular value of the
    scaled regressor (fit_consequents scales the fuzzy block by its RMS)."""
    a = phi / np.sqrt(np.mean(phi**2))
    sv = np.linalg.svd(a, compute_uv=False)
    s_min = sv[sv > 1e-10 * sv[0]].min()
    lam = ridge * phi.shape[0]
    return lam / (s_min**2 + lam) * np.linalg.norm(theta)


def test_least_squares_recovers_t1_consequents():
    rng = np.random.default_rng(6)
    x = rng.uniform(-2, 2, (600, 2))
    mfs = random_mfs(rng, 3, 2)
    theta = rng.normal(size=3 * 3)
    phi = t1_regressor_matrix(x, mfs)
    np.testing.assert_allclose(fit_consequents(phi, phi @ theta, ridge=0.0), theta, atol=1e-10)
    bias = np.linalg.norm(fit_consequents(phi, phi @ theta) - theta)
    assert bias <= ridge_bias_bound(phi, theta) * (1 + 1e-6)


def test_least_squares_recovers_it2_consequents_up_to_their_null_space():
    rng = np.random.default_rng(6)
    x = rng.uniform(-2, 2, (600, 2))
    lower, upper = random_interval_mfs(rng, 3, 2)
    theta = rng.normal(size=2 * 3 * 3)
    phi = it2_regressor_matrix(x, lower, upper)
    null = it2_null_space(3, 2)
    assert np.abs(phi @ null).max() < 1e-14  # the rank deficiency is exact
    assert np.linalg.matrix_rank(phi) == phi.shape[1] - 3
    y = phi @ theta
    expected = min_norm_representative(theta, null)
    np.testing.assert_allclose(fit_consequents(phi, y, ridge=0.0), expected, atol=1e-8)
    # the default tiny ridge: the same solution within the ridge's bias bound
    est = fit_consequents(phi, y)
    assert np.linalg.norm(est - expected) <= ridge_bias_bound(phi, expected) * (1 + 1e-6)
    assert np.sqrt(np.mean((phi @ est - y) ** 2)) < 1e-6 * np.std(y)


def test_least_squares_recovers_g_with_input_column():
    rng = np.random.default_rng(7)
    x = rng.uniform(-2, 2, (800, 3))
    lower, upper = random_interval_mfs(rng, 3, 3)
    theta = rng.normal(size=2 * 3 * 4)
    u = rng.normal(0, 0.02, 800)  # a small input in its own units: the penalty must not care
    phi = it2_regressor_matrix(x, lower, upper)
    y = phi @ theta + 1.2778 * u
    est = fit_consequents(phi, y, ridge=0.0, extra_columns=u)
    expected = min_norm_representative(theta, it2_null_space(3, 3))
    np.testing.assert_allclose(est[:-1], expected, atol=1e-8)
    assert est[-1] == pytest.approx(1.2778, abs=1e-8)
    est_ridge = fit_consequents(phi, y, extra_columns=u)
    assert est_ridge[-1] == pytest.approx(1.2778, rel=1e-5)


def test_least_squares_ridge_tames_dead_columns():
    rng = np.random.default_rng(8)
    phi = rng.normal(size=(500, 3))
    phi[:, 2] *= 1e-9  # a rule that (almost) never fires in the data
    y = phi[:, 0] - phi[:, 1] + 1e-3 * rng.normal(size=500)
    assert abs(fit_consequents(phi, y, ridge=0.0)[2]) > 1e3
    assert abs(fit_consequents(phi, y, ridge=1e-8)[2]) < 1.0


# ---------------------------------------------------------------- identification


@pytest.fixture(scope="module")
def bilinear_model():
    x, f, y = bilinear_data(seed=0)
    half = 2000
    model = identify_channel(x[:half], y[:half], x[half:], y[half:], ("a", "b", "w"), seed=0)
    return model, x, f, y


def test_ivfm_and_t1fm_fit_bilinear_function(bilinear_model):
    model, x, f, y = bilinear_model
    spread = np.std(y[2000:])
    assert model.rmse_valid_ivfm < 0.5 * spread
    assert model.rmse_valid_t1fm < 0.5 * spread
    for fitted in (model.ivfm.predict_f(x[2000:]), model.t1fm.predict_f(x[2000:])):
        assert np.sqrt(np.mean((fitted - f[2000:]) ** 2)) < 0.4 * np.std(f[2000:])
    lower, upper = model.ivfm.lower, model.ivfm.upper
    for i in range(model.n_clusters):
        for j in range(3):
            assert interval_holds(Gaussian(*lower[i, j]), Gaussian(*upper[i, j]))
    assert model.output == "f" and model.g is None
    assert model.cluster_centers.shape == (model.n_clusters, 4)
    np.testing.assert_allclose(model.ivfm.input_ranges[:, 0], x[:2000].min(axis=0))


def test_identification_is_deterministic(bilinear_model):
    model, x, _, y = bilinear_model
    again = identify_channel(x[:2000], y[:2000], x[2000:], y[2000:], ("a", "b", "w"), seed=0)
    assert np.array_equal(again.ivfm.theta_f, model.ivfm.theta_f)
    assert np.array_equal(again.t1fm.mfs, model.t1fm.mfs)


def test_joint_fit_of_f_and_g_from_acceleration():
    rng = np.random.default_rng(11)
    x, f, _ = bilinear_data(seed=1, noise=0.0)
    u = smooth_signal(rng, x.shape[0], 1.5, fmax_hz=2.0)
    acc = f + 1.2778 * u
    acc = acc + 0.05 * np.ptp(acc) / 2 * rng.normal(size=acc.size)
    m = identify_channel(
        x[:2000],
        acc[:2000],
        x[2000:],
        acc[2000:],
        ("a", "b", "w"),
        u_ident=u[:2000],
        u_valid=u[2000:],
    )
    assert m.output == "acc"
    assert m.ivfm.g == pytest.approx(1.2778, rel=0.03)
    assert m.t1fm.g == pytest.approx(1.2778, rel=0.03)
    assert m.rmse_valid_ivfm < 0.5 * np.std(acc[2000:])


def test_constant_output_gives_valid_model():
    rng = np.random.default_rng(12)
    x = np.column_stack([smooth_signal(rng, 1000, 2.0), smooth_signal(rng, 1000, 2.0)])
    zero = np.zeros(1000)
    m = identify_channel(x[:500], zero[:500], x[500:], zero[500:], ("p", "q"))
    assert any("constant" in note for note in m.notes)
    for value in (m.rmse_ident_ivfm, m.rmse_valid_ivfm, m.rmse_ident_t1fm, m.rmse_valid_t1fm):
        assert value == 0.0
    assert np.all(np.isfinite(m.ivfm.lower)) and np.all(np.isfinite(m.cluster_centers))
    assert np.all(m.ivfm.predict_f(rng.normal(0, 5, (20, 2))) == 0.0)


def test_identify_channel_rejects_bad_input():
    x, _, y = bilinear_data(seed=0, n=400)
    with pytest.raises(ValueError, match="constant"):
        xc = x.copy()
        xc[:, 1] = 1.0
        identify_channel(xc[:200], y[:200], xc[200:], y[200:], ("a", "b", "w"))
    with pytest.raises(ValueError, match="NaN"):
        yb = y.copy()
        yb[3] = np.nan
        identify_channel(x[:200], yb[:200], x[200:], yb[200:], ("a", "b", "w"))
    with pytest.raises(ValueError, match="too few"):
        identify_channel(x[:30], y[:30], x[200:], y[200:], ("a", "b", "w"))


# ---------------------------------------------------------------- dataset and model file


def synthetic_dataset(n: int = 1200, seed: int = 0, with_f: bool = True) -> Dataset:
    """Paper-like data: f from section 3 (Ixx = Iyy, so f_psi = 0), acc = f + g U."""
    rng = np.random.default_rng(seed)
    a1, a2, a3, a4, a5 = 0.5, 1.32e-3 / 0.18, -0.5, 1.32e-3 / 0.18, 0.0
    b1 = b2 = 0.23 / 0.18
    b3 = 1 / 0.09
    cols = {"time_s": np.arange(n) * 0.01}
    for name in ("phi_rad", "theta_rad", "psi_rad"):
        cols[name] = smooth_signal(rng, n, 0.5)
    p, q, r = (smooth_signal(rng, n, 2.0) for _ in range(3))
    w_r = smooth_signal(rng, n, 40.0)
    cols |= {"phi_rate_rad_s": p, "theta_rate_rad_s": q, "psi_rate_rad_s": r, "w_r_rad_s": w_r}
    u = {k: smooth_signal(rng, n, 1.0, fmax_hz=2.0) for k in ("u_phi_n", "u_theta_n", "u_psi_nm")}
    cols |= u
    f_phi = a1 * q * r - a2 * q * w_r
    f_theta = a3 * p * r + a4 * p * w_r
    f_psi = a5 * p * q
    cols["phi_acc_rad_s2"] = f_phi + b1 * u["u_phi_n"]
    cols["theta_acc_rad_s2"] = f_theta + b2 * u["u_theta_n"]
    cols["psi_acc_rad_s2"] = f_psi + b3 * u["u_psi_nm"]
    if with_f:
        cols |= {"f_phi": f_phi, "f_theta": f_theta, "f_psi": f_psi}
    return Dataset(columns=cols, source="synthetic")


def test_dataset_round_trip_is_exact(tmp_path: Path):
    ds = synthetic_dataset(n=200)
    path = tmp_path / "data.csv"
    write_dataset(path, ds)
    back = read_dataset(path)
    assert list(back.columns) == list(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)
    for name, values in ds.columns.items():
        assert np.array_equal(back.column(name), values), name
    assert os.listdir(tmp_path) == ["data.csv"]


def test_identify_dataset_and_model_round_trip(tmp_path: Path):
    ds = synthetic_dataset()
    models = identify_dataset(ds, split=0.5, n_clusters=3, metadata={"note": "test"})
    assert set(models.channels) == {"phi", "theta", "psi"}
    phi = models.channels["phi"]
    # g = least squares of (acc - f^(x)) on U over the identification half
    x = ds.matrix(CHANNEL_REGRESSORS["phi"])[:600]
    u = ds.column("u_phi_n")[:600]
    residual = ds.column("phi_acc_rad_s2")[:600] - phi.ivfm.predict_f(x)
    assert phi.g == pytest.approx(np.dot(u, residual) / np.dot(u, u), rel=1e-12)
    # f^'s error leaks into g where it correlates with U: a few % with 600 samples
    assert phi.g == pytest.approx(0.23 / 0.18, rel=0.05)
    assert phi.ivfm.regressor_names == CHANNEL_REGRESSORS["phi"]
    psi = models.channels["psi"]
    assert any("constant" in note for note in psi.notes)  # Ixx = Iyy: f_psi = 0
    assert psi.g == pytest.approx(1 / 0.09, rel=1e-9)
    assert models.metadata["note"] == "test" and models.metadata["seed"] == 0

    path = tmp_path / "model.json"
    save_model(path, models)
    back = load_model(path)
    assert model_set_to_dict(back) == model_set_to_dict(models)
    for name, ch in models.channels.items():
        other = back.channels[name]
        assert np.array_equal(other.ivfm.lower, ch.ivfm.lower)
        assert np.array_equal(other.ivfm.theta_f, ch.ivfm.theta_f)
        assert np.array_equal(other.t1fm.mfs, ch.t1fm.mfs)
        assert other.rmse_valid_ivfm == ch.rmse_valid_ivfm and other.g == ch.g
    assert os.listdir(tmp_path) == ["model.json"]


def test_identify_dataset_without_f_fits_f_and_g_together():
    ds = synthetic_dataset(n=4000, with_f=False)  # the paper's size: 2000 + 2000 samples
    models = identify_dataset(ds, channels=("phi",))
    phi = models.channels["phi"]
    assert phi.output == "acc" and set(models.channels) == {"phi"}
    # within 3 % over the data sets tried while choosing the defaults
    assert phi.ivfm.g == pytest.approx(0.23 / 0.18, rel=0.05)
    assert phi.t1fm.g == pytest.approx(0.23 / 0.18, rel=0.05)
    assert phi.rmse_valid_ivfm < 0.5 * np.std(ds.column("phi_acc_rad_s2")[2000:])


CSV_HEADER = ",".join(REQUIRED_COLUMNS)


def _csv_rows(n: int = 12) -> list[list[str]]:
    return [[str(k * 0.01)] + ["0.5"] * (len(REQUIRED_COLUMNS) - 1) for k in range(n)]


def _write_csv(path: Path, header: str, rows: list[list[str]]) -> None:
    path.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")


def _mutate(rows, row, col, text):
    rows[row][col] = text
    return rows


@pytest.mark.parametrize(
    ("header", "rows", "fragments"),
    [
        (CSV_HEADER.replace(",w_r_rad_s", ""), [r[:-1] for r in _csv_rows()], ["w_r_rad_s"]),
        (CSV_HEADER + ",extra", [r + ["1"] for r in _csv_rows()], ["unknown", "extra"]),
        (CSV_HEADER + ",phi_rad", [r + ["1"] for r in _csv_rows()], ["duplicate", "phi_rad"]),
        (CSV_HEADER, _mutate(_csv_rows(), 4, 2, "abc"), ["line 6", "theta_rad", "abc"]),
        (CSV_HEADER, _mutate(_csv_rows(), 3, 5, "nan"), ["line 5", "theta_rate_rad_s"]),
        (CSV_HEADER, _mutate(_csv_rows(), 7, 1, "inf"), ["line 9", "phi_rad"]),
        (CSV_HEADER, _mutate(_csv_rows(), 6, 0, "0.01"), ["line 8", "time_s"]),
        (CSV_HEADER, _mutate(_csv_rows(), 2, 3, ""), ["line 4", "psi_rad"]),
        (CSV_HEADER, _csv_rows(5), ["too few rows"]),
        (CSV_HEADER, _csv_rows()[:6] + [_csv_rows()[6][:-1]] + _csv_rows()[7:], ["line 8"]),
        ("", [], ["empty"]),
    ],
)
def test_malformed_dataset_is_refused(tmp_path: Path, header, rows, fragments):
    src = tmp_path / "bad.csv"
    if header:
        _write_csv(src, header, rows)
    else:
        src.write_text("")
    out = tmp_path / "model.json"
    with pytest.raises(DatasetError) as info:
        save_model(out, identify_dataset(read_dataset(src)))
    for fragment in fragments:
        assert fragment in str(info.value)
    assert "bad.csv" in str(info.value)
    assert sorted(os.listdir(tmp_path)) == ["bad.csv"]


def test_write_dataset_refuses_corrupted_dataset(tmp_path: Path):
    ds = synthetic_dataset(n=50)
    ds.columns["u_phi_n"][10] = np.inf  # mutated after validation
    with pytest.raises(DatasetError, match="u_phi_n"):
        write_dataset(tmp_path / "out.csv", ds)
    assert os.listdir(tmp_path) == []
    with pytest.raises(DatasetError, match="unknown column 'bogus'"):
        Dataset(columns={**synthetic_dataset(n=50).columns, "bogus": np.zeros(50)})


@pytest.fixture(scope="module")
def model_document():
    models = identify_dataset(synthetic_dataset(n=600), n_clusters=2)
    return model_set_to_dict(models)


def _set(doc, path, value):
    node = doc
    for key in path[:-1]:
        node = node[key]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "fragment"),
    [
        (("format",), "something-else", "format"),
        (("version",), 2, "version"),
        (("channels", "yaw"), {}, "channels.yaw: unknown channel"),
        (("channels", "phi", "ivfm", "lower"), [[[0.5, 0.0, 1.0]]], "channels.phi.ivfm.lower"),
        (("channels", "phi", "ivfm", "theta_f", 3), float("nan"), "channels.phi.ivfm.theta_f"),
        (("channels", "phi", "t1fm", "theta_f", 0), float("inf"), "channels.phi.t1fm.theta_f"),
        (("channels", "theta", "ivfm", "upper", 0, 1, 2), 0.0, "ivfm.upper[0][1]: sigma"),
        (("channels", "theta", "t1fm", "mfs", 1, 0, 2), -1.0, "t1fm.mfs[1][0]: sigma"),
        (("channels", "phi", "ivfm", "upper", 1, 2, 0), 1.5, "ivfm.upper[1][2]: height"),
        (("channels", "phi", "ivfm", "lower", 0, 0, 0), 1.0, "ivfm.lower[0][0]: lower MF"),
        (("channels", "phi", "ivfm", "g"), "big", "channels.phi.ivfm.g"),
        (("channels", "phi", "ivfm", "rmse_valid"), -1.0, "channels.phi.ivfm.rmse_valid"),
        (("channels", "phi", "n_clusters"), True, "channels.phi.n_clusters"),
        (("channels", "phi", "regressors"), ["a", "b", "c"], "channels.phi.regressors"),
        (("channels", "phi", "input_ranges", 0), [1.0, -1.0], "channels.phi.input_ranges"),
        (("channels", "phi", "output"), "x", "channels.phi.output"),
        (("channels", "phi", "surprise"), 1, "channels.phi.surprise: unknown field"),
        (("channels", "psi", "t1fm", "theta_f"), _DELETE, "channels.psi.t1fm.theta_f: missing"),
        (("channels",), {}, "channels"),
    ],
)
def test_malformed_model_file_is_refused(tmp_path: Path, model_document, path, value, fragment):
    doc = _set(json.loads(json.dumps(model_document)), path, value)
    src = tmp_path / "bad.json"
    src.write_text(json.dumps(doc))  # json writes NaN / Infinity tokens, as a bad tool might
    with pytest.raises(ModelFileError) as info:
        load_model(src)
    assert fragment in str(info.value)
    assert "bad.json" in str(info.value)


def test_unreadable_model_files_are_refused(tmp_path: Path):
    (tmp_path / "broken.json").write_text("{ not json")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        load_model(tmp_path / "broken.json")
    with pytest.raises(ModelFileError, match="cannot read"):
        load_model(tmp_path / "missing.json")


def test_invalid_model_is_never_written(tmp_path: Path, model_document):
    good = tmp_path / "model.json"
    good.write_text(json.dumps(model_document))
    before = good.read_bytes()
    models = load_model(good)
    ch = models.channels["phi"]
    bad_lower = ch.ivfm.lower.copy()
    bad_lower[0, 0, 0] = 1.0  # lower height above the upper MF
    bad_upper = ch.ivfm.upper.copy()
    bad_upper[0, 0, 0] = min(bad_upper[0, 0, 0], 0.5)
    import dataclasses

    broken = dataclasses.replace(ch.ivfm, lower=bad_lower, upper=bad_upper)
    models.channels["phi"] = dataclasses.replace(ch, ivfm=broken)
    with pytest.raises(ModelFileError, match="channels.phi.ivfm.lower"):
        save_model(good, models)
    assert good.read_bytes() == before
    models.channels["phi"] = ch
    models.metadata["bad"] = float("nan")
    with pytest.raises(ModelFileError, match="metadata"):
        save_model(tmp_path / "other.json", models)
    assert sorted(os.listdir(tmp_path)) == ["model.json"]
