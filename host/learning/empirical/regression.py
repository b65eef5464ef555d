"""Linear regressions of a thermal target on temperatures: MLR, PCR, stepwise.

scikit-learn style estimators: parameters in ``__init__``, ``fit(X, y, names=None)``
returns self, ``predict(X)``, learned attributes end in ``_``. Every fitted
estimator exposes the same linear form ``y ≈ intercept_ + X @ coef_`` in the
units of X (a plain linear function of the raw inputs, also for PCR) and
``statistics()``, a JSON-ready dict. docs/empirical.md gives the formulas.

Bad input raises :class:`host.learning.empirical.EmpiricalDataError` naming the problem:
NaN, fewer samples than parameters, a constant sensor, perfectly collinear
sensors (MLR and stepwise; PCR handles collinearity by design), constant target.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats as _st

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import check_predict_x, check_xy, finite_or_none
from host.learning.empirical.diagnostics import CANCEL_RULE, autocorrelation, cancelling_pairs

_COLLINEAR_TOL = 1e-10  # 1 − R² of a sensor on the others below this = perfectly collinear


def _collinear_groups(A, names, has_intercept):
    """Names of the columns of A that are (numerically) linear combinations of earlier ones.

    |R_jj| of the QR decomposition is the norm of column j's residual on the
    columns before it; compared with the column's own (centred) norm.
    """
    R = np.linalg.qr(A, mode="r")
    d2 = np.diag(R) ** 2
    dep = []
    for j in range(A.shape[1]):
        if has_intercept and j == 0:
            continue
        col = A[:, j]
        ref = col - col.mean() if has_intercept else col
        if d2[j] <= _COLLINEAR_TOL * max(float(ref @ ref), 1e-300):
            dep.append(names[j - int(has_intercept)])
    return dep


def ols_statistics(A: np.ndarray, y: np.ndarray, beta: np.ndarray, has_intercept: bool) -> dict[str, Any]:
    """Textbook OLS statistics of y ≈ A @ beta (A includes the ones column when has_intercept).

    Returns a dict: bse (standard errors of beta), t, p (two-sided), rss, df_resid,
    df_model, sigma (residual standard error), r2, r2_adj, F, F_p, cov.
    R² is centred with an intercept and uncentred without (the usual convention).
    """
    n, k = A.shape
    resid = y - A @ beta
    rss = float(resid @ resid)
    df_resid = n - k
    df_model = k - int(has_intercept)
    tss = float(((y - y.mean()) ** 2).sum()) if has_intercept else float(y @ y)
    if tss == 0.0:
        raise EmpiricalDataError("regression: the target is constant (%g) over all %d samples; nothing to model" % (y[0], n))
    sigma2 = rss / df_resid
    # (A'A)^-1 from the SVD of R (A = QR, same singular values and V as A): the
    # explicit inverse's value, better conditioned, and cheap for tall A
    _, s, Vt = np.linalg.svd(np.linalg.qr(A, mode="r"))
    xtx_inv = (Vt.T / s**2) @ Vt
    cov = sigma2 * xtx_inv
    bse = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = beta / bse
        F = ((tss - rss) / df_model) / sigma2 if df_model else float("nan")
    p = 2.0 * _st.t.sf(np.abs(t), df_resid)
    r2 = 1.0 - rss / tss
    r2_adj = 1.0 - (1.0 - r2) * (n - int(has_intercept)) / df_resid
    F_p = float(_st.f.sf(F, df_model, df_resid)) if df_model else float("nan")
    return {
        "bse": bse, "t": t, "p": p, "rss": rss, "df_resid": int(df_resid), "df_model": int(df_model),
        "sigma": float(np.sqrt(sigma2)), "r2": float(r2), "r2_adj": float(r2_adj), "F": float(F), "F_p": F_p, "cov": cov,
        "rmse": float(np.sqrt(rss / n)),
    }


class _Linear:
    """Shared prediction and reporting of the fitted linear form."""

    coef_: np.ndarray
    intercept_: float
    n_samples_: int
    # the whole-fit statistics (ols_statistics), learned by _set_fit_statistics (MLR, PCR) or copied by _refit_on
    rsquared_: float
    rsquared_adj_: float
    fvalue_: float
    f_pvalue_: float
    resid_std_err_: float
    df_resid_: int
    rmse_: float
    # set by the subclasses: their parameter, and (the subset selectors, the only users of _refit_on) the chosen names
    fit_intercept: bool
    selected_names_: list[str]

    def predict(self, X):
        X = check_predict_x(self, X, "coef_", lambda: self.coef_.size)
        return self.intercept_ + X @ self.coef_

    def _stats_dict(self, st, extra=None):
        d = {
            "n_samples": int(self.n_samples_),
            "r2": finite_or_none(st["r2"]),
            "r2_adj": finite_or_none(st["r2_adj"]),
            "F": finite_or_none(st["F"]),
            "F_p": finite_or_none(st["F_p"]),
            "df_model": st["df_model"],
            "df_resid": st["df_resid"],
            "residual_std_error": finite_or_none(st["sigma"]),
            "rmse": finite_or_none(st["rmse"]),
        }
        if extra:
            d.update(extra)
        return d

    def _refit_on(self, X, y, sel):
        """Subset selectors: the final model is a plain MLR on the chosen columns ``sel``."""
        self.mlr_ = MLR(fit_intercept=self.fit_intercept).fit(X[:, sel], y, self.selected_names_)
        self.coef_ = np.zeros(X.shape[1])
        self.coef_[sel] = self.mlr_.coef_
        self.intercept_ = self.mlr_.intercept_
        self.n_samples_ = X.shape[0]
        _set_fit_statistics(self, self.mlr_._st)  # the refit MLR's whole-fit statistics are the selector's
        return self


def _set_fit_statistics(est: _Linear, st: dict[str, Any]) -> None:
    """The whole-fit statistics MLR and PCR learn alike from ``ols_statistics``' result (trailing-underscore attributes)."""
    est.rsquared_ = st["r2"]
    est.rsquared_adj_ = st["r2_adj"]
    est.fvalue_ = st["F"]
    est.f_pvalue_ = st["F_p"]
    est.resid_std_err_ = st["sigma"]
    est.df_resid_ = st["df_resid"]
    est.rmse_ = st["rmse"]


