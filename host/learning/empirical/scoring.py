"""Evaluate a fitted model on a run, and disturb runs for robustness.

Thermal error compared (µm, per errors.csv row):

* ``poly_slope``: measured thermal error e_i(P) − e_0(P), with e_0 the run's own
  cold sweep of the same direction (linearly interpolated in P), against the
  model's thermal part s(T)·P. Judging the thermal part against the run's own
  cold sweep keeps the geometric polynomial's error (a different job) out of the
  comparison; the cold sweep rows themselves are excluded.
* ``linear_direct``: the measured error of the model's channel against the
  prediction.

Metrics: RMSE, max and min residual (measured − predicted), RMS of the measured
thermal error and accuracy = (1 − RMSE / RMS(measured)) · 100 %.

The accuracy is **this project's definition**. The papers quote "fitting
accuracy 89 % / prediction accuracy 86 %" without defining it, and their figures
show the comprehensive error (geometric + thermal). So :func:`score_model` also
reports ``comprehensive``: the same metrics on the whole measured error of the
same rows against the whole prediction (``model.predict``: geometric polynomial
+ thermal part for ``poly_slope``; for ``linear_direct`` there is no geometric
part and both are the same numbers).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import copy

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.targets import in_window, sweep_slopes

if TYPE_CHECKING:
    from host.data.runs import Run


def metrics(measured: ArrayLike, predicted: ArrayLike) -> dict[str, Any]:
    """RMSE, max/min residual, RMS(measured), accuracy % and n of measured − predicted."""
    m = np.asarray(measured, dtype=float)
    p = np.asarray(predicted, dtype=float)
    r = m - p
    if r.size == 0:
        raise EmpiricalDataError("evaluation: no sample to evaluate")
    rmse = float(np.sqrt(np.mean(r**2)))
    rms = float(np.sqrt(np.mean(m**2)))
    return {
        "n": int(r.size),
        "rmse_um": rmse,
        "max_residual_um": float(r.max()),
        "min_residual_um": float(r.min()),
        "rms_measured_um": rms,
        "accuracy_pct": float(100.0 * (1.0 - rmse / rms)) if rms > 0 else None,
    }


def thermal_pairs(model: Any, run: Run, window: tuple[float | None, float | None] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(time_s, position_mm, measured thermal error, predicted thermal error) over the evaluated rows."""
    rows, measured, pred = _thermal_rows(model, run, window)
    return run.errors.time_s[rows], run.errors.position_mm[rows], measured, pred


def _thermal_rows(model, run, window=None):
    """(errors.csv row indices, measured thermal error, predicted thermal error) over the evaluated rows."""
    e = run.errors
    if model.target == "slope":
        s = sweep_slopes(run, model.channel)
        cold = {}
        for d, rows in zip(s.direction, s.rows):
            cold.setdefault(int(d), rows)
        idx, meas = [], []
        for d, rows in zip(s.direction, s.rows):
            c = cold[int(d)]
            if rows is c:
                continue
            order = np.argsort(e.position_mm[c])
            e0 = np.interp(e.position_mm[rows], e.position_mm[c][order], e.error_um[c][order])
            idx.append(rows)
            meas.append(e.error_um[rows] - e0)
        if not idx:
            raise EmpiricalDataError("%s: only the cold sweep was measured; nothing thermal to evaluate" % run.name)
        rows = np.concatenate(idx)
        measured = np.concatenate(meas)
        P = e.position_mm[rows]
        pred = model.thermal_at(run, e.time_s[rows]) * P
    else:
        rows = model._rows(run)
        measured = e.error_um[rows]
        pred = model.thermal_at(run, e.time_s[rows])
    t = e.time_s[rows]
    if window is not None:
        keep = in_window(t, window)
        if not keep.any():
            raise EmpiricalDataError("%s: no row in the evaluation window %s..%s s" % ((run.name,) + tuple(window)))
        rows, measured, pred = rows[keep], measured[keep], pred[keep]
    return rows, measured, pred


def score_model(model: Any, run: Run, window: tuple[float | None, float | None] | None = None) -> dict[str, Any]:
    """Metrics of ``model`` on ``run`` (optionally only rows with lo <= time_s < hi).

    The thermal metrics at the top level; ``comprehensive``: the same metrics on the
    whole error (geometric + thermal) of the same rows.
    """
    rows, m, p = _thermal_rows(model, run, window)
    out = metrics(m, p)
    out["comprehensive"] = metrics(run.errors.error_um[rows], model.predict(run)[rows]) if model.target == "slope" else dict(metrics(m, p))
    return out


def disturb_run(run: Run, noise_C: float = 0.0, offset_C: float = 0.0, seed: int = 0) -> Run:
    """A copy of ``run`` whose temperatures carry sensor disturbances.

    ``noise_C``: independent Gaussian noise of that standard deviation on every
    sample except the first. ``offset_C``: each sensor gets a constant offset
    drawn uniformly from ±offset_C, applied from the second sample on, i.e. a
    calibration shift after the rise reference was latched (an offset present
    from the start would cancel out of rises). The first sample is left
    untouched so the rise reference is the clean cold start.
    """
    rng = np.random.default_rng(seed)
    r = copy.copy(run)
    t = copy.copy(run.temperatures)
    v = np.array(t.values, dtype=float, copy=True)
    if noise_C:
        v[1:] += rng.normal(0.0, noise_C, size=v[1:].shape)
    if offset_C:
        v[1:] += rng.uniform(-offset_C, offset_C, size=v.shape[1])
    t.values = v
    r.temperatures = t
    r.name = "%s+disturbed" % run.name
    return r
