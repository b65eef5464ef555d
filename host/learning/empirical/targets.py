"""What the empirical models are fitted to: targets and temperature features.

Two kinds of target, both functions of time within one run:

* **slope** (``poly_slope`` models): every measurement sweep of ``errors.csv``
  (one group of :meth:`host.data.runs.Errors.sweeps`: one time stamp, channel and
  direction) gets a first-order least-squares line ``error = a_i + k_i·P``;
  the target is the thermal slope change ``k_i − k_0`` in µm/mm, with ``k_0``
  the slope of the *cold sweep*, the first sweep of the run in file order.
  Bidirectional data: each direction is fitted separately and has its own cold
  sweep (the first sweep of that direction), so the backlash and the
  direction-dependent geometric slope cancel out of ``k_i − k_0``; the targets
  of both directions are then pooled, which is least-squares equivalent to
  averaging the two directions when they are measured at the same times.
* **direct** (``linear_direct`` models): the error of one channel at one fixed
  point (e.g. spindle growth), as measured, one target per row.

Temperature features are the sensors linearly interpolated at the target times,
by default as *rises* over the run's first temperature sample (the cold start),
which is how the published slope and spindle models are formulated and what
makes a model portable between runs started at different ambient temperatures.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

from dataclasses import dataclass

import numpy as np

from host.data.runs import common_error_reference
from host.learning.empirical import EmpiricalDataError

if TYPE_CHECKING:
    from host.data.runs import Run

TARGETS = ("slope", "direct")


def _channel_rows(run, channel):
    """Row indices of ``run.errors`` for ``channel`` (None: the only channel, or all rows)."""
    e = run.errors
    if e.channel is None:
        if channel is not None:
            raise EmpiricalDataError("%s: errors.csv has no 'channel' column, cannot select channel %r" % (run.name, channel))
        return np.arange(len(e))
    chans = e.channels()
    if channel is None:
        if len(chans) == 1:
            return np.arange(len(e))
        raise EmpiricalDataError("%s: errors.csv has %d channels (%s); name one with channel=... (--channel)" % (run.name, len(chans), ", ".join(chans)))
    if channel not in chans:
        raise EmpiricalDataError("%s: channel %r is not in errors.csv (channels: %s)" % (run.name, channel, ", ".join(chans)))
    return np.flatnonzero(e.channel == channel)


@dataclass
class SweepSlopes:
    """Per-sweep first-order fits of one run (see module docstring)."""

    run: str
    time_s: np.ndarray  # (n,) sweep time
    slope_um_per_mm: np.ndarray  # (n,) k_i
    intercept_um: np.ndarray  # (n,) a_i
    direction: np.ndarray  # (n,) +1/-1, or 0 for unidirectional data
    k0_um_per_mm: dict  # {direction: k_0}
    rows: list  # row indices of errors.csv per sweep

    @property
    def target(self) -> np.ndarray:
        """Thermal slope targets k_i − k_0 (µm/mm), k_0 per direction."""
        k0 = np.array([self.k0_um_per_mm[int(d)] for d in self.direction])
        return self.slope_um_per_mm - k0


def sweep_slopes(run: Run, channel: str | None = None) -> SweepSlopes:
    """First-order fit of every sweep of ``run`` -> :class:`SweepSlopes`, in time order.

    Raises EmpiricalDataError when a sweep has fewer than two distinct positions
    (no slope can be fitted) or the run has no sweep at all.
    """
    e = run.errors
    keep = set(_channel_rows(run, channel).tolist())
    sweeps = [rows for rows in e.sweeps() if int(rows[0]) in keep]
    if not sweeps:
        raise EmpiricalDataError("%s: no measurement sweep in errors.csv%s" % (run.name, "" if channel is None else " for channel %r" % channel))
    times, slopes, inters, dirs = [], [], [], []
    for rows in sweeps:
        p = e.position_mm[rows]
        y = e.error_um[rows]
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(y))):
            raise EmpiricalDataError("%s: sweep at t=%g s (errors.csv lines %d..%d) contains NaN" % (run.name, e.time_s[rows[0]], rows[0] + 2, rows[-1] + 2))
        if np.unique(p).size < 2:
            raise EmpiricalDataError(
                "%s: sweep at t=%g s (errors.csv lines %d..%d) has %d distinct position(s); a slope needs at least 2 "
                "(single-point data is a direct target: use --direct)" % (run.name, e.time_s[rows[0]], rows[0] + 2, rows[-1] + 2, np.unique(p).size)
            )
        k, a = np.polyfit(p, y, 1)
        times.append(float(np.mean(e.time_s[rows])))
        slopes.append(k)
        inters.append(a)
        dirs.append(int(e.direction[rows[0]]) if e.direction is not None else 0)
    order = np.argsort(np.asarray(times), kind="stable")
    times = np.asarray(times)[order]
    slopes = np.asarray(slopes)[order]
    inters = np.asarray(inters)[order]
    dirs = np.asarray(dirs, dtype=int)[order]
    rows = [sweeps[i] for i in order]
    k0 = {}
    for d, k in zip(dirs, slopes):
        k0.setdefault(int(d), float(k))  # first sweep of each direction = cold sweep
    return SweepSlopes(run.name, times, slopes, inters, dirs, k0, rows)


def direct_targets(run: Run, channel: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Times and measured errors (µm) of one channel at a fixed point -> (time_s, error_um).

    The channel's rows must all be at one position (a direct model has no
    position term); otherwise EmpiricalDataError suggests the slope model.
    """
    rows = _channel_rows(run, channel)
    e = run.errors
    if rows.size == 0:
        raise EmpiricalDataError("%s: no error rows%s" % (run.name, "" if channel is None else " for channel %r" % channel))
    pos = np.unique(e.position_mm[rows])
    if pos.size > 1:
        raise EmpiricalDataError(
            "%s: channel %s is measured at %d positions (%g..%g mm); a direct model needs one fixed point "
            "(use the poly_slope model for position-dependent errors)" % (run.name, channel or "(all rows)", pos.size, pos.min(), pos.max())
        )
    t = e.time_s[rows]
    y = e.error_um[rows]
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise EmpiricalDataError("%s: errors.csv line %d: error_um is NaN" % (run.name, rows[bad[0]] + 2))
    return t.astype(float), y.astype(float)