class MLR(_Linear):
    """Ordinary least squares with full statistics.

    Parameters: ``fit_intercept``. Learned: ``coef_``, ``intercept_``, ``bse_``
    (standard errors of coef_), ``intercept_bse_``, ``tvalues_``, ``pvalues_``
    (coef_, then intercept last in ``intercept_t_``/``intercept_p_``),
    ``rsquared_``, ``rsquared_adj_``, ``fvalue_``, ``f_pvalue_``,
    ``resid_std_err_``, ``df_resid_``, ``df_model_``, ``n_samples_``, ``names_``.
    """

    method = "mlr"

    def __init__(self, *, fit_intercept: bool = True) -> None:
        self.fit_intercept = fit_intercept

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> MLR:
        """``groups`` (cross-validation groups) is part of every estimator's fit signature; this one does not read it."""
        X, y, names = check_xy(X, y, names, X_params(X, self.fit_intercept), "MLR")
        A = np.column_stack([np.ones(len(y)), X]) if self.fit_intercept else X
        dep = _collinear_groups(A, names, self.fit_intercept)
        if dep:
            raise EmpiricalDataError(
                "MLR: sensor(s) %s are perfectly collinear with the other sensors (a linear combination of them); "
                "drop them, select sensors first, or use PCR" % ", ".join(dep)
            )
        beta, *_ = np.linalg.lstsq(A, y, rcond=None)
        st = ols_statistics(A, y, beta, self.fit_intercept)
        o = int(self.fit_intercept)
        self.names_ = names
        self.n_samples_ = len(y)
        self.coef_ = beta[o:]
        self.intercept_ = float(beta[0]) if o else 0.0
        self.bse_ = st["bse"][o:]
        self.tvalues_ = st["t"][o:]
        self.pvalues_ = st["p"][o:]
        self.intercept_bse_ = float(st["bse"][0]) if o else None
        self.intercept_t_ = float(st["t"][0]) if o else None
        self.intercept_p_ = float(st["p"][0]) if o else None
        self.cov_ = st["cov"]
        _set_fit_statistics(self, st)
        self.df_model_ = st["df_model"]
        self._st = st
        # what the p-values and coefficients hide (host/learning/empirical/diagnostics.py)
        fitted = A @ beta
        self.autocorrelation_ = autocorrelation(y - fitted, st["t"][o:], A.shape[1], groups)
        self.cancelling_ = cancelling_pairs(X, self.coef_, names, fitted)
        return self

    def statistics(self) -> dict[str, Any]:
        p_eff = self.autocorrelation_["p_effective"]
        coefs = {
            n: {"coef": finite_or_none(c), "std_error": finite_or_none(s), "t": finite_or_none(t), "p": finite_or_none(p),
                "p_effective": pe}
            for n, c, s, t, p, pe in zip(self.names_, self.coef_, self.bse_, self.tvalues_, self.pvalues_, p_eff)
        }
        extra: dict = {"coefficients": coefs, "autocorrelation": {k: v for k, v in self.autocorrelation_.items() if k != "p_effective"},
                       "cancelling": {"pairs": self.cancelling_, "rule": CANCEL_RULE}}
        if self.fit_intercept:
            # fit() sets them to floats when fit_intercept (None only without an intercept)
            assert self.intercept_bse_ is not None and self.intercept_t_ is not None and self.intercept_p_ is not None
            extra["intercept"] = {"coef": finite_or_none(self.intercept_), "std_error": finite_or_none(self.intercept_bse_), "t": finite_or_none(self.intercept_t_), "p": finite_or_none(self.intercept_p_)}
        return self._stats_dict(self._st, extra)

    def warnings(self) -> list[str]:
        """Lines saying what the textbook statistics oversell (empty when nothing is flagged)."""
        out = []
        a = self.autocorrelation_
        if a["autocorrelated"]:
            out.append("WARNING: residuals are autocorrelated (Durbin-Watson %.3f, lag-1 %.3f): the %d samples count as "
                       "about %.0f independent ones; p-values assuming independence are too small (p_effective recomputes "
                       "them)" % (a["durbin_watson"], a["lag1_autocorrelation"], self.n_samples_, a["n_effective"]))
        for c in self.cancelling_:
            out.append("WARNING: coefficients of %s and %s (%+.4g, %+.4g) cancel: their terms vary %.3g and %.3g but their "
                       "sum only %.3g; a drift of either sensor moves the prediction by its large coefficient"
                       % (c["sensors"][0], c["sensors"][1], c["coefficients"][0], c["coefficients"][1], c["term_std"][0],
                          c["term_std"][1], c["sum_std"]))
        return out

    def summary(self) -> str:
        """Plain-text coefficient table (what a statistics package prints)."""
        lines = ["%-12s %12s %12s %9s %10s" % ("term", "coef", "std err", "t", "P>|t|")]
        rows = list(zip(self.names_, self.coef_, self.bse_, self.tvalues_, self.pvalues_))
        if self.fit_intercept:
            rows.insert(0, ("intercept", self.intercept_, self.intercept_bse_, self.intercept_t_, self.intercept_p_))
        for n, c, s, t, p in rows:
            lines.append("%-12s %12.5g %12.4g %9.3f %10.3g" % (n, c, s, t, p))
        lines.append(
            "n=%d  R2=%.4f  adj R2=%.4f  F=%.4g (p=%.3g, df %d/%d)  residual std error=%.4g"
            % (self.n_samples_, self.rsquared_, self.rsquared_adj_, self.fvalue_, self.f_pvalue_, self.df_model_, self.df_resid_, self.resid_std_err_)
        )
        return "\n".join(lines + self.warnings())


