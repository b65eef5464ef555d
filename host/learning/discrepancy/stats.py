"""Significance of a held-out improvement: a Diebold-Mariano test on per-sweep losses.

Both models are scored on data neither saw (leave-one-run-out or a time split),
so the classical partial-F test, which assumes nested models fitted to the same
data, does not apply. The held-out analogue is the Diebold-Mariano (DM) test of
equal predictive accuracy: the loss differential ``d = MSE_base - MSE_candidate``
is formed per *sweep* (one measurement time: every position and direction
measured then), because residuals inside a sweep share the same thermal state
and are far from independent. Successive sweeps are still autocorrelated (the
machine warms up slowly), so the variance of the mean differential is a
Newey-West long-run variance with Bartlett weights, autocovariances taken only
between sweeps of the same run. The statistic gets the Harvey-Leybourne-Newbold
small-sample correction and is referred to Student's t with N-1 degrees of
freedom (N = number of sweeps). One-sided: H1 is "the candidate predicts better".
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any
import math

import numpy as np
from scipy import stats as _st


def sweep_ids(time_s: np.ndarray) -> np.ndarray:
    """Integer id of each row's sweep (rows sharing one measurement time), in time order."""
    _, inv = np.unique(np.asarray(time_s, dtype=float), return_inverse=True)
    return inv.ravel()


def sweep_losses(residuals: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """Mean squared residual per sweep, in time order -> (n_sweeps,)."""
    r = np.asarray(residuals, dtype=float)
    ids = sweep_ids(time_s)
    ok = np.isfinite(r)
    n = np.bincount(ids[ok], minlength=ids.max() + 1 if ids.size else 0)
    ss = np.bincount(ids[ok], weights=r[ok] ** 2, minlength=n.size)
    keep = n > 0
    return ss[keep] / n[keep]


def bartlett_lag(n: int) -> int:
    """Newey-West bandwidth: floor(4 (n/100)^(2/9)), at least 1."""
    return max(1, int(math.floor(4.0 * (n / 100.0) ** (2.0 / 9.0))))


def long_run_variance(groups: Sequence[np.ndarray], lag: int | None = None) -> float:
    """Newey-West long-run variance of series split in independent groups (runs).

    ``groups`` is a list of 1-D arrays; the mean is pooled, autocovariances are
    summed only within each group (sweeps of different runs are independent).
    """
    allv = np.concatenate([np.asarray(g, dtype=float) for g in groups]) if groups else np.zeros(0)
    n = allv.size
    if n < 2:
        return float("nan")
    lag = bartlett_lag(n) if lag is None else int(lag)
    mu = allv.mean()
    gamma = np.zeros(lag + 1)
    for g in groups:
        x = np.asarray(g, dtype=float) - mu
        for k in range(min(lag, x.size - 1) + 1):
            gamma[k] += float(np.dot(x[k:], x[: x.size - k]))
    gamma /= n
    w = 1.0 - np.arange(1, lag + 1) / (lag + 1.0)
    lrv = gamma[0] + 2.0 * float(np.dot(w, gamma[1:]))
    # Bartlett weights keep the estimate non-negative; guard round-off anyway
    return max(lrv, gamma[0] * 1e-12)


def dm_test(loss_base: Sequence[np.ndarray], loss_cand: Sequence[np.ndarray], lag: int | None = None, log: bool = False) -> dict[str, Any]:
    """One-sided Diebold-Mariano test that the candidate's held-out loss is lower.

    ``loss_base``/``loss_cand``: lists (one per run) of per-sweep losses in time
    order. ``log``: use the differential of log losses (the per-sweep log MSE
    ratio), which weighs every sweep alike instead of letting the few largest
    warm-up sweeps dominate mean and variance. Returns dict(statistic, p_value,
    n_sweeps, mean_diff, lag).
    """
    if log:
        floor = 1e-12 * max([float(np.max(b)) for b in loss_base if np.size(b)] + [1e-300])
        f = lambda v: np.log(np.maximum(np.asarray(v, dtype=float), floor))  # noqa: E731
        d = [f(b) - f(c) for b, c in zip(loss_base, loss_cand)]
    else:
        d = [np.asarray(b, dtype=float) - np.asarray(c, dtype=float) for b, c in zip(loss_base, loss_cand)]
    if any(a.shape != b.shape for a, b in zip(loss_base, loss_cand)):
        raise ValueError("base and candidate losses cover different sweeps")
    allv = np.concatenate(d) if d else np.zeros(0)
    n = allv.size
    if n < 3:
        return {"statistic": float("nan"), "p_value": 1.0, "n_sweeps": int(n), "mean_diff": float("nan"), "lag": 0}
    lag = bartlett_lag(n) if lag is None else int(lag)
    lrv = long_run_variance(d, lag)
    mean = float(allv.mean())
    if not lrv > 0:
        stat = math.inf if mean > 0 else (-math.inf if mean < 0 else 0.0)
    else:
        stat = mean / math.sqrt(lrv / n)
    # Harvey, Leybourne & Newbold (1997) correction for a one-step horizon
    stat *= math.sqrt((n - 1.0) / n)
    p = float(_st.t.sf(stat, df=n - 1)) if math.isfinite(stat) else (0.0 if stat > 0 else 1.0)
    return {"statistic": float(stat), "p_value": p, "n_sweeps": int(n), "mean_diff": mean, "lag": int(lag)}


def holm_adjust(p_values: Sequence[float]) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values (family-wise error control), same order as given."""
    p = np.asarray(p_values, dtype=float)
    m = p.size
    order = np.argsort(p)
    adj = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adj[i] = running
    return adj


def rmse(residuals: np.ndarray) -> float:
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r ** 2))) if r.size else float("nan")
