"""MLR, PCR, stepwise and cv-subset against independent textbook computations."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.regression import MLR, PCR, BestSubsetCV, Stepwise


def _data(n=40, p=4, seed=0, coef=None, noise=0.3):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, p)) * rng.uniform(0.5, 3, p) + rng.uniform(-5, 5, p)
    coef = np.arange(1, p + 1, dtype=float) if coef is None else np.asarray(coef, float)
    y = 1.5 + X @ coef + rng.normal(0, noise, n)
    return X, y


def _textbook(X, y, intercept=True):
    """OLS statistics with the explicit inverse of X'X, as in a statistics textbook."""
    n = len(y)
    A = np.column_stack([np.ones(n), X]) if intercept else X
    k = A.shape[1]
    XtX_inv = np.linalg.inv(A.T @ A)
    b = XtX_inv @ A.T @ y
    e = y - A @ b
    s2 = e @ e / (n - k)
    se = np.sqrt(np.diag(s2 * XtX_inv))
    t = b / se
    p = 2 * (1 - stats.t.cdf(np.abs(t), n - k))
    tss = np.sum((y - y.mean()) ** 2) if intercept else y @ y
    r2 = 1 - (e @ e) / tss
    dfm = k - int(intercept)
    adj = 1 - (1 - r2) * (n - int(intercept)) / (n - k)
    F = (r2 / dfm) / ((1 - r2) / (n - k))
    Fp = 1 - stats.f.cdf(F, dfm, n - k)
    return dict(b=b, se=se, t=t, p=p, r2=r2, adj=adj, F=F, Fp=Fp, rse=np.sqrt(s2))


@pytest.mark.parametrize("intercept", [True, False])
def test_mlr_statistics_equal_textbook(intercept):
    X, y = _data(noise=2.0)
    m = MLR(fit_intercept=intercept).fit(X, y)
    tb = _textbook(X, y, intercept)
    o = int(intercept)
    np.testing.assert_allclose(m.coef_, tb["b"][o:], rtol=1e-9)
    np.testing.assert_allclose(m.bse_, tb["se"][o:], rtol=1e-8)
    np.testing.assert_allclose(m.tvalues_, tb["t"][o:], rtol=1e-8)
    np.testing.assert_allclose(m.pvalues_, tb["p"][o:], atol=1e-12)
    if intercept:
        assert m.intercept_ == pytest.approx(tb["b"][0], rel=1e-9)
        assert m.intercept_bse_ == pytest.approx(tb["se"][0], rel=1e-8)
        assert m.intercept_p_ == pytest.approx(tb["p"][0], abs=1e-12)
    assert m.rsquared_ == pytest.approx(tb["r2"], rel=1e-10)
    assert m.rsquared_adj_ == pytest.approx(tb["adj"], rel=1e-10)
    assert m.fvalue_ == pytest.approx(tb["F"], rel=1e-8)
    assert m.f_pvalue_ == pytest.approx(tb["Fp"], abs=1e-12)
    assert m.resid_std_err_ == pytest.approx(tb["rse"], rel=1e-10)
    s = m.statistics()
    assert s["r2"] == pytest.approx(tb["r2"]) and s["df_resid"] == len(y) - len(tb["b"])
    assert "x1" in m.summary() and "adj R2" in m.summary()


def test_pcr_with_all_components_equals_mlr():
    X, y = _data(p=5, seed=3)
    m = MLR().fit(X, y)
    p = PCR(n_components=5).fit(X, y)
    np.testing.assert_allclose(p.coef_, m.coef_, rtol=1e-8)
    assert p.intercept_ == pytest.approx(m.intercept_, rel=1e-8)
    np.testing.assert_allclose(p.bse_, m.bse_, rtol=1e-7)
    assert p.rsquared_ == pytest.approx(m.rsquared_, rel=1e-10)
    assert p.fvalue_ == pytest.approx(m.fvalue_, rel=1e-8)
    # threshold 1.0 keeps every component as well
    p1 = PCR(variance_threshold=1.0).fit(X, y)
    assert p1.n_components_ == 5
    np.testing.assert_allclose(PCR(n_components=5, fit_intercept=False).fit(X, y).coef_, MLR(fit_intercept=False).fit(X, y).coef_, rtol=1e-8)


@pytest.mark.parametrize("threshold", [0.5, 0.7, 0.85, 0.95, 0.99])
def test_pcr_keeps_the_components_stated(threshold):
    rng = np.random.default_rng(7)
    base = rng.normal(size=(200, 2))
    X = np.column_stack([base[:, 0], base[:, 0] + 0.3 * rng.normal(size=200), base[:, 1], base[:, 1] * 2 + 0.5 * rng.normal(size=200), rng.normal(size=200)])
    y = X @ [1, 2, -1, 0.5, 0.2] + rng.normal(0, 0.1, 200)
    p = PCR(variance_threshold=threshold).fit(X, y)
    w = np.sort(np.linalg.eigvalsh(np.corrcoef(X.T)))[::-1]
    cum = np.cumsum(w) / w.sum()
    expected = int(np.argmax(cum >= threshold) + 1)
    assert p.n_components_ == expected
    np.testing.assert_allclose(p.eigenvalues_, w, rtol=1e-9)
    scree = p.scree()
    assert [s["kept"] for s in scree] == [i < expected for i in range(5)]
    assert scree[expected - 1]["cumulative"] >= threshold > (scree[expected - 2]["cumulative"] if expected > 1 else 0)


