"""Least squares for selectors: one fit with statistics, and many subset fits at once.

The GA evaluates thousands of sensor subsets per generation; fitting each with
its own ``lstsq`` call would be Python-loop bound. All subsets of one size share
the centred cross-product matrix of the full data, so their normal equations are
gathered from it as a (m, k, k) stack and solved by one ``np.linalg.solve``.
Centring (and scaling to unit variance) first keeps those systems as well
conditioned as the data allow: temperatures of 20-40 °C with an intercept column
would otherwise square a condition number in the thousands.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def ols_stats(X: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """OLS of ``y`` on ``X`` with an intercept: coefficients, R², adjusted R², F and its p-value.

    Returns a dict of plain floats and lists (JSON-able). With as many parameters
    as samples the F test is undefined and ``F``/``p_F`` are None.
    """
    from scipy import stats

    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    n, k = X.shape
    A = np.column_stack([np.ones(n), X])
    coef, _, rank, _ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ coef
    sse = float(resid @ resid)
    sst = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")
    df_res = n - k - 1
    out = {
        "n": int(n),
        "k": int(k),
        "rank": int(rank),
        "intercept": float(coef[0]),
        "coefficients": [float(c) for c in coef[1:]],
        "r2": float(r2),
        "adj_r2": float(1.0 - (1.0 - r2) * (n - 1) / df_res) if df_res > 0 else None,
        "rmse": float(np.sqrt(sse / n)),
        "F": None,
        "p_F": None,
        "df": [int(k), int(df_res)],
    }
    if df_res > 0 and rank == k + 1:
        if sse <= 1e-300:
            out["F"], out["p_F"] = float("inf"), 0.0
        else:
            F = ((sst - sse) / k) / (sse / df_res)
            out["F"] = float(F)
            out["p_F"] = float(stats.f.sf(F, k, df_res))
    return out


class SubsetFitter:
    """Fits ``y ~ 1 + X[:, subset]`` (or ``y ~ X[:, subset]`` with ``intercept=False``) for a
    whole batch of equally sized subsets at once.

    Without intercept the columns are scaled by their root mean square instead of
    centred and scaled, and the intercepts returned are zero.
    """

    def __init__(self, X: np.ndarray, y: np.ndarray, intercept: bool = True) -> None:
        X = np.asarray(X, dtype=float)
        y = np.asarray(y, dtype=float)
        self.intercept = bool(intercept)
        self.mean_ = X.mean(axis=0) if intercept else np.zeros(X.shape[1])
        self.scale_ = np.sqrt(((X - self.mean_) ** 2).mean(axis=0))
        self.scale_[self.scale_ == 0] = 1.0
        Z = (X - self.mean_) / self.scale_
        self.y_mean_ = float(y.mean()) if intercept else 0.0
        yc = y - self.y_mean_
        self.gram_ = Z.T @ Z  # (p, p)
        self.cross_ = Z.T @ yc  # (p,)
        self.n_samples_ = X.shape[0]

    def fit(self, combos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``combos`` (m, k) int -> (intercepts (m,), coefficients (m, k)) in raw units."""
        combos = np.asarray(combos, dtype=np.intp)
        m, k = combos.shape
        G = self.gram_[combos[:, :, None], combos[:, None, :]]  # (m, k, k)
        c = self.cross_[combos]  # (m, k)
        try:
            beta = np.linalg.solve(G, c[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            # an exactly collinear subset somewhere in the batch: the minimum-norm
            # solution (still one batched SVD) is what lstsq would return
            beta = (np.linalg.pinv(G) @ c[:, :, None])[:, :, 0]
        coef = beta / self.scale_[combos]
        intercept = self.y_mean_ - np.einsum("mk,mk->m", coef, self.mean_[combos])
        return intercept, coef


class SubsetScorer:
    """RMSE of many subset models on one data set, from its centred cross products.

    With r = y - b0 - X b and the data centred on its own means, the cross term
    vanishes: sum r^2 = |yc|^2 - 2 b.(Xc'yc)_S + b'(Xc'Xc)_SS b + n d^2 with
    d = mean(y) - b0 - mean(X)_S.b. So each model costs O(k^2), not O(n k), and a
    long test run costs no more per model than a short one.
    """

    def __init__(self, X: np.ndarray, y: np.ndarray) -> None:
        X = np.asarray(X, dtype=float)
        y = np.asarray(y, dtype=float)
        self.n = X.shape[0]
        self.x_mean = X.mean(axis=0)
        self.y_mean = float(y.mean())
        Xc = X - self.x_mean
        yc = y - self.y_mean
        self.gram = Xc.T @ Xc
        self.cross = Xc.T @ yc
        self.yy = float(yc @ yc)

    def rmse(self, intercept: np.ndarray, coef: np.ndarray, combos: np.ndarray) -> np.ndarray:
        combos = np.asarray(combos, dtype=np.intp)
        G = self.gram[combos[:, :, None], combos[:, None, :]]
        quad = np.einsum("mk,mkl,ml->m", coef, G, coef)
        lin = np.einsum("mk,mk->m", coef, self.cross[combos])
        d = self.y_mean - intercept - np.einsum("mk,mk->m", coef, self.x_mean[combos])
        sse = self.yy - 2.0 * lin + quad + self.n * d * d
        return np.sqrt(np.maximum(sse, 0.0) / self.n)


def subset_rmse(intercept: np.ndarray, coef: np.ndarray, combos: np.ndarray, X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """RMSE of every subset model on (X, y) -> (m,)."""
    return SubsetScorer(X, y).rmse(intercept, coef, combos)
