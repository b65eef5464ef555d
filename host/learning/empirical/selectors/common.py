"""What every selector shares: the result type, the error type, input checking."""

from __future__ import annotations

from collections.abc import Mapping

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from host.learning.empirical import EmpiricalDataError


class SelectionError(EmpiricalDataError):
    """Input a selector cannot work with; the message names the sensor, run or parameter."""


@dataclass
class Selection:
    """The chosen sensors, the method, the numbers behind the choice, and a plot."""

    sensors: list
    method: str
    reason: dict
    _plotter: object = field(default=None, repr=False, compare=False)

    def plot(self, path: str) -> str:
        """Write a PNG explaining the choice to ``path``; returns ``path``."""
        if self._plotter is None:
            raise SelectionError("this %s selection carries no plot data" % self.method)
        self._plotter(path)
        return path

    def to_json(self) -> dict[str, Any]:
        """Strict-JSON dict: numpy scalars become Python numbers, inf/NaN become None."""
        return plain({"method": self.method, "sensors": list(self.sensors), "reason": self.reason})


def plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def _is_run(obj):
    return hasattr(obj, "temperatures") and hasattr(obj, "errors")


def as_arrays(data: Any, target: str = "slope", channel: str | None = None, sensors: Any = None) -> tuple[list[Any], list[str]]:
    """Normalise runs or ``(X, y, names)`` tuples to a checked list of tuples plus run labels."""
    # list[Any]: (X, y, names) tuples, or targets.RunArrays (which unpack as one and carry the temperature log)
    if _is_run(data) or (hasattr(data, "X") and hasattr(data, "y")):
        data = [data]  # one Run or one targets.RunArrays
    elif isinstance(data, tuple) and len(data) == 3 and not _is_run(data[0]) and np.ndim(data[0]) == 2:
        data = [data]
    data = list(data)
    if not data:
        raise SelectionError("no runs given")
    if all(_is_run(r) for r in data):
        from host.learning.empirical.targets import training_arrays

        labels = [getattr(r, "name", None) or "run %d" % (i + 1) for i, r in enumerate(data)]
        try:
            arrays = training_arrays(data, target=target, channel=channel, sensors=sensors)
        except EmpiricalDataError as exc:
            raise SelectionError(str(exc)) from exc
    elif any(_is_run(r) for r in data):
        raise SelectionError("mix of run folders and arrays; give one kind")
    else:
        arrays = data
        # targets.RunArrays carry their run's name; plain tuples get a position
        labels = [a.run if isinstance(getattr(a, "run", None), str) else "run %d" % (i + 1) for i, a in enumerate(data)]
        if sensors is not None:
            arrays = [_subset(a, sensors, labels[i]) for i, a in enumerate(arrays)]
    checked = [_keep_start(check_arrays(a, labels[i]), a) for i, a in enumerate(arrays)]
    names = checked[0][2]
    for (_, _, other), label in zip(checked[1:], labels[1:]):
        if other != names:
            raise SelectionError("%s has sensors %s but %s has %s; every run needs the same sensors in the same order" % (label, ",".join(other), labels[0], ",".join(names)))
    return checked, labels


def _subset(arr, sensors, label):
    X, y, names = arr
    names = list(names)
    missing = [s for s in sensors if s not in names]
    if missing:
        raise SelectionError("%s has no sensor %s (has %s)" % (label, ", ".join(missing), ",".join(names)))
    idx = [names.index(s) for s in sensors]
    start = getattr(arr, "start", None)
    log = arr.log_columns(idx) if hasattr(arr, "log_columns") else None
    return _keep_start((np.asarray(X, dtype=float)[:, idx], y, list(sensors)), arr, None if start is None else np.asarray(start)[idx], log)


_SAME = object()  # _keep_start: the original's log, its columns unchanged


def _keep_start(checked, original, start=None, log=_SAME):
    """``checked`` (X, y, names) keeps the start temperatures and the temperature log of a RunArrays
    (rises -> measured values; the whole log for correlations and distances)."""
    from host.learning.empirical.targets import RunArrays

    start = getattr(original, "start", None) if start is None else start
    log = getattr(original, "log", None) if log is _SAME else log
    if start is None and log is None:
        return checked
    X, y, names = checked
    return RunArrays(X, y, names, getattr(original, "time_s", None), getattr(original, "run", None),
                     None if start is None else np.asarray(start, dtype=float), log)


