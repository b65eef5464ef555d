import numpy as np
import pytest
from scipy import stats as st

from host.learning.discrepancy import stats
from host.learning.discrepancy.localize import eta_squared, localize


def test_sweep_losses_group_by_time():
    t = np.array([0, 0, 0, 10, 10, 20.0])
    r = np.array([1, 1, 1, 2, 0, np.nan])
    np.testing.assert_allclose(stats.sweep_losses(r, t), [1.0, 2.0])


def test_long_run_variance_white_noise_equals_variance():
    x = np.random.default_rng(1).normal(size=4000)
    assert stats.long_run_variance([x], lag=0) == pytest.approx(np.var(x), rel=1e-12)
    # for white noise the Bartlett-weighted estimate stays close to the variance
    assert stats.long_run_variance([x]) == pytest.approx(np.var(x), rel=0.1)


def test_long_run_variance_ar1_inflates():
    rng = np.random.default_rng(2)
    e = rng.normal(size=20000)
    x = np.empty_like(e)
    x[0] = e[0]
    for i in range(1, e.size):
        x[i] = 0.6 * x[i - 1] + e[i]
    # true long-run variance of AR(1): s2 / (1 - phi)^2 = 6.25; Bartlett with a long lag gets near it
    assert stats.long_run_variance([x], lag=60) == pytest.approx(6.25, rel=0.15)


def test_dm_matches_paired_t_without_autocorrelation():
    rng = np.random.default_rng(3)
    a = rng.gamma(2, 1, 50)
    b = a - 0.3 + rng.normal(0, 0.5, 50)
    out = stats.dm_test([a], [b], lag=0)
    d = a - b
    # with lag 0 the DM statistic is the paired t statistic with population variance, HLN-scaled
    t_ref = d.mean() / np.sqrt(np.var(d) / d.size) * np.sqrt((d.size - 1) / d.size)
    assert out["statistic"] == pytest.approx(t_ref)
    assert out["p_value"] == pytest.approx(st.t.sf(t_ref, d.size - 1))


def test_dm_null_is_calibrated_under_autocorrelation():
    """Under H0 with AR(1) loss differentials, rejections at 5 % stay near 5 % (not the ~25 % of a naive t)."""
    rng = np.random.default_rng(4)
    rej = naive = 0
    trials = 400
    for _ in range(trials):
        groups = []
        for _run in range(3):
            e = rng.normal(size=40)
            x = np.empty(40)
            x[0] = e[0]
            for i in range(1, 40):
                x[i] = 0.5 * x[i - 1] + e[i]
            groups.append(x)
        out = stats.dm_test(groups, [np.zeros(40)] * 3)
        rej += out["p_value"] < 0.05
        naive += stats.dm_test(groups, [np.zeros(40)] * 3, lag=0)["p_value"] < 0.05
    assert rej / trials < 0.10
    assert naive > rej


def test_dm_detects_real_improvement():
    rng = np.random.default_rng(5)
    base = [rng.gamma(2, 2, 30) + 3 for _ in range(3)]
    cand = [b - 2.5 + rng.normal(0, 0.5, 30) for b in base]
    assert stats.dm_test(base, cand)["p_value"] < 1e-6
    assert stats.dm_test(cand, base)["p_value"] > 0.99


def test_holm():
    np.testing.assert_allclose(stats.holm_adjust([0.01, 0.04, 0.03, 0.5]), [0.04, 0.09, 0.09, 0.5])


def test_eta_squared_exact():
    v = np.array([1.0, 1.0, -1.0, -1.0])
    share, groups = eta_squared(v, np.array(["a", "a", "b", "b"]))
    assert share == pytest.approx(1.0)
    assert {g["level"]: g["mean_um"] for g in groups} == {"a": 1.0, "b": -1.0}
    share, _ = eta_squared(v, np.array(["a", "b", "a", "b"]))
    assert share == pytest.approx(0.0)


def test_localization_points_at_direction_and_position(make):
    run = make(7, "loc", noise_um=0.1)
    e = run.errors
    loc = {d["factor"]: d for d in localize([run], [2.0 * e.direction])}
    assert loc["direction"]["share"] == pytest.approx(1.0)
    assert loc["zone"]["share"] < 0.05
    loc = localize([run], [0.02 * e.position_mm + np.random.default_rng(0).normal(0, 0.1, len(e))])
    assert loc[0]["factor"] == "slope_in_position"
    byname = {d["factor"]: d for d in loc}
    assert byname["zone"]["worst"] == "far"
