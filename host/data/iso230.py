"""The thermal-drift figures of ISO 230-3 (Clause 7, thermal distortion caused by moving linear axes; Clause 5,
ETVE) computed from a run's errors.csv: the one place `tcomp report` takes its numbers from (docs/report.md says
which of the standard's clauses these follow and which not).

Every figure is computed per group of rows that measure the same thing: one errors.csv channel and one
approach direction. Within a group, each target position's deviations over time form its drift curve:

- ``drift_um`` of a position at time t: its deviation at t minus its deviation at the group's first
  measurement (ISO 230-3's drift is the change from the start of the test);
- ``max_drift_um``: the largest |drift| over the test (signed value kept in ``max_drift_signed_um``);
- ``drift_range_um``: max − min of the position's deviations over the test;
- ``positioning_change_um``: at each time, (deviation at the last target − at the first target) minus the same
  at the start: the change of the positioning error between the two end targets, the axis's thermal expansion
  as ISO 230-3 Clause 7 reads it off the two positions; ``max_positioning_change_um`` its largest |value|;
- ``max_deviation_range_um``: the largest drift range over all positions, the ETVE-style figure (Clause 5's
  ETVE is this range over a test where only the environment changes: ``etve_applicable`` says whether the run
  had no motion and no spindle, as Clause 5 requires).

The same functions give the figures of residuals (measured − predicted): "after compensation".
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # for the hints only: this module imports nothing of tcomp at run time
    from host.data.runs import Errors, Run

POSITION_DECIMALS = 3  # targets closer than 1 µm are one target (laser software writes them rounded)


def groups(errors: Errors) -> list[tuple[str, np.ndarray]]:
    """[(label, row indices)] per (channel, direction) of errors.csv, in first-seen order."""
    keys = []
    labels = []
    for i in range(len(errors)):
        parts = []
        if errors.channel is not None:
            parts.append(str(errors.channel[i]))
        if errors.direction is not None:
            parts.append("forward" if errors.direction[i] > 0 else "reverse")
        keys.append(" ".join(parts) or "error")
    out = {}
    for i, k in enumerate(keys):
        if k not in out:
            labels.append(k)
        out.setdefault(k, []).append(i)
    return [(k, np.asarray(out[k])) for k in labels]


def drift_table(time_s: np.ndarray, position_mm: np.ndarray, value_um: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, positions, matrix[time, position]) of one group's values (NaN where a position was not measured)."""
    pos = np.round(np.asarray(position_mm, dtype=float), POSITION_DECIMALS)
    times = np.unique(time_s)
    targets = np.unique(pos)
    m = np.full((times.size, targets.size), np.nan)
    ti = np.searchsorted(times, time_s)
    pi = np.searchsorted(targets, pos)
    m[ti, pi] = value_um  # a repeated (time, target) keeps the last row, as a sweep that re-measured a target
    return times, targets, m


def drift_figures(time_s: np.ndarray, position_mm: np.ndarray, value_um: np.ndarray) -> dict[str, Any]:
    """The figures of the module doc for one group of rows (values: deviations, or residuals)."""
    times, targets, m = drift_table(time_s, position_mm, value_um)
    per_position = []
    for j, p in enumerate(targets):
        col = m[:, j]
        ok = np.flatnonzero(np.isfinite(col))
        if ok.size == 0:
            continue
        drift = col[ok] - col[ok[0]]
        k = int(np.argmax(np.abs(drift)))
        per_position.append({"position_mm": float(p), "measurements": int(ok.size),
                             "start_um": float(col[ok[0]]), "max_drift_um": float(abs(drift[k])),
                             "max_drift_signed_um": float(drift[k]), "at_time_s": float(times[ok[k]]),
                             "drift_range_um": float(col[ok].max() - col[ok].min())})
    out = {"times": int(times.size), "positions": per_position,
           "max_deviation_range_um": max((p["drift_range_um"] for p in per_position), default=float("nan")),
           "max_drift_um": max((p["max_drift_um"] for p in per_position), default=float("nan"))}
    if targets.size >= 2:
        both = np.flatnonzero(np.isfinite(m[:, 0]) & np.isfinite(m[:, -1]))
        if both.size:
            span = m[both, -1] - m[both, 0]
            change = span - span[0]
            k = int(np.argmax(np.abs(change)))
            out["positioning_change"] = {"from_mm": float(targets[0]), "to_mm": float(targets[-1]),
                                         "max_positioning_change_um": float(abs(change[k])),
                                         "signed_um": float(change[k]), "at_time_s": float(times[both[k]])}
    return out


def etve_applicable(run: Run) -> tuple[bool, str]:
    """(bool, why): Clause 5's ETVE needs the machine standing still while only the environment changes."""
    moving = run.motion is not None and len(run.motion) > 0
    spinning = run.spindle is not None and np.any(np.asarray(run.spindle.rpm) != 0)
    if moving or spinning:
        return False, "the run %s: its deviation range is thermal drift under operation, not ETVE" % (
            "moves the axis (motion.csv)" if moving else "runs the spindle (spindle.csv)")
    return True, "no motion and no spindle in the run: the range is an ETVE-style figure"
