"""Fuzzy clustering of sensors by the maximal-tree method, and selection by R² and F.

The Pearson correlation matrix is read as a fuzzy similarity relation. Its
maximum spanning tree (Prim, starting from sensor 1) carries everything the
λ-cuts of the relation's max-min transitive closure need: cutting the tree's
edges lighter than λ leaves exactly the closure's λ-cut classes. So the only λ
values where the partition changes are the tree's edge weights, and the full list
of distinct partitions over λ in [0, 1] comes from sorting them.

Interval convention, as Li 2021 (Table 3) writes it: a partition holds for λ in
[lambda_low, lambda_high); the last interval is closed at 1, [lambda_low, 1]. At λ
exactly equal to an edge weight that edge is cut (sensors i, j stay together when
their similarity is above λ); edges of weight 1 are never cut. (Before issue 23:
(lambda_low, lambda_high], the edge kept at equality; the interval ends are the
same numbers.)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from dataclasses import dataclass, field

import numpy as np

from host.learning.empirical.selectors.common import Selection, SelectionError, check_params, data_label, number, pooled
from host.learning.empirical.selectors.linalg import ols_stats

SYMMETRY_TOL = 1e-6  # published matrices are printed to 2-4 decimals; real asymmetry is larger


@dataclass
class Partition:
    lambda_low: float
    lambda_high: float
    clusters: list  # [[names]] members in sensor order, clusters by first member
    representatives: list  # one name per cluster, same order as clusters

    def to_json(self) -> dict[str, Any]:
        return {
            "lambda_low": self.lambda_low,
            "lambda_high": self.lambda_high,
            "clusters": [list(c) for c in self.clusters],
            "representatives": list(self.representatives),
        }


@dataclass
class MaxTree:
    names: list
    similarity: np.ndarray = field(repr=False)
    edges: list  # [(name_a, name_b, weight)] in the order Prim added them
    partitions: list  # [Partition] ordered by λ
    representative_rule: str

    def partition_at(self, lam: float) -> list[list[str]]:
        """Clusters (lists of names) from cutting the tree edges not heavier than ``lam`` (weight-1 edges are kept)."""
        return _components(self.names, [(self.names.index(a), self.names.index(b)) for a, b, w in self.edges if w > lam or w >= 1.0])

    def to_json(self) -> dict[str, Any]:
        return {
            "sensors": list(self.names),
            "edges": [[a, b, float(w)] for a, b, w in self.edges],
            "partitions": [p.to_json() for p in self.partitions],
            "representative_rule": self.representative_rule,
            "interval_convention": "lambda in [lambda_low, lambda_high) (Li 2021 Table 3); the last interval is [lambda_low, 1]",
        }

    def linkage(self) -> np.ndarray:
        """scipy linkage matrix of the tree (height 1 - weight): merges heaviest edge first."""
        p = len(self.names)
        idx = {n: i for i, n in enumerate(self.names)}
        parent = list(range(p))
        cid = list(range(p))  # scipy cluster id of each union-find root
        size = [1] * p

        def find(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        rows = []
        for a, b, w in sorted(self.edges, key=lambda e: -e[2]):
            ra, rb = find(idx[a]), find(idx[b])
            rows.append([min(cid[ra], cid[rb]), max(cid[ra], cid[rb]), 1.0 - w, size[ra] + size[rb]])
            parent[rb] = ra
            size[ra] += size[rb]
            cid[ra] = p + len(rows) - 1
        return np.asarray(rows, dtype=float).reshape(-1, 4)

    def plot(self, path: str, title: str | None = None, mark_lambda: float | None = None, ax: Any = None) -> str:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from scipy.cluster.hierarchy import dendrogram

        own = ax is None
        if own:
            fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(self.names) + 2), 4.5))
        if len(self.names) > 1:
            Z = self.linkage()
            # heights are 1 - λ; negative similarities give heights above 1, which scipy accepts
            dendrogram(Z, labels=list(self.names), ax=ax, leaf_rotation=90, color_threshold=None if mark_lambda is None else 1.0 - mark_lambda)
            ticks = ax.get_yticks()
            ax.set_yticks(ticks)
            ax.set_yticklabels(["%.2f" % (1.0 - t) for t in ticks])
        ax.set_ylabel("λ (similarity at which the clusters join)")
        if mark_lambda is not None:
            ax.axhline(1.0 - mark_lambda, color="k", ls="--", lw=0.8)
            ax.text(ax.get_xlim()[1], 1.0 - mark_lambda, " λ=%.3f" % mark_lambda, va="center", fontsize=8)
        ax.set_title(title or "Maximal tree of %d sensors (similarity from the correlation matrix)" % len(self.names))
        if own:
            fig.tight_layout()
            fig.savefig(path, dpi=110)
            plt.close(fig)
        return path


def _components(names, pairs):
    p = len(names)
    parent = list(range(p))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in pairs:
        ri, rj = find(i), find(j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    groups = {}
    for i in range(p):
        groups.setdefault(find(i), []).append(i)
    return [[names[i] for i in g] for g in sorted(groups.values(), key=lambda g: g[0])]


def check_corr(corr: Any, names: Sequence[str], source: str = "correlation matrix") -> np.ndarray:
    """Validate a square correlation matrix; returns it as float array."""
    names = [str(n) for n in names]
    C = np.asarray(corr, dtype=float)
    if C.ndim != 2 or C.shape[0] != C.shape[1]:
        raise SelectionError("%s: must be square, got shape %s" % (source, C.shape))
    if C.shape[0] != len(names):
        raise SelectionError("%s: %d names for a %dx%d matrix" % (source, len(names), C.shape[0], C.shape[1]))
    if len(set(names)) != len(names):
        raise SelectionError("%s: sensor name(s) %s appear more than once" % (source, ", ".join(sorted({n for n in names if names.count(n) > 1}))))
    bad = np.argwhere(~np.isfinite(C))
    if bad.size:
        i, j = bad[0]
        raise SelectionError("%s: entry (%s, %s) is not a finite number" % (source, names[i], names[j]))
    out = np.argwhere(np.abs(C) > 1.0 + 1e-9)
    if out.size:
        i, j = out[0]
        raise SelectionError("%s: entry (%s, %s) = %g is outside [-1, 1]" % (source, names[i], names[j], C[i, j]))
    asym = np.argwhere(np.abs(C - C.T) > SYMMETRY_TOL)
    if asym.size:
        i, j = asym[0]
        raise SelectionError("%s: not symmetric: (%s, %s) = %g but (%s, %s) = %g" % (source, names[i], names[j], C[i, j], names[j], names[i], C[j, i]))
    diag = np.flatnonzero(np.abs(np.diag(C) - 1.0) > SYMMETRY_TOL)
    if diag.size:
        i = diag[0]
        raise SelectionError("%s: diagonal entry of %s is %g, a correlation matrix has 1 there" % (source, names[i], C[i, i]))
    return np.clip((C + C.T) / 2.0, -1.0, 1.0)


def prim_maximum_tree(S: np.ndarray) -> list[tuple[int, int, float]]:
    """Maximum spanning tree of similarity ``S`` by Prim from vertex 0 -> [(i, j, w)] in addition order.

    Ties go to the lowest vertex index so the tree is reproducible.
    """
    p = S.shape[0]
    in_tree = np.zeros(p, dtype=bool)
    in_tree[0] = True
    best = S[0].astype(float).copy()
    parent = np.zeros(p, dtype=int)
    edges = []
    for _ in range(p - 1):
        cand = np.where(in_tree, -np.inf, best)
        j = int(np.argmax(cand))
        edges.append((int(parent[j]), j, float(S[parent[j], j])))
        in_tree[j] = True
        better = (~in_tree) & (S[j] > best)
        best[better] = S[j, better]
        parent[better] = j
    return edges


def maximal_tree(corr: Any, names: Sequence[str], target_corr: Any = None, absolute: bool = True) -> MaxTree:
    """Maximal-tree fuzzy clustering of a correlation matrix (see module docstring).

    ``target_corr``: per-sensor correlation with the target (sequence in ``names``
    order, or {name: r}); each cluster's representative is the member with the
    largest |r|. Without it the representative is the member with the largest mean
    similarity to the rest of its cluster (its most typical member).
    ``absolute``: use |r| as the similarity, so a sensor that mirrors another
    with the opposite sign counts as redundant; False uses r (negative r never joins).
    """
    names = [str(n) for n in names]
    C = check_corr(corr, names)
    S = np.abs(C) if absolute else C
    p = len(names)
    t = None
    if target_corr is not None:
        if isinstance(target_corr, dict):
            missing = [n for n in names if n not in target_corr]
            if missing:
                raise SelectionError("target correlations: no value for sensor(s) %s" % ", ".join(missing))
            t = np.asarray([target_corr[n] for n in names], dtype=float)
        else:
            t = np.asarray(target_corr, dtype=float).ravel()
            if t.size != p:
                raise SelectionError("target correlations: %d values for %d sensors" % (t.size, p))
        bad = np.flatnonzero(~np.isfinite(t) | (np.abs(t) > 1.0 + 1e-9))
        if bad.size:
            raise SelectionError("target correlations: value for %s is %r; must be a finite number in [-1, 1]" % (names[bad[0]], t[bad[0]]))

    tree = prim_maximum_tree(S) if p > 1 else []
    edges = [(names[i], names[j], w) for i, j, w in tree]
    breaks = sorted({w for _, _, w in tree if 0.0 <= w < 1.0})
    highs = breaks + [1.0]
    lows = [0.0] + breaks
    partitions = []
    for lo, hi in zip(lows, highs):
        if lo == hi:  # an edge of weight 0: [0, 0) holds for no λ (at λ = 0 that edge is already cut)
            continue
        clusters = _components(names, [(i, j) for i, j, w in tree if w >= hi])
        partitions.append(Partition(float(lo), float(hi), clusters, [_representative(c, names, S, t) for c in clusters]))
    rule = "max |r| with the target" if t is not None else "max mean similarity to the other cluster members"
    return MaxTree(names, S, edges, partitions, rule)


def _representative(cluster, names, S, t):
    idx = [names.index(n) for n in cluster]
    if t is not None:
        score = np.abs(t[idx])
    elif len(idx) == 1:
        return cluster[0]
    else:
        sub = S[np.ix_(idx, idx)]
        score = (sub.sum(axis=1) - np.diag(sub)) / (len(idx) - 1)
    return cluster[int(np.argmax(score))]  # argmax keeps the first of equals


# ---------------------------------------------------------------- selection on data

DEFAULTS = {"alpha": 0.05, "criterion": "paper", "r2_tolerance": 0.01, "max_sensors": None, "absolute": True,
            "min_tolerance": 1e-4, "correlation_on": "log"}
CORRELATION_ON = ("log", "targets")
CRITERIA = ("paper", "r2-change", "tolerance")
# SPSS REGRESSION's default TOLERANCE: a variable whose 1 − R² on the other variables is below this is not entered,
# so the set it belongs to cannot be fitted whole (Li 2021 §4.2 (5): "the tolerance is exceeded")
SPSS_MIN_TOLERANCE = 1e-4


def tolerances(X: np.ndarray) -> list[float]:
    """Each column's tolerance 1 − R² of its regression (with intercept) on the other columns (SPSS's TOLERANCE).

    One column: 1. A column that is an exact combination of the others: 0."""
    X = np.asarray(X, dtype=float)
    n, k = X.shape
    out = []
    for j in range(k):
        if k == 1:
            out.append(1.0)
            continue
        xj = X[:, j]
        A = np.column_stack([np.ones(n), np.delete(X, j, axis=1)])
        res = xj - A @ np.linalg.lstsq(A, xj, rcond=None)[0]
        sst = float(((xj - xj.mean()) ** 2).sum())
        out.append(max(0.0, float(res @ res) / sst) if sst > 0 else 0.0)
    return out


def r2_change_test(r2_small: float, k_small: int, r2_large: float, k_large: int, n: int) -> tuple[float, float]:
    """F test of the R² gain from k_small to k_large regressors (with intercept) -> (F, p).

    F = ((R²_L − R²_S)/(k_L − k_S)) / ((1 − R²_L)/(n − k_L − 1)), F(k_L − k_S, n − k_L − 1)
    under "the extra regressors add nothing". No gain (or no residual degree of
    freedom) gives (0, 1): nothing to accept.
    """
    from scipy import stats

    dk, df = k_large - k_small, n - k_large - 1
    gain = r2_large - r2_small
    if dk <= 0 or df <= 0 or gain <= 0:
        return 0.0, 1.0
    if r2_large >= 1.0:
        return float("inf"), 0.0
    F = (gain / dk) / ((1.0 - r2_large) / df)
    return float(F), float(stats.f.sf(F, dk, df))


def _choose_r2_change(ok, alpha, n):
    """``criterion="r2-change"`` (this project's reading before issue 23, not the paper's): the first set is the
    coarsest whose regression is significant at ``alpha``; going to finer partitions, each next representative set
    must raise R² significantly over the current one (F test of the R² change at ``alpha``); the first that does not
    ends the search, as in forward selection with an F-to-enter. Returns (chosen row, steps)."""
    ok = sorted(ok, key=lambda r: (len(r["representatives"]), r["partition"]))
    cur = ok[0]
    steps = [{"partition": cur["partition"], "sensors": len(cur["representatives"]), "r2": cur["r2"], "accepted": True,
              "why": "coarsest partition whose regression is significant (p_F %.3g < alpha)" % cur["p_F"]}]
    for row in ok[1:]:
        F, p = r2_change_test(cur["r2"], len(cur["representatives"]), row["r2"], len(row["representatives"]), n)
        steps.append({"partition": row["partition"], "sensors": len(row["representatives"]), "r2": row["r2"], "against": cur["partition"],
                      "F_change": F, "p_change": p, "accepted": p < alpha})
        if p >= alpha:
            break
        cur = row
    return cur, steps


def choose_partition(rows: Sequence[dict[str, Any]], n: int, criterion: str = "paper", alpha: float = 0.05, r2_tolerance: float = 0.01, min_tolerance: float = SPSS_MIN_TOLERANCE) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """The chosen row among evaluated representative sets -> (row, reason dict).

    ``rows``: one dict per representative set with ``partition`` (an id), ``representatives`` (names), ``r2``,
    ``F``, ``p_F`` and, for the paper rule, ``min_tolerance`` (the smallest tolerance of its variables); rows
    with ``skipped`` are not candidates. The published numbers (Li 2021 Tables 6–8) can be passed as such rows.

    * ``paper`` (Li 2021 §3.2 and §4.2 (5)): among the sets whose regression is significant at ``alpha``
      and whose variables all pass SPSS's tolerance (``min_tolerance``, default 0.0001; a set with a variable
      below it cannot be fitted whole: "the tolerance is exceeded"), the one whose R² is closest to 1;
      equal R²: fewer sensors.
    * ``r2-change``: forward F test of the R² change (:func:`_choose_r2_change`).
    * ``tolerance``: within ``r2_tolerance`` of the best R², the largest F (equal F: fewer sensors).
    """
    if criterion not in CRITERIA:
        raise SelectionError("maxtree: criterion must be one of %s, got %r" % (", ".join(CRITERIA), criterion))
    reason: dict[str, Any] = {"criterion_name": criterion}
    if criterion == "paper":
        for r in rows:
            if "skipped" not in r and r.get("min_tolerance") is not None and r["min_tolerance"] < min_tolerance:
                r["skipped"] = "tolerance exceeded: %s has tolerance %.3g < %g (SPSS excludes it, the set cannot be fitted whole)" % (
                    r.get("min_tolerance_sensor", "a variable"), r["min_tolerance"], min_tolerance)
    ok = [r for r in rows if "skipped" not in r and r.get("p_F") is not None and r["p_F"] < alpha]
    if not ok:
        return None, reason
    best_r2 = max(r["r2"] for r in ok)
    reason["best_r2"] = best_r2
    if criterion == "paper":
        chosen = max(ok, key=lambda r: (r["r2"], -len(r["representatives"]), -r["partition"]))
        reason["criterion"] = ("Li 2021: among the representative sets whose regression is significant (p_F < alpha) and whose "
                               "variables all pass the tolerance (min_tolerance, SPSS default), the largest R2 (closest to 1)")
        reason["min_tolerance"] = min_tolerance
    elif criterion == "r2-change":
        chosen, steps = _choose_r2_change(ok, alpha, n)
        reason["criterion"] = ("regression F test p < alpha; from the coarsest significant partition, a finer one replaces the choice "
                               "only if its R2 gain is significant (F test of the R2 change, p < alpha); the first refusal stops")
        reason["steps"] = steps
    else:
        cands = [r for r in ok if r["r2"] >= best_r2 - r2_tolerance]
        chosen = max(cands, key=lambda r: (r["F"], -len(r["representatives"]), -r["partition"]))
        reason["criterion"] = "F test p < alpha; R2 within r2_tolerance of the best; then largest F"
        reason["r2_tolerance"] = r2_tolerance
    return chosen, reason


def select_maxtree(arrays: Any, context: dict[str, Any] | None = None, **params: Any) -> Selection:
    """Choose the partition whose representatives regress best on the target (:func:`choose_partition`).

    ``criterion="paper"`` (default, Li 2021 §3.2/§4.2): the largest R² among the representative sets whose
    regression F test is significant at ``alpha`` (0.05) and whose variables all have a tolerance
    1 − R²_j >= ``min_tolerance`` (SPSS's 0.0001). ``criterion="r2-change"``: forward F test of the R² change
    (this project's reading before issue 23). ``criterion="tolerance"`` (the earlier rule): within
    ``r2_tolerance`` of the best R², the largest F.
    """
    prm = check_params("maxtree", params, DEFAULTS)
    prm["alpha"] = number("maxtree", "alpha", prm["alpha"], 0.0, 1.0)
    if prm["criterion"] not in CRITERIA:
        raise SelectionError("maxtree: criterion must be one of %s, got %r" % (", ".join(CRITERIA), prm["criterion"]))
    prm["r2_tolerance"] = number("maxtree", "r2_tolerance", prm["r2_tolerance"], 0.0, 1.0)
    prm["min_tolerance"] = number("maxtree", "min_tolerance", prm["min_tolerance"], 0.0, 1.0)
    prm["max_sensors"] = number("maxtree", "max_sensors", prm["max_sensors"], 1, integer=True, allow_none=True)
    if not isinstance(prm["absolute"], bool):
        raise SelectionError("maxtree: absolute must be true or false, got %r" % (prm["absolute"],))
    if prm["correlation_on"] not in CORRELATION_ON:
        raise SelectionError("maxtree: correlation_on must be one of %s, got %r" % (", ".join(CORRELATION_ON), prm["correlation_on"]))
    X, y, names = pooled(arrays)
    n = X.shape[0]
    # Li 2021 Eq. 11: the sensors' correlations over their temperature series, i.e. every logged sample (rises over
    # each run's start, all runs pooled); the target is only known at the sweeps, so its correlations stay there
    logs = [getattr(a, "log", None) for a in arrays]
    if prm["correlation_on"] == "log" and all(lg is not None for lg in logs):
        L = np.vstack([lg[1] for lg in logs])  # pyright: ignore[reportOptionalSubscript]  # all not None: checked above
        similarity_on = "temperature log: %d samples (rises over each run's start, runs pooled)" % L.shape[0]
    else:
        L = X
        similarity_on = "target times: %d samples%s" % (n, "" if prm["correlation_on"] == "targets" else " (no temperature log with these arrays)")
    C = np.corrcoef(L, rowvar=False).reshape(len(names), len(names))
    t = np.array([np.corrcoef(X[:, j], y)[0, 1] for j in range(len(names))])
    tree = maximal_tree(C, names, target_corr=t, absolute=prm["absolute"])
    rows = []
    for k, part in enumerate(tree.partitions):
        reps = part.representatives
        row = {"partition": k, "lambda_low": part.lambda_low, "lambda_high": part.lambda_high, "clusters": len(part.clusters), "representatives": list(reps)}
        if len(reps) + 1 >= n:
            row["skipped"] = "%d parameters for %d samples" % (len(reps) + 1, n)
        elif prm["max_sensors"] is not None and len(reps) > prm["max_sensors"]:
            row["skipped"] = "more than max_sensors=%d" % prm["max_sensors"]
        else:
            cols = X[:, [names.index(r) for r in reps]]
            st = ols_stats(cols, y)
            tol = tolerances(cols)
            j = int(np.argmin(tol))
            row.update(r2=st["r2"], adj_r2=st["adj_r2"], F=st["F"], p_F=st["p_F"], rmse=st["rmse"], min_tolerance=tol[j],
                       min_tolerance_sensor=reps[j])
            if st["p_F"] is None:
                row["skipped"] = "representatives are collinear (rank %d of %d)" % (st["rank"], len(reps) + 1)
        rows.append(row)
    chosen, reason = choose_partition(rows, n, prm["criterion"], prm["alpha"], prm["r2_tolerance"], prm["min_tolerance"])
    if chosen is None:
        raise SelectionError(
            "maxtree: no partition's representatives give a regression significant at alpha=%g (%d samples, %d sensors); more data or a different target is needed"
            % (prm["alpha"], n, len(names))
        )
    best_r2 = reason.pop("best_r2")
    part = tree.partitions[chosen["partition"]]
    sensors = [s for s in names if s in part.representatives]
    reason.update({
        "similarity_on": similarity_on,
        "alpha": prm["alpha"],
        "best_r2": best_r2,
        "chosen_partition": chosen["partition"],
        "chosen_lambda": [part.lambda_low, part.lambda_high],
        "r2": chosen["r2"],
        "F": chosen["F"],
        "p_F": chosen["p_F"],
        "target_correlation": {s: float(v) for s, v in zip(names, t)},
        "partitions": rows,
        "tree": tree.to_json(),
        "samples": int(n),
    })
    label = data_label(context, n)

    def plotter(path):
        _plot_selection(path, tree, rows, chosen, label)

    return Selection(sensors, "maxtree", reason, plotter)


def _plot_selection(path, tree, rows, chosen, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(max(11.0, 0.45 * len(tree.names) + 6), 4.8), gridspec_kw={"width_ratios": [3, 2]})
    lam = 0.5 * (chosen["lambda_low"] + chosen["lambda_high"])
    tree.plot(None, title="maximal tree; dashed: chosen λ; chosen sensors in red", mark_lambda=lam, ax=a1)
    for tick in a1.get_xticklabels():
        if tick.get_text() in chosen["representatives"]:
            tick.set_color("red")
            tick.set_fontweight("bold")
    ev = [r for r in rows if "r2" in r]
    ks = [len(r["representatives"]) for r in ev]
    a2.plot(ks, [r["r2"] for r in ev], "o-", label="R²")
    a2.set_xlabel("sensors (one per cluster)")
    a2.set_ylabel("sample R²")
    a3 = a2.twinx()
    a3.plot(ks, [r["F"] if r["F"] is not None and np.isfinite(r["F"]) else np.nan for r in ev], "s--", color="C1", label="F")
    a3.set_ylabel("F statistic", color="C1")
    a2.plot([len(chosen["representatives"])], [chosen["r2"]], "r*", ms=14, label="chosen")
    a2.legend(loc="lower right", fontsize=8)
    a2.set_title("partition fit: R² and F")
    fig.suptitle("Maximal-tree sensor selection: %s" % label, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