def X_params(X: np.ndarray, fit_intercept: bool) -> int:
    X = np.asarray(X)
    return (X.shape[1] if X.ndim == 2 else 1) + int(fit_intercept)


class PCR(_Linear):
    """Principal component regression mapped back to the raw temperatures.

    Standardise (centre and scale to unit sample variance; without intercept:
    scale by the root mean square, no centring), correlation matrix,
    eigen-decomposition sorted by decreasing eigenvalue, keep the first
    ``n_components`` or the fewest components whose cumulative explained
    variance reaches ``variance_threshold`` (default 0.85), regress y on their
    scores by OLS, map the score coefficients back: coef_ = V_k·γ / scale.

    Learned: ``coef_``, ``intercept_``, ``bse_`` (standard errors of coef_ via the
    mapped covariance), ``n_components_``, ``eigenvalues_``,
    ``explained_variance_ratio_``, ``cumulative_variance_ratio_``,
    ``components_`` (k, p loadings), ``score_coef_``, ``mean_``, ``scale_``,
    ``corr_``, ``rsquared_``, ``rsquared_adj_``, ``fvalue_``, ``f_pvalue_``,
    ``resid_std_err_`` (degrees of freedom counted with k components).
    Perfectly collinear sensors are allowed (their component has eigenvalue 0
    and is never kept unless asked for explicitly).
    """

    method = "pcr"

    def __init__(self, *, variance_threshold: float = 0.85, n_components: int | None = None, fit_intercept: bool = True) -> None:
        self.variance_threshold = variance_threshold
        self.n_components = n_components
        self.fit_intercept = fit_intercept

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> PCR:
        """``groups`` (cross-validation groups) is part of every estimator's fit signature; this one does not read it."""
        if not (0.0 < float(self.variance_threshold) <= 1.0):
            raise EmpiricalDataError("PCR: variance_threshold must be in (0, 1], got %r" % self.variance_threshold)
        X, y, names = check_xy(X, y, names, None, "PCR")
        n, p = X.shape
        if self.fit_intercept:
            mean = X.mean(axis=0)
            scale = X.std(axis=0, ddof=1)
            Z = (X - mean) / scale
            corr = Z.T @ Z / (n - 1)
        else:
            mean = np.zeros(p)
            scale = np.sqrt((X**2).mean(axis=0))
            Z = X / scale
            corr = Z.T @ Z / n
        w, V = np.linalg.eigh(corr)
        order = np.argsort(w)[::-1]
        w = np.clip(w[order], 0.0, None)
        V = V[:, order]
        # deterministic signs: the largest loading of each component is positive
        flip = np.sign(V[np.argmax(np.abs(V), axis=0), np.arange(p)])
        V = V * np.where(flip == 0, 1.0, flip)
        ratio = w / w.sum()
        cum = np.cumsum(ratio)
        if self.n_components is not None:
            k = int(self.n_components)
            if not 1 <= k <= p:
                raise EmpiricalDataError("PCR: n_components must be 1..%d, got %r" % (p, self.n_components))
        else:
            k = int(np.searchsorted(cum, float(self.variance_threshold) - 1e-12) + 1)
            k = min(k, p)
        if n <= k + int(self.fit_intercept):
            raise EmpiricalDataError("PCR: %d samples for %d components%s; need at least %d" % (n, k, " + intercept" if self.fit_intercept else "", k + int(self.fit_intercept) + 1))
        if w[k - 1] <= _COLLINEAR_TOL * w[0]:
            raise EmpiricalDataError("PCR: component %d has zero variance (collinear sensors); keep fewer components" % k)
        Vk = V[:, :k]
        T = Z @ Vk
        A = np.column_stack([np.ones(n), T]) if self.fit_intercept else T
        gamma, *_ = np.linalg.lstsq(A, y, rcond=None)
        st = ols_statistics(A, y, gamma, self.fit_intercept)
        o = int(self.fit_intercept)
        M = Vk / scale[:, None]  # raw coef = M @ score coef
        self.coef_ = M @ gamma[o:]
        self.intercept_ = float(gamma[0] - mean @ self.coef_) if o else 0.0
        cov_g = st["cov"][o:, o:]
        self.bse_ = np.sqrt(np.clip(np.diag(M @ cov_g @ M.T), 0.0, None))
        self.names_ = names
        self.n_samples_ = n
        self.n_components_ = k
        self.eigenvalues_ = w
        self.explained_variance_ratio_ = ratio
        self.cumulative_variance_ratio_ = cum
        self.components_ = Vk.T
        self.score_coef_ = gamma[o:]
        self.mean_ = mean
        self.scale_ = scale
        self.corr_ = corr
        _set_fit_statistics(self, st)
        self._st = st
        return self

    def scree(self) -> list[dict[str, Any]]:
        """Scree data: one dict per component (eigenvalue, explained and cumulative ratio, kept)."""
        return [
            {"component": i + 1, "eigenvalue": float(self.eigenvalues_[i]), "explained": float(self.explained_variance_ratio_[i]),
             "cumulative": float(self.cumulative_variance_ratio_[i]), "kept": i < self.n_components_}
            for i in range(self.eigenvalues_.size)
        ]

    def statistics(self) -> dict[str, Any]:
        return self._stats_dict(self._st, {
            "n_components": int(self.n_components_),
            "variance_threshold": float(self.variance_threshold),
            "scree": self.scree(),
            "coefficients": {n: {"coef": finite_or_none(c), "std_error": finite_or_none(s)} for n, c, s in zip(self.names_, self.coef_, self.bse_)},
            "intercept": {"coef": finite_or_none(self.intercept_)} if self.fit_intercept else None,
        })


