"""Residual figures of a prediction against a measurement, per channel: the one place `tcomp predict`,
`tcomp check` and `tcomp report` compute them, so the three verbs agree on the same rows.

residual = measured − predicted (Li 2021's MAXR/MINR are its max and min). Rows whose prediction is NaN
(rows of another channel than the model's) are not the model's rows and are left out; which rows were used
is counted in ``rows``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # for the hints only
    from host.data.runs import Errors

NO_CHANNEL = "error"  # the key of a run without an errors.csv channel column


def figures(measured: ArrayLike, predicted: ArrayLike) -> dict[str, Any]:
    """{rows, rmse_um, max_residual_um, min_residual_um, max_abs_residual_um, r2} of the finite pairs."""
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    ok = np.isfinite(measured) & np.isfinite(predicted)
    y, r = measured[ok], measured[ok] - predicted[ok]
    if not r.size:
        nan = float("nan")
        return {"rows": 0, "rmse_um": nan, "max_residual_um": nan, "min_residual_um": nan, "max_abs_residual_um": nan, "r2": nan}
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    # R² = 1 − SS_res/SS_tot of the measured values about their mean; undefined (NaN) for a constant measurement
    r2 = 1.0 - float(np.sum(r ** 2)) / ss_tot if ss_tot > 0 else float("nan")
    return {"rows": int(r.size), "rmse_um": float(np.sqrt(np.mean(r ** 2))), "max_residual_um": float(r.max()),
            "min_residual_um": float(r.min()), "max_abs_residual_um": float(np.abs(r).max()), "r2": r2}


def channel_rows(errors: Errors, predicted: ArrayLike) -> dict[str, np.ndarray]:
    """{channel name: row indices} of the rows with a finite prediction, in first-seen order."""
    ok = np.isfinite(np.asarray(predicted, dtype=float))
    if errors.channel is None:
        return {NO_CHANNEL: np.flatnonzero(ok)}
    out = {}
    for c in errors.channels():
        rows = np.flatnonzero(ok & (errors.channel == c))
        if rows.size:
            out[str(c)] = rows
    return out


def per_channel(errors: Errors, predicted: ArrayLike) -> dict[str, dict[str, Any]]:
    """{channel: figures(...)} over the rows ``channel_rows`` gives."""
    return {c: figures(errors.error_um[rows], np.asarray(predicted, dtype=float)[rows])
            for c, rows in channel_rows(errors, predicted).items()}
