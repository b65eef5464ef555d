"""Input checks shared by every empirical estimator (regression.py, ann.py, ppr.py, dynamic.py).

The bottom of the estimators: it imports none of them, they all import it (docs/empirical.md).
Bad input raises :class:`host.learning.empirical.EmpiricalDataError` naming the sensor and sample.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from host.learning.empirical import EmpiricalDataError


def column_names(names: Sequence[str] | None, p: int) -> list[str]:
    if names is None:
        return ["x%d" % (j + 1) for j in range(p)]
    names = [str(n) for n in names]
    if len(names) != p:
        raise EmpiricalDataError("%d sensor names for %d columns" % (len(names), p))
    return names


def check_xy(X: Any, y: Any, names: Sequence[str] | None = None, n_params: int | None = None, what: str = "regression") -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Validate a design: 2-D finite X, 1-D finite y of the same length, no constant column.

    ``n_params`` is the number of fitted parameters; at least one more sample is
    needed so the residual variance has a degree of freedom.
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2 or y.ndim != 1:
        raise EmpiricalDataError("%s: X must be (n, p) and y (n,), got %s and %s" % (what, X.shape, y.shape))
    n, p = X.shape
    names = column_names(names, p)
    if y.size != n:
        raise EmpiricalDataError("%s: X has %d rows but y has %d" % (what, n, y.size))
    if p == 0:
        raise EmpiricalDataError("%s: no sensor given" % what)
    bad = np.argwhere(~np.isfinite(X))
    if bad.size:
        i, j = bad[0]
        raise EmpiricalDataError("%s: sensor %s sample %d is %r (NaN/inf in the temperatures)" % (what, names[j], i, X[i, j]))
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise EmpiricalDataError("%s: target sample %d is %r (NaN/inf in the errors)" % (what, bad[0], y[bad[0]]))
    if n_params is not None and n <= n_params:
        raise EmpiricalDataError(
            "%s: %d samples for %d parameters; need at least %d (fewer sensors or more measurements)" % (what, n, n_params, n_params + 1)
        )
    const = [names[j] for j in range(p) if np.ptp(X[:, j]) == 0.0]
    if const:
        raise EmpiricalDataError("%s: sensor(s) %s constant over all %d samples (zero variance); remove them" % (what, ", ".join(const), n))
    return X, y, names


def check_predict_x(est: Any, X: Any, fitted: str, n_columns: Callable[[], int]) -> np.ndarray:
    """``X`` for ``est.predict`` as a 2-D float array. EmpiricalDataError when ``est`` has no attribute
    ``fitted`` yet (predict before fit), X holds NaN/inf, or its column count is not ``n_columns()``."""
    if not hasattr(est, fitted):
        raise EmpiricalDataError("%s: predict before fit (call fit first)" % est.method)
    X = np.asarray(X, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    bad = np.argwhere(~np.isfinite(X))
    if bad.size:
        raise EmpiricalDataError("%s predict: sample %d column %d is %r (NaN/inf in the temperatures)"
                                 % (est.method, bad[0][0], bad[0][1], X[tuple(bad[0])]))
    if X.shape[1] != n_columns():
        raise EmpiricalDataError("predict: X has %d columns, the model has %d inputs" % (X.shape[1], n_columns()))
    return X


def finite_or_none(x: float) -> float | None:
    """``x`` as a float for a JSON report, or None when it is NaN or infinite (JSON has neither)."""
    x = float(x)
    return x if np.isfinite(x) else None