class Stepwise(_Linear):
    """Stepwise regression with partial-F entry and removal (Efroymson).

    From the empty model: enter the candidate with the largest partial F if it is
    > ``f_enter``; then remove the selected sensor with the smallest partial F if
    it is ≤ ``f_remove`` (Fan & Guo 2017's inequalities); repeat until neither happens. Partial F of sensor j for
    the larger model L (q sensors) against the smaller S:
    F = (RSS_S − RSS_L) / (RSS_L / (n − q − intercept)).
    A candidate perfectly collinear with the selected ones (1 − R² < 1e-10) is
    skipped. ``f_enter >= f_remove`` is required (otherwise it can cycle).
    Raises EmpiricalDataError if no sensor reaches f_enter (with the best F seen).

    Learned: ``support_`` (bool mask), ``selected_`` (indices in entry order),
    ``selected_names_``, ``history_`` (list of steps with F values), ``mlr_``
    (the MLR on the selected sensors), ``coef_`` over all inputs (0 where not
    selected), ``intercept_`` and the MLR statistics.
    """

    method = "stepwise"

    def __init__(self, *, f_enter: float = 100.0, f_remove: float = 50.0, fit_intercept: bool = True, max_steps: int | None = None) -> None:
        self.f_enter = f_enter
        self.f_remove = f_remove
        self.fit_intercept = fit_intercept
        self.max_steps = max_steps

    def _rss(self, X, y, cols):
        n = len(y)
        parts = [np.ones((n, 1))] if self.fit_intercept else []
        if cols:
            parts.append(X[:, cols])
        if not parts:
            return float(y @ y)
        A = np.hstack(parts)
        beta, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = y - A @ beta
        return float(r @ r)

    def _tolerance(self, X, cols, j):
        x = X[:, j]
        ref = x - x.mean() if self.fit_intercept else x
        parts = [np.ones((len(x), 1))] if self.fit_intercept else []
        if cols:
            parts.append(X[:, cols])
        if not parts:
            return 1.0
        A = np.hstack(parts)
        c, *_ = np.linalg.lstsq(A, x, rcond=None)
        r = x - A @ c
        return float(r @ r) / max(float(ref @ ref), 1e-300)

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> Stepwise:
        """``groups`` (cross-validation groups) is part of every estimator's fit signature; this one does not read it."""
        if self.f_enter < self.f_remove:
            raise EmpiricalDataError("stepwise: F_enter (%g) must be >= F_remove (%g), otherwise a sensor can enter and leave forever" % (self.f_enter, self.f_remove))
        X, y, names = check_xy(X, y, names, 1 + int(self.fit_intercept), "stepwise")
        n, p = X.shape
        sel = []
        history = []
        max_steps = self.max_steps or 4 * p + 4
        best_seen = (None, -np.inf)
        for _ in range(max_steps):
            changed = False
            rss_s = self._rss(X, y, sel)
            df = n - (len(sel) + 1) - int(self.fit_intercept)
            cand = []
            if df > 0:
                for j in range(p):
                    if j in sel:
                        continue
                    if self._tolerance(X, sel, j) < _COLLINEAR_TOL:
                        continue
                    rss_l = self._rss(X, y, sel + [j])
                    F = (rss_s - rss_l) / (rss_l / df) if rss_l > 0 else np.inf
                    cand.append((F, j))
            if cand:
                F, j = max(cand)
                if F > best_seen[1]:
                    best_seen = (names[j], F)
                if F > self.f_enter:  # Fan & Guo 2017: enter when F > F_E
                    sel.append(j)
                    history.append({"step": len(history) + 1, "action": "enter", "sensor": names[j], "F": finite_or_none(F), "threshold": float(self.f_enter)})
                    changed = True
            if len(sel) > 1:
                rss_l = self._rss(X, y, sel)
                df_l = n - len(sel) - int(self.fit_intercept)
                outs = []
                for j in sel:
                    rest = [c for c in sel if c != j]
                    F = (self._rss(X, y, rest) - rss_l) / (rss_l / df_l) if rss_l > 0 else np.inf
                    outs.append((F, j))
                F, j = min(outs)
                if F <= self.f_remove:  # Fan & Guo 2017: delete when F <= F_D
                    sel.remove(j)
                    history.append({"step": len(history) + 1, "action": "remove", "sensor": names[j], "F": finite_or_none(F), "threshold": float(self.f_remove)})
                    changed = True
            if not changed:
                break
        if not sel:
            raise EmpiricalDataError(
                "stepwise: no sensor reaches F_enter=%g (largest partial F: %.4g for %s); lower f_enter or check the data"
                % (self.f_enter, best_seen[1], best_seen[0])
            )
        self.selected_ = list(sel)
        self.selected_names_ = [names[j] for j in sel]
        self.support_ = np.zeros(p, bool)
        self.support_[sel] = True
        self.history_ = history
        self.names_ = names
        return self._refit_on(X, y, sel)

    def statistics(self) -> dict[str, Any]:
        d = self.mlr_.statistics()
        d.update({"selected": list(self.selected_names_), "f_enter": float(self.f_enter), "f_remove": float(self.f_remove), "history": self.history_})
        return d


