"""Where does the held-out residual concentrate? Factor labels per row and variance shares.

Each error row gets labels for the factors a thermal engineer asks about: which
run, which moving state came last before the sweep, warm-up or cool-down, how
far from the fixed end, which direction. For each factor the share of residual
variance it explains is the correlation ratio eta^2 = SS_between / SS_total
(about the overall mean). Two structured factors are added: ``offset`` (share of
the mean square that is one constant bias) and ``slope_in_position`` (share of
the variance a straight line in position, fitted per sweep, explains: the mark
of a missing expansion term).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any
from typing import TYPE_CHECKING
import numpy as np

from host.learning.discrepancy.stats import sweep_ids

if TYPE_CHECKING:
    from host.data.runs import Run

ZONES = ("near", "middle", "far")


def _fixed_end(run):
    screw = run.meta.get("screw") or {}
    return float(screw.get("fixed_end_mm", 0.0) or 0.0)


def _state_label(iv, motion):
    return "%g mm/min %g-%g mm" % (motion.feed_mm_min[iv], min(motion.from_mm[iv], motion.to_mm[iv]), max(motion.from_mm[iv], motion.to_mm[iv]))


def row_factors(run: Run) -> dict[str, np.ndarray]:
    """Labels per error row of ``run``: dict factor -> array of str."""
    e = run.errors
    n = len(e)
    out = {"run": np.full(n, run.name, dtype=object)}
    m = run.motion
    state = np.full(n, "idle", dtype=object)
    phase = np.full(n, "cold", dtype=object)
    if m is not None and len(m):
        last_end = float(np.max(m.t_end_s))
        for i, t in enumerate(e.time_s):
            started = np.flatnonzero(m.t_start_s <= t)
            if started.size:
                iv = started[-1]
                state[i] = _state_label(iv, m)
                phase[i] = "cool-down" if t >= last_end else "warm-up"
    out["state"] = state
    out["phase"] = phase
    x = e.position_mm - _fixed_end(run)
    ax = np.abs(x)
    lo, hi = (float(ax.min()), float(ax.max())) if n else (0.0, 1.0)
    span = hi - lo if hi > lo else 1.0
    k = np.clip(((ax - lo) / span * 3).astype(int), 0, 2)
    out["zone"] = np.asarray([ZONES[j] for j in k], dtype=object)
    if e.direction is not None:
        out["direction"] = np.asarray(["%+d" % d for d in e.direction], dtype=object)
    return out


def eta_squared(values: np.ndarray, labels: np.ndarray) -> tuple[float, list[Any]]:
    """Share of the variance of ``values`` explained by the group means of ``labels``."""
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    v, labels = v[ok], np.asarray(labels)[ok]
    tot = float(np.sum((v - v.mean()) ** 2)) if v.size else 0.0
    if tot <= 0:
        return 0.0, []
    groups = []
    between = 0.0
    for lev in dict.fromkeys(labels.tolist()):
        sel = labels == lev
        g = v[sel]
        between += g.size * (g.mean() - v.mean()) ** 2
        groups.append({"level": str(lev), "n": int(g.size), "mean_um": float(g.mean()), "rms_um": float(np.sqrt(np.mean(g ** 2)))})
    return float(between / tot), groups


def _slope_share(runs, residuals):
    """Share of the residual variance explained by a per-sweep straight line in position."""
    tot = 0.0
    expl = 0.0
    allr = np.concatenate([np.asarray(r, dtype=float) for r in residuals])
    mu = float(np.nanmean(allr)) if allr.size else 0.0
    for run, r in zip(runs, residuals):
        r = np.asarray(r, dtype=float)
        ok = np.isfinite(r)
        x = run.errors.position_mm
        ids = sweep_ids(run.errors.time_s)
        tot += float(np.sum((r[ok] - mu) ** 2))
        for s in np.unique(ids[ok]):
            sel = ok & (ids == s)
            if sel.sum() < 3:
                continue
            xs = x[sel] - x[sel].mean()
            den = float(np.dot(xs, xs))
            if den <= 0:
                continue
            b = float(np.dot(xs, r[sel])) / den
            expl += b * b * den
    return expl / tot if tot > 0 else 0.0


def localize(runs: Sequence[Run], residuals: Sequence[np.ndarray]) -> list[dict[str, Any]]:
    """Localization table: list of {factor, share, groups[, worst]}, largest share first.

    ``residuals``: one array per run, aligned with ``run.errors`` (NaN = not scored).
    """
    facs = [row_factors(r) for r in runs]
    names = []
    for f in facs:
        for k in f:
            if k not in names:
                names.append(k)
    allr = np.concatenate([np.asarray(r, dtype=float) for r in residuals])
    out = []
    for name in names:
        labels = np.concatenate([f.get(name, np.full(len(r.errors), "n/a", dtype=object)) for f, r in zip(facs, runs)])
        share, groups = eta_squared(allr, labels)
        if len(groups) < 2:
            continue
        worst = max(groups, key=lambda g: g["rms_um"])["level"]
        out.append({"factor": name, "share": share, "worst": worst, "groups": groups})
    ok = np.isfinite(allr)
    ms = float(np.mean(allr[ok] ** 2)) if ok.any() else 0.0
    if ms > 0:
        out.append({"factor": "offset", "share": float(np.mean(allr[ok]) ** 2 / ms), "worst": None,
                    "groups": [{"level": "all", "n": int(ok.sum()), "mean_um": float(np.mean(allr[ok])), "rms_um": float(np.sqrt(ms))}]})
    out.append({"factor": "slope_in_position", "share": float(_slope_share(runs, residuals)), "worst": None, "groups": []})
    out.sort(key=lambda d: -d["share"])
    return out


def residual_map(run: Run, residual: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Residual on a (sweep time x position) grid per direction, for plots.

    Returns dict direction -> (times_s, positions_mm, grid[n_times, n_positions]) with NaN holes.
    """
    e = run.errors
    r = np.asarray(residual, dtype=float)
    dirs = [0] if e.direction is None else sorted(set(int(d) for d in e.direction))
    out = {}
    for d in dirs:
        sel = np.ones(len(e), bool) if e.direction is None else (e.direction == d)
        t = np.unique(e.time_s[sel])
        p = np.unique(np.round(e.position_mm[sel], 3))
        grid = np.full((t.size, p.size), np.nan)
        ti = np.searchsorted(t, e.time_s[sel])
        pi = np.searchsorted(p, np.round(e.position_mm[sel], 3))
        grid[ti, pi] = r[sel]
        out[d] = (t, p, grid)
    return out