def test_pcr_coefficients_map_back_to_raw_temperatures():
    """The exported linear form reproduces the regression on standardised scores."""
    X, y = _data(p=4, seed=11)
    p = PCR(n_components=2).fit(X, y)
    Z = (X - X.mean(0)) / X.std(0, ddof=1)
    w, V = np.linalg.eigh(np.corrcoef(X.T))
    V = V[:, np.argsort(w)[::-1][:2]]
    T = Z @ V
    g, *_ = np.linalg.lstsq(np.column_stack([np.ones(len(y)), T]), y, rcond=None)
    pred_scores = g[0] + T @ g[1:]
    np.testing.assert_allclose(p.predict(X), pred_scores, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p.predict(X), p.intercept_ + X @ p.coef_)


def test_stepwise_finds_exactly_the_relevant_sensors():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(120, 8))
    y = 3.0 * X[:, 1] - 2.0 * X[:, 5] + rng.normal(0, 0.3, 120)
    s = Stepwise().fit(X, y, ["T%d" % i for i in range(8)])
    assert sorted(s.selected_names_) == ["T1", "T5"]
    assert s.support_.sum() == 2 and s.coef_[[0, 2, 3, 4, 6, 7]].tolist() == [0.0] * 6
    # first step's partial F equals the textbook F of the one-variable regression
    j = 1 if s.history_[0]["sensor"] == "T1" else 5
    r = y - np.polyval(np.polyfit(X[:, j], y, 1), X[:, j])
    tss = np.sum((y - y.mean()) ** 2)
    assert s.history_[0]["F"] == pytest.approx((tss - r @ r) / (r @ r / (120 - 2)), rel=1e-9)
    assert s.statistics()["selected"] == s.selected_names_


def test_stepwise_removes_a_sensor_made_redundant():
    """x0 enters first (best alone) and leaves once x1 and x2, which explain it, are in."""
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 300))
    x1, x2 = a, b
    x0 = a + b + 0.05 * rng.normal(size=300)
    X = np.column_stack([x0, x1, x2, rng.normal(size=300)])
    y = a + b + 0.6 * a + rng.normal(0, 0.02, 300)
    s = Stepwise(f_enter=100, f_remove=50).fit(X, y, ["x0", "x1", "x2", "x3"])
    actions = [(h["action"], h["sensor"]) for h in s.history_]
    assert actions[0] == ("enter", "x0")
    assert ("remove", "x0") in actions
    assert sorted(s.selected_names_) == ["x1", "x2"]


def test_stepwise_thresholds_are_validated_and_nothing_entering_is_an_error():
    X, y = _data()
    with pytest.raises(EmpiricalDataError, match="F_enter"):
        Stepwise(f_enter=10, f_remove=50).fit(X, y)
    rng = np.random.default_rng(0)
    with pytest.raises(EmpiricalDataError, match="no sensor reaches F_enter"):
        Stepwise().fit(rng.normal(size=(30, 3)), rng.normal(size=30))