class BestSubsetCV(_Linear):
    """Exhaustive best subset of at most ``max_sensors`` sensors by blocked cross-validation.

    Not a published method: our answer to "which few sensors predict *other*
    conditions". Every subset of 1..max_sensors sensors is scored by
    leave-one-group-out CV RMSE of an OLS fit (groups: the training runs, or
    contiguous time blocks of one run, e.g. its speed steps); the subset with
    the lowest CV RMSE wins, then MLR is refitted on all training data. Scoring
    is batched: per-group Gram matrices, one batched solve per subset size, no
    Python loop over subsets. Falls back to greedy forward search when the
    number of subsets exceeds ``max_combinations`` (``search_`` says which).
    Needs ``groups`` with at least 2 distinct values.

    Learned: ``selected_names_``, ``selected_``, ``cv_rmse_`` (best per size),
    ``search_``, ``mlr_``, ``coef_`` (all inputs, 0 if unused), ``intercept_``.
    """

    method = "cv-subset"

    def __init__(self, *, max_sensors: int = 5, fit_intercept: bool = True, max_combinations: int = 200000) -> None:
        self.max_sensors = max_sensors
        self.fit_intercept = fit_intercept
        self.max_combinations = max_combinations

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> BestSubsetCV:
        import itertools
        from math import comb

        if isinstance(self.max_sensors, bool) or not isinstance(self.max_sensors, (int, np.integer)) or self.max_sensors < 1:
            raise EmpiricalDataError("cv-subset: max_sensors must be an integer >= 1, got %r" % (self.max_sensors,))
        X, y, names = check_xy(X, y, names, 1 + int(self.fit_intercept), "cv-subset")
        n, p = X.shape
        if groups is None:
            raise EmpiricalDataError("cv-subset: needs groups (runs or time blocks) for cross-validation")
        groups = np.asarray(groups)
        if groups.shape != (n,):
            raise EmpiricalDataError("cv-subset: groups has %s entries for %d samples" % (groups.shape, n))
        labels = np.unique(groups)
        if labels.size < 2:
            raise EmpiricalDataError("cv-subset: cross-validation needs at least 2 groups (runs or time blocks), got %d" % labels.size)
        kmax = min(int(self.max_sensors), p)
        o = int(self.fit_intercept)
        A = np.column_stack([np.ones(n), X]) if o else X
        G = [(A[groups == g].T @ A[groups == g], A[groups == g].T @ y[groups == g], float(y[groups == g] @ y[groups == g]), int((groups == g).sum())) for g in labels]
        Gall = sum(g[0] for g in G)
        call = sum(g[1] for g in G)

        def score(combos):
            c = np.asarray(combos, dtype=int) + o
            idx = np.column_stack([np.zeros(len(c), int), c]) if o else c
            tot = np.zeros(len(c))
            ok = np.ones(len(c), bool)
            for Gv, cv, yy, nv in G:
                Gt, ct = Gall - Gv, call - cv
                M = Gt[idx[:, :, None], idx[:, None, :]]
                # singular training Gram (collinear subset) -> excluded, never silently solved
                det_ok = np.linalg.cond(M) < 1e12
                ok &= det_ok
                M = np.where(det_ok[:, None, None], M, np.eye(M.shape[1]))
                beta = np.linalg.solve(M, ct[idx][..., None])[..., 0]
                Mv = Gv[idx[:, :, None], idx[:, None, :]]
                sse = yy - 2 * np.einsum("ij,ij->i", beta, cv[idx]) + np.einsum("ij,ijk,ik->i", beta, Mv, beta)
                tot += np.maximum(sse, 0.0) / nv
            out = np.sqrt(tot / len(G))
            out[~ok] = np.inf
            return out

        total = sum(comb(p, k) for k in range(1, kmax + 1))
        best_by_k = {}
        if total <= self.max_combinations:
            self.search_ = "exhaustive (%d subsets)" % total
            for k in range(1, kmax + 1):
                combos = list(itertools.combinations(range(p), k))
                s = score(combos)
                i = int(np.argmin(s))
                best_by_k[k] = (float(s[i]), list(combos[i]))
        else:
            self.search_ = "greedy forward (%d subsets exceed max_combinations=%d)" % (total, self.max_combinations)
            cur = []
            for k in range(1, kmax + 1):
                cand = [cur + [j] for j in range(p) if j not in cur]
                s = score(cand)
                i = int(np.argmin(s))
                cur = sorted(cand[i])
                best_by_k[k] = (float(s[i]), list(cur))
        finite = {k: v for k, v in best_by_k.items() if np.isfinite(v[0])}
        if not finite:
            raise EmpiricalDataError("cv-subset: every subset is collinear within a training fold")
        k = min(finite, key=lambda k: (finite[k][0], k))
        sel = finite[k][1]
        self.cv_rmse_ = {int(kk): {"cv_rmse": v[0], "sensors": [names[j] for j in v[1]]} for kk, v in best_by_k.items()}
        self.selected_ = sel
        self.selected_names_ = [names[j] for j in sel]
        self.names_ = names
        self.n_groups_ = int(labels.size)
        return self._refit_on(X, y, sel)

    def statistics(self) -> dict[str, Any]:
        d = self.mlr_.statistics()
        d.update({"selected": list(self.selected_names_), "max_sensors": int(self.max_sensors), "search": self.search_,
                  "cv_groups": self.n_groups_, "cv_rmse_by_size": self.cv_rmse_})
        return d
