"""Diagnostics of a fitted linear model that its p-values and coefficients alone hide (docs/empirical.md,
"Honest statistics"): autocorrelated residuals, which make textbook p-values far too small, and pairs of
coefficients that cancel.

Autocorrelation. Thermal samples 15 s apart are not independent: consecutive residuals share the same slow
error. With lag-1 autocorrelation ρ of the residuals (within each group, e.g. each training run), the AR(1)
effective sample size is n_eff = n·(1 − ρ)/(1 + ρ) (ρ > 0; n otherwise). The p-values are recomputed with it:
t_eff = t·sqrt(n_eff/n) on n_eff − k degrees of freedom (k parameters, the intercept included); none when
n_eff − k < 1. The fit is flagged when the Durbin–Watson statistic DW = Σ(r_t − r_{t−1})² / Σ r_t² is below
``DW_FLAG`` (1.5, the usual bound of positive autocorrelation; DW ≈ 2(1 − ρ)).

Cancelling coefficients. A pair of coefficients of opposite signs whose terms b·x each vary more than the
fitted target does (std(b_i·x_i) > std(ŷ) and std(b_j·x_j) > std(ŷ)) while their sum varies less than half
of the smaller term (std(b_i·x_i + b_j·x_j) < ``CANCEL_FRACTION``·min): the two terms mostly cancel, and a
drift or offset of either sensor moves the prediction by the large coefficient, not by the small net effect.
"""
from __future__ import annotations

from collections.abc import Sequence
import itertools
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats as _st

DW_FLAG = 1.5
CANCEL_FRACTION = 0.5


def _pairs(groups, n):
    """Index pairs (t−1, t) of consecutive samples within the same group."""
    idx = np.arange(1, n)
    if groups is None:
        return idx - 1, idx
    g = np.asarray(groups)
    same = g[1:] == g[:-1]
    return idx[same] - 1, idx[same]


def autocorrelation(resid: ArrayLike, t_values: Sequence[float] | np.ndarray, n_params: int,
                    groups: ArrayLike | None = None) -> dict[str, Any]:
    """{durbin_watson, lag1_autocorrelation, n_effective, autocorrelated, p_effective (per t value), rule}."""
    r = np.asarray(resid, dtype=float)
    n = r.size
    a, b = _pairs(groups, n)
    ss = float(r @ r)
    if ss == 0.0 or a.size == 0:
        return {"durbin_watson": None, "lag1_autocorrelation": None, "n_effective": n, "autocorrelated": False,
                "p_effective": [None] * len(t_values), "rule": "no residual variation: nothing to judge"}
    dw = float(np.sum((r[b] - r[a]) ** 2) / ss)
    rho = float(np.sum(r[b] * r[a]) / ss)
    n_eff = n * (1.0 - rho) / (1.0 + rho) if rho > 0 else float(n)
    df = n_eff - n_params
    if df >= 1:
        t_eff = np.asarray(t_values, dtype=float) * np.sqrt(n_eff / n)
        p = [float(v) if np.isfinite(v) else None for v in 2.0 * _st.t.sf(np.abs(t_eff), df)]
    else:
        p = [None] * len(t_values)
    return {"durbin_watson": dw, "lag1_autocorrelation": rho, "n_effective": float(n_eff), "autocorrelated": dw < DW_FLAG,
            "p_effective": p,
            "rule": "flagged when Durbin-Watson < %g; p_effective: t*sqrt(n_eff/n) on n_eff - %d df, n_eff = n(1-rho)/(1+rho)"
                    % (DW_FLAG, n_params)}


def cancelling_pairs(X: ArrayLike, coef: ArrayLike, names: Sequence[str], fitted: np.ndarray) -> list[dict[str, Any]]:
    """[{sensors, coefficients, term_std, sum_std, fitted_std}] of the pairs the module doc's rule flags."""
    X = np.asarray(X, dtype=float)
    coef = np.asarray(coef, dtype=float)
    fitted_std = float(np.std(fitted))
    terms = X * coef  # each sensor's term b·x
    sd = terms.std(axis=0)
    out = []
    for i, j in itertools.combinations(range(coef.size), 2):
        if not coef[i] * coef[j] < 0:
            continue
        small = min(sd[i], sd[j])
        both = float(np.std(terms[:, i] + terms[:, j]))
        if sd[i] > fitted_std and sd[j] > fitted_std and both < CANCEL_FRACTION * small:
            out.append({"sensors": [names[i], names[j]], "coefficients": [float(coef[i]), float(coef[j])],
                        "term_std": [float(sd[i]), float(sd[j])], "sum_std": both, "fitted_std": fitted_std})
    return out


CANCEL_RULE = ("opposite-sign pair whose terms b*x each vary more than the fitted target while their sum varies "
               "less than %g of the smaller term" % CANCEL_FRACTION)
