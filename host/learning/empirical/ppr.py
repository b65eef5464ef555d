"""Projection pursuit regression (Friedman & Stuetzle), the comparison model of Fan & Guo 2017.

y ≈ ȳ + Σ_m g_m(a_m·z), z the standardised temperature rises, a_m unit directions,
g_m smooth ridge functions. Our choices (the paper does not fix them):

* g_m is a natural cubic regression spline in the projection with ``knots``
  knots at equally spaced quantiles of the training projection: smooth, and
  linear beyond the outer knots, so a held-out condition hotter than the training
  data gets a straight-line continuation instead of a cubic blow-up;
* each term is fitted to the current residual by variable projection: for a
  direction a the spline coefficients are a least-squares solve, and a is
  optimised by BFGS (scipy) starting from the residual's OLS direction, so the
  fit is deterministic;
* ``n_terms`` terms (default 2) are added forward; then ``backfit_passes`` (1) passes
  refit every term (direction and function) on the residual of the others.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast
from numpy.typing import ArrayLike

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import check_predict_x, check_xy, finite_or_none


def natural_spline_basis(v: ArrayLike, knots: ArrayLike) -> np.ndarray:
    """Natural cubic spline basis (n, K) of values v for K knots: 1, v, and K−2 truncated-power terms."""
    v = np.asarray(v, dtype=float)
    k = np.asarray(knots, dtype=float)
    K = k.size

    def d(j):
        return (np.maximum(v - k[j], 0.0) ** 3 - np.maximum(v - k[K - 1], 0.0) ** 3) / (k[K - 1] - k[j])

    cols = [np.ones_like(v), v]
    dK = d(K - 2)
    for j in range(K - 2):
        cols.append(d(j) - dK)
    return np.column_stack(cols)


class _Ridge:
    """One term: unit direction ``a`` and spline coefficients on fixed knots."""

    def __init__(self, a, knots, beta):
        self.a, self.knots, self.beta = a, knots, beta

    def __call__(self, Z):
        return natural_spline_basis(Z @ self.a, self.knots) @ self.beta


def _fit_ridge(Z, r, a0, n_knots):
    from scipy.optimize import minimize

    def knots_for(v):
        k = np.quantile(v, np.linspace(0.02, 0.98, n_knots))
        # equal quantiles (a projection with ties) would divide by zero in the basis
        return k + np.arange(n_knots) * 1e-9 * max(1.0, float(np.ptp(v)))

    def solve(a):
        a = a / (np.linalg.norm(a) or 1.0)
        v = Z @ a
        k = knots_for(v)
        B = natural_spline_basis(v, k)
        # normal equations of a (n, knots) basis: knots x knots, far cheaper than an SVD of B per evaluation
        G = B.T @ B
        beta = np.linalg.solve(G + 1e-10 * np.trace(G) / G.shape[0] * np.eye(G.shape[0]), B.T @ r)
        e = r - B @ beta
        return float(e @ e), a, k, beta

    res = minimize(lambda a: solve(a)[0], a0, method="BFGS", options={"maxiter": 40, "gtol": 1e-5})
    best = min((solve(res.x), solve(a0)), key=lambda s: s[0])
    return _Ridge(best[1], best[2], best[3])


class PPR:
    """Projection pursuit regression; scikit-learn style.

    Parameters (keyword-only): ``n_terms``, ``knots``, ``backfit_passes``.
    Learned: ``terms_`` (each with unit direction ``a`` on standardised inputs),
    ``x_mean_``, ``x_scale_``, ``y_mean_``, ``rmse_``, ``rsquared_``,
    ``n_samples_``, ``names_``.
    """

    method = "ppr"

    def __init__(self, *, n_terms: int = 2, knots: int = 5, backfit_passes: int = 1, fit_intercept: bool = True) -> None:
        self.n_terms = n_terms
        self.knots = knots
        self.backfit_passes = backfit_passes
        self.fit_intercept = fit_intercept  # ȳ is always fitted

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> PPR:
        """``groups`` (cross-validation groups) is part of every estimator's fit signature; PPR does not read it."""
        for key, lo in (("n_terms", 1), ("knots", 3), ("backfit_passes", 0)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise EmpiricalDataError("ppr: %s must be an integer >= %d, got %r" % (key, lo, v))
        X, y, names = check_xy(X, y, names, self.n_terms * self.knots + 1, "PPR")
        self.x_mean_ = X.mean(axis=0)
        self.x_scale_ = X.std(axis=0)
        self.x_scale_[self.x_scale_ == 0] = 1.0
        Z = (X - self.x_mean_) / self.x_scale_
        self.y_mean_ = float(y.mean())
        r = y - self.y_mean_
        terms = []
        for _ in range(int(self.n_terms)):
            a0 = np.linalg.lstsq(Z, r, rcond=None)[0]
            term = _fit_ridge(Z, r, a0 if np.linalg.norm(a0) > 0 else np.ones(Z.shape[1]), int(self.knots))
            terms.append(term)
            r = r - term(Z)
        for _ in range(int(self.backfit_passes)):
            for j, term in enumerate(terms):
                partial = r + term(Z)
                terms[j] = _fit_ridge(Z, partial, term.a, int(self.knots))
                r = partial - terms[j](Z)
        self.terms_ = terms
        self.names_ = names
        self.n_samples_ = X.shape[0]
        e = y - self.predict(X)
        self.rmse_ = float(np.sqrt(np.mean(e**2)))
        sst = float(((y - y.mean()) ** 2).sum())
        self.rsquared_ = 1.0 - float(e @ e) / sst if sst > 0 else float("nan")
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = check_predict_x(self, X, "terms_", lambda: self.x_mean_.size)
        Z = (X - self.x_mean_) / self.x_scale_
        # each ridge term returns an array, so the sum is one; pyright types sum() from its int start
        return cast(np.ndarray, self.y_mean_ + sum(t(Z) for t in self.terms_))

    def ridges(self) -> dict[str, Any]:
        """The fitted model as plain lists (the ``ppr`` model document's ``thermal.ridges``): the standardisation,
        ȳ, and each term's unit direction, spline knots and spline coefficients (natural_spline_basis)."""
        return {
            "input_offset": [float(v) for v in self.x_mean_],
            "input_scale": [float(v) for v in self.x_scale_],
            "output_offset": float(self.y_mean_),
            "terms": [{"direction": [float(v) for v in t.a], "knots": [float(v) for v in t.knots],
                       "coefficients": [float(v) for v in t.beta]} for t in self.terms_],
        }

    @classmethod
    def from_ridges(cls, ridges: dict[str, Any]) -> PPR:
        """A PPR predicting with a ``ridges()`` dict (no training data; host/learning/empirical/kinds.py
        PPRModel.from_document checks the dict first)."""
        terms = ridges["terms"]
        self = cls(n_terms=len(terms), knots=len(terms[0]["knots"]))
        self.x_mean_ = np.asarray(ridges["input_offset"], dtype=float)
        self.x_scale_ = np.asarray(ridges["input_scale"], dtype=float)
        self.y_mean_ = float(ridges["output_offset"])
        self.terms_ = [_Ridge(np.asarray(t["direction"], dtype=float), np.asarray(t["knots"], dtype=float),
                              np.asarray(t["coefficients"], dtype=float)) for t in terms]
        return self

    def statistics(self) -> dict[str, Any]:
        return {
            "n_samples": int(self.n_samples_),
            "r2": finite_or_none(self.rsquared_),
            "rmse": finite_or_none(self.rmse_),
            "n_terms": int(self.n_terms),
            "knots": int(self.knots),
            "directions": [{n: float(v) for n, v in zip(self.names_, t.a)} for t in self.terms_],
            "r2_adj": None, "F": None, "F_p": None, "residual_std_error": finite_or_none(self.rmse_),
        }