def check_arrays(arr: Any, label: str = "data") -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Return ``(X, y, names)`` as float arrays and a list, or raise naming the problem."""
    try:
        X, y, names = arr
    except (TypeError, ValueError):
        raise SelectionError("%s: expected (X, y, names), got %r" % (label, type(arr).__name__))
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float).ravel()
    names = [str(n) for n in names]
    if X.ndim != 2:
        raise SelectionError("%s: temperatures must be a 2-D array (samples x sensors), got shape %s" % (label, X.shape))
    n, p = X.shape
    if p != len(names):
        raise SelectionError("%s: %d sensor names for %d temperature columns" % (label, len(names), p))
    if len(set(names)) != p:
        dup = sorted({s for s in names if names.count(s) > 1})
        raise SelectionError("%s: sensor name(s) %s appear more than once" % (label, ", ".join(dup)))
    if p == 0:
        raise SelectionError("%s: no sensors" % label)
    if y.size != n:
        raise SelectionError("%s: %d target values for %d temperature samples" % (label, y.size, n))
    if n < 3:
        raise SelectionError("%s: %d samples; at least 3 are needed to estimate a correlation or a regression" % (label, n))
    bad = ~np.isfinite(X)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise SelectionError("%s: sensor %s has a non-finite value (%r) at sample %d (%d bad values in all)" % (label, names[j], X[i, j], i + 1, int(bad.sum())))
    if not np.isfinite(y).all():
        i = int(np.flatnonzero(~np.isfinite(y))[0])
        raise SelectionError("%s: the target has a non-finite value (%r) at sample %d" % (label, y[i], i + 1))
    span = X.max(axis=0) - X.min(axis=0)
    scale = np.maximum(np.abs(X).max(axis=0), 1.0)
    const = np.flatnonzero(span <= 1e-12 * scale)
    if const.size:
        raise SelectionError("%s: sensor(s) %s are constant (zero variance): they carry no information and make correlations undefined; drop them with sensors=..." % (label, ", ".join(names[j] for j in const)))
    if np.ptp(y) <= 1e-12 * max(np.abs(y).max(), 1.0):
        raise SelectionError("%s: the target is constant; there is nothing to explain" % label)
    return X, y, names


def pooled(arrays: list[tuple[np.ndarray, np.ndarray, list[str]]]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """All runs stacked: the sample correlations and the stepwise fit use every sample."""
    X = np.vstack([a[0] for a in arrays])
    y = np.concatenate([a[1] for a in arrays])
    return X, y, list(arrays[0][2])


def check_params(method: str, params: Mapping[str, Any], allowed: Mapping[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise SelectionError("%s: unknown parameter(s) %s (known: %s)" % (method, ", ".join(unknown), ", ".join(sorted(allowed))))
    out = dict(allowed)
    out.update(params)
    return out


def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, integer: bool = False, allow_none: bool = False) -> Any:
    """A numeric parameter checked against its range (CLI --option values arrive as JSON)."""
    # -> Any: an int when ``integer``, else a float, None only when ``allow_none``: each caller knows which it asked for
    if value is None and allow_none:
        return None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok and lo is not None:
        ok = value >= lo
    if ok and hi is not None:
        ok = value <= hi
    if not ok:
        rng = "%s%s" % ("" if lo is None else ">= %g" % lo, "" if hi is None else (" and " if lo is not None else "") + "<= %g" % hi)
        raise SelectionError("%s: %s must be %s%s, got %r" % (method, name, "an integer" if integer else "a number", " " + rng if rng else "", value))
    return int(value) if integer else float(value)


def data_label(context: Mapping[str, Any] | None, n_samples: int) -> str:
    ctx = context or {}
    runs = ctx.get("runs") or []
    what = ctx.get("target") or "target"
    if ctx.get("channel"):
        what += " of channel %s" % ctx["channel"]
    runs_s = ", ".join(runs[:4]) + (" +%d" % (len(runs) - 4) if len(runs) > 4 else "")
    return "%s; %d training samples; runs %s" % (what, n_samples, runs_s or "given as arrays")