def temperature_features(run: Run, sensors: Sequence[str], times: ArrayLike, rise: bool = True) -> np.ndarray:
    """Temperatures of ``sensors`` linearly interpolated at ``times`` -> (n, p).

    ``rise=True`` subtracts each sensor's first sample of the run (the cold
    start). Times outside the logged temperature span are an error (no
    extrapolation), as are unknown sensors and non-finite values.
    """
    temps = run.temperatures
    sensors = list(sensors)
    missing = [s for s in sensors if s not in temps.names]
    if missing:
        raise EmpiricalDataError("%s: sensor(s) %s not in temperatures.csv (has %s)" % (run.name, ", ".join(missing), ", ".join(temps.names)))
    times = np.atleast_1d(np.asarray(times, dtype=float))
    t0, t1 = temps.time_s[0], temps.time_s[-1]
    outside = np.flatnonzero((times < t0) | (times > t1))
    if outside.size:
        raise EmpiricalDataError(
            "%s: target time %g s is outside the temperature log %g..%g s (no extrapolation)" % (run.name, times[outside[0]], t0, t1)
        )
    cols = [temps.names.index(s) for s in sensors]
    raw = temps.values[:, cols]
    bad = np.argwhere(~np.isfinite(raw))
    if bad.size:
        i, j = bad[0]
        raise EmpiricalDataError("%s: temperatures.csv line %d sensor %s is not finite" % (run.name, i + 2, sensors[j]))
    X = np.empty((times.size, len(sensors)))
    for j in range(len(sensors)):
        X[:, j] = np.interp(times, temps.time_s, raw[:, j])
    if rise:
        X -= raw[0]
    return X


def start_temperatures(run: Run, sensors: Sequence[str]) -> np.ndarray:
    """Each sensor's first sample of the run (the reference of the rises), °C."""
    temps = run.temperatures
    return np.array([temps.column(s)[0] for s in sensors], dtype=float)


def targets(run: Run, target: str = "slope", channel: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, y) of one run for ``target`` in TARGETS."""
    if target == "slope":
        s = sweep_slopes(run, channel)
        return s.time_s, s.target
    if target == "direct":
        return direct_targets(run, channel)
    raise ValueError("target must be one of %s (got %r)" % (", ".join(TARGETS), target))


def common_sensors(runs: Sequence[Run]) -> list[str]:
    """Sensors present in every run, in the first run's column order."""
    names = list(runs[0].temperatures.names)
    for r in runs[1:]:
        names = [n for n in names if n in r.temperatures.names]
    if not names:
        raise EmpiricalDataError("no temperature sensor is common to runs %s" % ", ".join(r.name for r in runs))
    return names