def test_cv_subset_finds_the_predictive_pair_and_scores_like_a_loop():
    rng = np.random.default_rng(4)
    n = 150
    X = rng.normal(size=(n, 7))
    y = 2 * X[:, 2] - X[:, 4] + rng.normal(0, 0.2, n)
    groups = np.repeat([0, 1, 2], n // 3)
    m = BestSubsetCV(max_sensors=3).fit(X, y, None, groups=groups)
    assert set(m.selected_names_) >= {"x3", "x5"}
    # batched score of the chosen 2-subset equals an explicit leave-one-group-out loop
    best2 = m.cv_rmse_[2]
    cols = [int(s[1:]) - 1 for s in best2["sensors"]]
    mse = []
    for g in range(3):
        tr, te = groups != g, groups == g
        A = np.column_stack([np.ones(tr.sum()), X[tr][:, cols]])
        b = np.linalg.lstsq(A, y[tr], rcond=None)[0]
        r = y[te] - np.column_stack([np.ones(te.sum()), X[te][:, cols]]) @ b
        mse.append(np.mean(r**2))
    assert best2["cv_rmse"] == pytest.approx(np.sqrt(np.mean(mse)), rel=1e-8)
    with pytest.raises(EmpiricalDataError, match="at least 2 groups"):
        BestSubsetCV().fit(X, y, groups=np.zeros(n))


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize("est,n", [(MLR(), 5), (PCR(), 2), (Stepwise(), 2), (PCR(n_components=3), 4), (MLR(fit_intercept=False), 4)])
def test_fewer_samples_than_parameters(est, n):
    """MLR needs more samples than sensors + intercept; stepwise and PCR more than the terms they keep."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(n, 4))
    with pytest.raises(EmpiricalDataError, match="samples"):
        est.fit(X, rng.normal(size=n))


@pytest.mark.parametrize("cls", [MLR, PCR, Stepwise])
def test_constant_sensor_is_named(cls):
    X, y = _data()
    X[:, 2] = 21.5
    with pytest.raises(EmpiricalDataError, match="T3.*constant|constant.*T3|sensor\\(s\\) T3"):
        cls().fit(X, y, ["T1", "T2", "T3", "T4"])


@pytest.mark.parametrize("cls", [MLR, PCR, Stepwise])
def test_nan_is_an_error(cls):
    X, y = _data()
    X[5, 1] = np.nan
    with pytest.raises(EmpiricalDataError, match="T2.*NaN|NaN"):
        cls().fit(X, y, ["T1", "T2", "T3", "T4"])
    X, y = _data()
    y[3] = np.nan
    with pytest.raises(EmpiricalDataError, match="target"):
        cls().fit(X, y)


def test_perfectly_collinear_sensors():
    X, y = _data(p=3)
    Xc = np.column_stack([X, 2 * X[:, 0] - X[:, 1] + 4.0])
    names = ["T1", "T2", "T3", "T4"]
    with pytest.raises(EmpiricalDataError, match="collinear.*T4|T4.*collinear"):
        MLR().fit(Xc, y, names)
    # PCR: documented fallback, the zero-variance component is never kept
    p = PCR(variance_threshold=0.999999).fit(Xc, y, names)
    assert p.n_components_ == 3 and p.eigenvalues_[-1] == pytest.approx(0, abs=1e-9)
    with pytest.raises(EmpiricalDataError, match="zero variance"):
        PCR(n_components=4).fit(Xc, y, names)
    # stepwise: a candidate collinear with the selected ones is skipped
    s = Stepwise(f_enter=4, f_remove=3).fit(Xc, y, names)
    assert len(s.selected_names_) <= 3 and np.isfinite(s.mlr_.bse_).all()


def test_constant_target_is_an_error():
    X, _ = _data()
    with pytest.raises(EmpiricalDataError, match="target is constant"):
        MLR().fit(X, np.full(len(X), 2.0))


# ------------------------------------------------------------------ properties


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.floats(-50, 50), perm_seed=st.integers(0, 1000))
def test_linear_form_invariances(seed, shift, perm_seed):
    """Adding a constant to a sensor changes only the intercept; permuting sensors permutes coefficients."""
    X, y = _data(n=30, p=4, seed=seed, noise=1.0)
    perm = np.random.default_rng(perm_seed).permutation(4)
    for make in (MLR, lambda: PCR(n_components=2)):
        a = make().fit(X, y)
        Xs = X.copy()
        Xs[:, 1] += shift
        b = make().fit(Xs, y)
        np.testing.assert_allclose(b.coef_, a.coef_, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(b.predict(Xs), a.predict(X), rtol=1e-6, atol=1e-7)
        c = make().fit(X[:, perm], y)
        np.testing.assert_allclose(c.coef_, a.coef_[perm], rtol=1e-6, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_stepwise_selection_is_order_invariant(seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(60, 6))
    y = 2 * X[:, 0] - 1.5 * X[:, 3] + rng.normal(0, 0.5, 60)
    names = ["a", "b", "c", "d", "e", "f"]
    perm = rng.permutation(6)
    try:
        s1 = Stepwise(f_enter=10, f_remove=5).fit(X, y, names)
    except EmpiricalDataError:
        return
    s2 = Stepwise(f_enter=10, f_remove=5).fit(X[:, perm], y, [names[i] for i in perm])
    assert sorted(s1.selected_names_) == sorted(s2.selected_names_)
    assert set(s1.selected_names_) <= set(names)


def test_stepwise_inequalities_are_the_papers():
    """Fan & Guo 2017: a variable enters when F > F_E (and is deleted when F <= F_D). At F exactly F_E nothing
    enters."""
    rng = np.random.default_rng(11)
    n = 40
    X = rng.normal(size=(n, 3))
    y = 2.0 * X[:, 0] + 0.3 * X[:, 1] + 0.5 * rng.normal(size=n)
    # the first step's partial F of each sensor alone, by the textbook formula F = SSR / MSE (one regressor)
    def single_F(j):
        A = np.column_stack([np.ones(n), X[:, j]])
        r = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        sse, sst = r @ r, ((y - y.mean()) ** 2).sum()
        return (sst - sse) / (sse / (n - 2))
    F0 = Stepwise(f_enter=1.0, f_remove=0.5).fit(X, y, ["a", "b", "c"]).history_[0]["F"]  # the estimator's own first F
    assert F0 == pytest.approx(max(single_F(j) for j in range(3)), rel=1e-9)
    with pytest.raises(EmpiricalDataError, match="no sensor reaches"):
        Stepwise(f_enter=F0, f_remove=1.0).fit(X, y, ["a", "b", "c"])
    assert Stepwise(f_enter=F0 * (1 - 1e-9), f_remove=1.0).fit(X, y, ["a", "b", "c"]).selected_names_[0] == "a"
