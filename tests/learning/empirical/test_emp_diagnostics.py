"""MLR flags autocorrelated residuals (and recomputes p-values on the effective sample size) and cancelling
coefficients; the figures are checked against formulas written here, not against the module's code."""
import numpy as np
import pytest
from scipy import stats

from host.learning.empirical.regression import MLR


def _ar1(n, rho, rng):
    e = np.empty(n)
    e[0] = rng.normal()
    for i in range(1, n):
        e[i] = rho * e[i - 1] + np.sqrt(1 - rho ** 2) * rng.normal()
    return e


def test_autocorrelated_residuals_are_flagged_and_p_values_recomputed():
    rng = np.random.default_rng(1)
    n = 2000
    X = np.column_stack([np.linspace(0, 10, n) + rng.normal(0, 1, n), rng.normal(0, 1, n)])
    y = 0.5 * X[:, 0] + 0.02 * X[:, 1] + 0.5 * _ar1(n, 0.95, rng)
    m = MLR().fit(X, y, ["T1", "T2"])
    st = m.statistics()
    r = y - m.predict(X)
    dw = np.sum(np.diff(r) ** 2) / np.sum(r ** 2)
    rho = np.sum(r[1:] * r[:-1]) / np.sum(r ** 2)
    n_eff = n * (1 - rho) / (1 + rho)
    a = st["autocorrelation"]
    assert a["durbin_watson"] == pytest.approx(dw, rel=1e-9) and a["autocorrelated"] is True
    assert a["n_effective"] == pytest.approx(n_eff, rel=1e-9) and n_eff < n / 10
    t2 = st["coefficients"]["T2"]["t"]
    assert st["coefficients"]["T2"]["p_effective"] == pytest.approx(2 * stats.t.sf(abs(t2) * np.sqrt(n_eff / n), n_eff - 3), rel=1e-6)
    assert st["coefficients"]["T2"]["p_effective"] > st["coefficients"]["T2"]["p"]
    assert "autocorrelated" in m.summary()


def test_independent_residuals_are_not_flagged():
    rng = np.random.default_rng(2)
    X = rng.normal(0, 1, (500, 2))
    y = X @ [1.0, -0.5] + rng.normal(0, 0.1, 500)
    st = MLR().fit(X, y, ["T1", "T2"]).statistics()
    assert st["autocorrelation"]["autocorrelated"] is False and st["cancelling"]["pairs"] == []


def test_cancelling_coefficients_are_flagged():
    rng = np.random.default_rng(3)
    n = 400
    s = np.linspace(0, 5, n)
    u = rng.normal(0, 1, n)
    x1, x2, x3 = s, s + 0.01 * u, rng.normal(0, 1, n)
    y = s + 5.0 * (x2 - x1) + 0.1 * x3 + rng.normal(0, 0.001, n)  # = -4 x1 + 5 x2 + 0.1 x3
    m = MLR().fit(np.column_stack([x1, x2, x3]), y, ["T1", "T2", "T3"])
    (pair,) = m.statistics()["cancelling"]["pairs"]
    assert pair["sensors"] == ["T1", "T2"]
    assert pair["coefficients"] == pytest.approx([-4.0, 5.0], abs=0.05)
    t1, t2 = -4.0 * x1, 5.0 * x2
    assert pair["sum_std"] == pytest.approx(np.std(t1 + t2), rel=0.05) and pair["sum_std"] < 0.5 * np.std(t1)
    assert "cancel" in m.summary()
