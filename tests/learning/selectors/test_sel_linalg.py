"""Batched subset least squares against per-combination np.linalg.lstsq; OLS statistics."""
import itertools

import numpy as np
import pytest
from scipy import stats

from host.learning.empirical.selectors.hclust_ga import combinations
from host.learning.empirical.selectors.linalg import SubsetFitter, ols_stats, subset_rmse


def _data(seed, n=50, p=7):
    rng = np.random.default_rng(seed)
    base = 25.0 + np.cumsum(rng.normal(size=(n, 3)), axis=0)  # °C-like levels and collinearity
    X = base @ rng.uniform(0.2, 1.0, (3, p)) / 2 + 0.05 * rng.normal(size=(n, p))
    y = X[:, 0] * 1.5 - X[:, -1] + rng.normal(scale=0.1, size=n)
    return X, y


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_batched_fit_equals_lstsq_per_combination(seed, k):
    X, y = _data(seed)
    combos = np.array(list(itertools.combinations(range(X.shape[1]), k)))
    b0, b = SubsetFitter(X, y).fit(combos)
    Xt, yt = _data(seed + 100)
    rmse = subset_rmse(b0, b, combos, Xt, yt)
    for i, c in enumerate(combos):
        A = np.column_stack([np.ones(len(y)), X[:, c]])
        ref = np.linalg.lstsq(A, y, rcond=None)[0]
        np.testing.assert_allclose(b0[i], ref[0], rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(b[i], ref[1:], rtol=1e-7, atol=1e-9)
        pred = ref[0] + Xt[:, c] @ ref[1:]
        assert rmse[i] == pytest.approx(np.sqrt(np.mean((pred - yt) ** 2)), rel=1e-8)


def test_cross_product_rmse_equals_direct_residuals_on_a_long_run():
    X, y = _data(5, n=4000)
    combos = np.array(list(itertools.product(range(3), range(3, 7))))
    b0, b = SubsetFitter(X[:200], y[:200]).fit(combos)
    Xd = X + np.random.default_rng(0).uniform(-0.5, 0.5, X.shape)
    direct = np.sqrt(((b0[:, None] + np.einsum("nmk,mk->mn", Xd[:, combos], b) - y[None, :]) ** 2).mean(axis=1))
    np.testing.assert_allclose(subset_rmse(b0, b, combos, Xd, y), direct, rtol=1e-9)


def test_exactly_collinear_subset_gets_the_minimum_norm_solution():
    X, y = _data(1)
    X = np.column_stack([X, 2.0 * X[:, 1] + 3.0])  # column 7 = affine copy of column 1
    combos = np.array([[1, 7], [0, 2]])
    b0, b = SubsetFitter(X, y).fit(combos)
    assert np.all(np.isfinite(b)) and np.all(np.isfinite(b0))
    # the collinear pair still predicts like the single sensor
    ref = np.linalg.lstsq(np.column_stack([np.ones(len(y)), X[:, 1]]), y, rcond=None)[0]
    np.testing.assert_allclose(b0[0] + X[:, [1, 7]] @ b[0], ref[0] + X[:, 1] * ref[1], atol=1e-6)
    ref2 = np.linalg.lstsq(np.column_stack([np.ones(len(y)), X[:, [0, 2]]]), y, rcond=None)[0]
    np.testing.assert_allclose(b[1], ref2[1:], rtol=1e-7)


def test_ols_stats_textbook():
    X, y = _data(2, n=30, p=3)
    st = ols_stats(X, y)
    n, k = X.shape
    A = np.column_stack([np.ones(n), X])
    beta = np.linalg.solve(A.T @ A, A.T @ y)
    sse = float(((y - A @ beta) ** 2).sum())
    sst = float(((y - y.mean()) ** 2).sum())
    F = ((sst - sse) / k) / (sse / (n - k - 1))
    assert st["r2"] == pytest.approx(1 - sse / sst)
    assert st["adj_r2"] == pytest.approx(1 - (sse / (n - k - 1)) / (sst / (n - 1)))
    assert st["F"] == pytest.approx(F)
    assert st["p_F"] == pytest.approx(stats.f.sf(F, k, n - k - 1))
    np.testing.assert_allclose(st["coefficients"], beta[1:], rtol=1e-8)
    one = ols_stats(X[:, :1], y)
    lr = stats.linregress(X[:, 0], y)
    assert one["r2"] == pytest.approx(lr.rvalue ** 2) and one["p_F"] == pytest.approx(lr.pvalue)


def test_ols_stats_saturated_has_no_f():
    X, y = _data(3, n=4, p=3)
    st = ols_stats(X, y)
    assert st["F"] is None and st["p_F"] is None


def test_combinations_enumerate_one_per_cluster_and_trim():
    clusters = [[0, 1, 2], [3], [4, 5]]
    combos, trimmed = combinations(clusters, np.arange(6.0), 100)
    assert trimmed is None
    assert sorted(map(tuple, combos)) == sorted(itertools.product(*clusters))
    combos, trimmed = combinations(clusters, np.array([0.9, 0.1, 0.5, 1, 0.2, 0.3]), 2)
    assert combos.shape[0] <= 2
    assert trimmed == [[0], [3], [4, 5]] or trimmed == [[0, 2], [3], [5]]
