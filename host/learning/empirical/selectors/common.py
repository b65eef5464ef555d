"""What every selector shares: the result type, the error type, input checking."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from dataclasses import dataclass, field
from typing import Any, Literal, overload

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
    _plotter: Callable[[str], object] | None = field(default=None, repr=False, compare=False)

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
    return _keep_start((np.asarray(X, dtype=float)[:, idx], y, list(sensors)), arr, idx)


def _keep_start(checked, original, columns=None):
    """``checked`` (X, y, names) keeps the start temperatures and the temperature log of a RunArrays
    (rises -> measured values; the whole log for correlations and distances), of its sensors ``columns``
    when given (_subset); a plain tuple, or a RunArrays with neither, stays a plain tuple."""
    from host.learning.empirical.targets import RunArrays

    if not isinstance(original, RunArrays):
        return checked
    start, log = original.start, original.log
    if columns is not None:
        start = None if start is None else np.asarray(start)[columns]
        log = original.log_columns(columns)
    if start is None and log is None:
        return checked
    X, y, names = checked
    return RunArrays(X, y, names, original.time_s, original.run, None if start is None else np.asarray(start, dtype=float), log)


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


# The overloads give each caller the type it asked for (an int when ``integer``, None only with ``allow_none``)
@overload
def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           integer: Literal[True], allow_none: Literal[False] = False) -> int: ...
@overload
def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           integer: Literal[True], allow_none: Literal[True]) -> int | None: ...
@overload
def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           integer: Literal[False] = False, allow_none: Literal[False] = False) -> float: ...
@overload
def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           integer: Literal[False] = False, allow_none: Literal[True]) -> float | None: ...
def number(method: str, name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           integer: bool = False, allow_none: bool = False) -> int | float | None:
    """A numeric parameter checked against its range (CLI --option values arrive as JSON): an int when
    ``integer``, else a float; None only when ``allow_none`` and ``value`` is None."""
    if value is None and allow_none:
        return None
    checked = _finite_number(value)
    ok = checked is not None
    if checked is not None and integer:
        ok = float(checked).is_integer()
    if checked is not None and lo is not None:
        ok = ok and checked >= lo
    if checked is not None and hi is not None:
        ok = ok and checked <= hi
    if checked is None or not ok:
        rng = "%s%s" % ("" if lo is None else ">= %g" % lo, "" if hi is None else (" and " if lo is not None else "") + "<= %g" % hi)
        raise SelectionError("%s: %s must be %s%s, got %r" % (method, name, "an integer" if integer else "a number", " " + rng if rng else "", value))
    return int(checked) if integer else float(checked)


def _finite_number(value: object) -> int | float | None:
    """``value`` when it is a finite int or float (a bool is not a number here), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        as_float = float(value)
    except OverflowError:  # an int beyond the float range (JSON allows any digits): no parameter here means that
        return None
    return value if math.isfinite(as_float) else None


def data_label(context: Mapping[str, Any] | None, n_samples: int) -> str:
    ctx = context or {}
    runs = ctx.get("runs") or []
    what = ctx.get("target") or "target"
    if ctx.get("channel"):
        what += " of channel %s" % ctx["channel"]
    runs_s = ", ".join(runs[:4]) + (" +%d" % (len(runs) - 4) if len(runs) > 4 else "")
    return "%s; %d training samples; runs %s" % (what, n_samples, runs_s or "given as arrays")