class RunArrays:
    """Design data of one run: unpacks as ``X, y, names``; also has ``time_s``, ``run`` and ``start``.

    ``start``: each sensor's first sample of the run (°C) when X holds rises, so
    ``X + start`` are the measured temperatures (hclust-ga's D_e uses them); None
    when X already holds measured values.
    ``log``: (time_s, X_log) the whole temperature log of the same sensors over the
    same span (every sample of temperatures.csv in the window, as X: rises or
    values), or None. The selectors' sensor-to-sensor correlations and distances use
    it (Li 2021 Eq. 11, Li 2017 D_e/D_r are computed on the temperature series).
    """

    __slots__ = ("X", "y", "names", "time_s", "run", "start", "log")

    def __init__(self, X: np.ndarray, y: np.ndarray, names: list[str], time_s: np.ndarray, run: str, start: np.ndarray | None = None, log: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.X, self.y, self.names, self.time_s, self.run, self.start, self.log = X, y, names, time_s, run, start, log

    def log_columns(self, idx: Any) -> tuple[np.ndarray, np.ndarray] | None:
        """``log`` restricted to the columns ``idx`` (None stays None)."""
        return None if self.log is None else (self.log[0], self.log[1][:, idx])

    @property
    def values(self) -> np.ndarray:
        """The measured temperatures (rises plus the start temperatures)."""
        return self.X if self.start is None else self.X + self.start

    def __iter__(self) -> Iterator[Any]:
        return iter((self.X, self.y, self.names))

    def __len__(self) -> int:
        return 3

    def __getitem__(self, i: int) -> Any:
        return (self.X, self.y, self.names)[i]

    def __repr__(self) -> str:
        return "RunArrays(run=%r, n=%d, sensors=%d)" % (self.run, self.y.size, len(self.names))


def in_window(t: np.ndarray, window: tuple[float | None, float | None]) -> np.ndarray:
    """Mask of the times with lo <= t < hi for ``window`` = (lo, hi); either end may be None (unbounded)."""
    lo, hi = window
    keep = np.ones(np.shape(t), bool)
    if lo is not None:
        keep &= t >= lo
    if hi is not None:
        keep &= t < hi
    return keep


def training_arrays(runs: Sequence[Run], target: str = "slope", channel: str | None = None, sensors: Sequence[str] | None = None, rise: bool = True, window: tuple[float | None, float | None] | None = None, exclude: tuple[float | None, float | None] | None = None) -> list[RunArrays]:
    """Per run, the (X, y, names) a regression or selector is fitted on.

    ``sensors=None`` uses the sensors common to all runs. ``window=(lo, hi)``
    keeps targets with lo <= time_s < hi (either may be None), e.g. the
    training part of a single long run; ``exclude=(lo, hi)`` drops the targets
    in that span (a held-out cycle in the middle of a run); rises stay relative
    to the run start.
    Returns a list of :class:`RunArrays`, one per run, in the given order.
    """
    runs = list(runs)
    if not runs:
        raise EmpiricalDataError("no run given")
    try:
        common_error_reference(runs)  # one convention per fit (docs/data-format.md)
    except ValueError as exc:
        raise EmpiricalDataError(str(exc))
    names = common_sensors(runs) if sensors is None else list(sensors)
    if len(set(names)) != len(names):
        raise EmpiricalDataError("sensor list has duplicates: %s" % ", ".join(names))
    out = []
    for r in runs:
        t, y = targets(r, target, channel)
        if window is not None:
            keep = in_window(t, window)
            t, y = t[keep], y[keep]
            if t.size == 0:
                raise EmpiricalDataError("%s: no %s target in the time window %s..%s s" % ((r.name, target) + tuple(window)))
        if exclude is not None:
            lo, hi = exclude
            keep = ~in_window(t, exclude)
            t, y = t[keep], y[keep]
            if t.size == 0:
                raise EmpiricalDataError("%s: no %s target left outside the excluded span %s..%s s" % (r.name, target, lo, hi))
        X = temperature_features(r, names, t, rise=rise)
        out.append(RunArrays(X, y, list(names), t, r.name, start_temperatures(r, names) if rise else None,
                             temperature_log(r, names, window, exclude, rise)))
    return out


def temperature_log(run: Run, sensors: Sequence[str], window: tuple[float | None, float | None] | None = None, exclude: tuple[float | None, float | None] | None = None, rise: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
    """(time_s, (m, p)) every sample of temperatures.csv of ``sensors`` inside ``window`` and outside ``exclude``
    (rises over the run's first sample, or values); None when fewer than 3 samples remain."""
    temps = run.temperatures
    t = np.asarray(temps.time_s, dtype=float)
    keep = np.ones(t.size, bool) if window is None else in_window(t, window)
    if exclude is not None:
        keep &= ~in_window(t, exclude)
    if keep.sum() < 3:
        return None
    cols = [temps.names.index(s) for s in sensors]
    raw = temps.values[:, cols]
    V = raw[keep] - raw[0] if rise else raw[keep]
    return t[keep], np.asarray(V, dtype=float)


def stack(arrays: Sequence[RunArrays]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate several RunArrays (same sensors) -> (X, y)."""
    arrays = list(arrays)
    names = arrays[0].names
    for a in arrays[1:]:
        if a.names != names:
            raise EmpiricalDataError("runs %s and %s use different sensors" % (arrays[0].run, a.run))
    return np.vstack([a.X for a in arrays]), np.concatenate([a.y for a in arrays])
