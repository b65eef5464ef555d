"""Structure averaging of the dynamic model (issue 21): a weighted sum of the best structures instead of the one best.

Forward chaining scores only 2-3 blocks on a few training cycles, so picking the
single structure with the lowest score is noisy: structures a few per cent apart
predict the next regime very differently (docs/results.md, "Issue 21"). The
classic cure is to average the predictions of several good structures. The
average of linear lag-filter models is itself one linear lag-filter model over
the union of their terms, with coefficient = Σ_m w_m · b_m (a term a member
lacks counts 0 there): the same document kind (``dynamic``), the same table
kind 4 on the board, one observer fitted for the union's signals.

*Members* (``average_structures`` = K, the most members; 1: the single best
structure): the structures the searches already made, one per value of the ridge
grid for the search over every term and, with the static fallback, for the
search over the static terms (τ = 0), each set of terms once (at the ridge value
it scored best with), in order of their forward-chaining score
(the lowest first: the single best structure, the model without averaging, is
always the first). A structure joins while the union stays within
``max_sensors`` temperature sensors and ``max_terms`` terms (what the board and
the exporter take); one that would break them is passed over.

*Weights*: w_m >= 0, Σ w_m = 1, on a grid of step ``WEIGHT_STEP`` over the
simplex, chosen by the pooled forward-chaining score of the averaged model
itself: on each scored block k, every member refitted on the blocks before k
(its own terms and penalty), combined with w, predicts the block as the board
of the *union* computes it (the scored block's switched-on columns with the
union's observer starts, dynamic.StartedColumns). w = (1, 0, ...) is the single
structure, so the chosen weights never score worse than it on the training
blocks (an in-sample choice of K - 1 numbers: optimistic, as the structure's own
score is). Members that get weight 0 are dropped from the model.
"""
from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import finite_or_none

AVERAGE_STRUCTURES = 1  # the default: the single best structure (docs/results.md, "Issue 21: structure averaging")
# the most terms a dynamic table holds (models_export/exact.py refuses more): the union's limit. Not ``max_terms``, the
# search's limit on one structure's greed: the average fits K - 1 weights, not new coefficients
BOARD_TERMS = 8
WEIGHT_STEP = 0.1  # the weight grid over the simplex: 66 combinations for 3 members
RULE = ("members: the best structure of each ridge value of the search over every term and of the static (tau 0) search, "
        "lowest forward-chaining score first, while the union stays within max_sensors sensors and %d terms; weights "
        ">= 0 summing to 1 on a %g grid, chosen by the averaged model's own pooled forward-chaining score (each scored block "
        "predicted by the members refitted on the blocks before it, with the union's switched-on columns)" % (BOARD_TERMS, WEIGHT_STEP))


PATH_RULE = ("members (average_members=path): the structures along the greedy path that ended in the chosen structure (after "
             "each addition and exchange, at its ridge value), lowest forward-chaining score first; weights as with ridge members")


def check_count(value: Any) -> int:
    """``average_structures``: an integer >= 1 (1: no averaging)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise EmpiricalDataError("dynamic: average_structures must be an integer >= 1 (1: the single best structure), got %r" % (value,))
    return int(value)


def member_structures(searches: Sequence[tuple[Any, Sequence[int]]]) -> list[dict[str, Any]]:
    """Every structure the searches made, lowest score first, each once (with the ridge value it scored best with).

    ``searches``: [(fitted DynamicRegression, the full candidate index of each of its columns)]; each search's
    ``fits_by_ridge_`` holds its best structure per ridge value."""
    found = []
    for est, columns in searches:
        for ridge, fitted in getattr(est, "fits_by_ridge_", {}).items():
            if np.isfinite(fitted["cv_rmse"]):
                found.append({"columns": [int(columns[j]) for j in fitted["selected_"]], "ridge": float(ridge),
                              "score_um": float(fitted["cv_rmse"])})
    found.sort(key=lambda m: m["score_um"])  # stable: on a tie the search over every term, lower ridge, first
    seen, out = set(), []
    for m in found:  # the same terms at another penalty is not another structure
        if frozenset(m["columns"]) not in seen:
            seen.add(frozenset(m["columns"]))
            out.append(m)
    return out


def path_structures(anchor: Any, terms: Sequence[tuple[str, float]]) -> list[dict[str, Any]]:
    """The structures along the greedy path that ended in ``anchor``'s structure (after each addition and each
    exchange, at the anchor's ridge value), lowest score first, each once (``average_members="path"``). Without
    exchanges each is a part of the anchor's structure, so averaging them shrinks the terms added last and the board
    reads nothing more; a structure from before an exchange can add a term (the union's limits still apply)."""
    index = {(n, float(tau)): j for j, (n, tau) in enumerate(terms)}
    sel: list[int] = []
    found = []
    for h in anchor.history_:
        if h["action"] == "add":
            sel = sel + [index[(h["term"][0], float(h["term"][1]))]]
        elif h["action"] == "swap":
            sel = list(sel)
            sel[sel.index(index[(h["replaces"][0], float(h["replaces"][1]))])] = index[(h["term"][0], float(h["term"][1]))]
        else:
            continue
        if np.isfinite(h["cv_rmse"]):
            found.append({"columns": list(sel), "ridge": float(anchor.ridge_), "score_um": float(h["cv_rmse"])})
    found.sort(key=lambda m: m["score_um"])
    seen, out = set(), []
    for m in found:
        if frozenset(m["columns"]) not in seen:
            seen.add(frozenset(m["columns"]))
            out.append(m)
    return out


MEMBERS = ("ridge", "path")  # where the members come from: each ridge value's best structure, or the chosen one's greedy path


def _within(cols: Sequence[int], terms: Sequence[tuple[str, float]], max_sensors: int, max_terms: int) -> bool:
    sensors = {terms[j][0] for j in cols if terms[j][0].startswith("T:")}
    return len(sensors) <= max_sensors and len(cols) <= max_terms


def pick_members(members: Sequence[dict[str, Any]], count: int, terms: Sequence[tuple[str, float]], max_sensors: int,
                 max_terms: int) -> list[dict[str, Any]]:
    """The first ``count`` members (score order) whose union stays within the board's limits; the first always."""
    chosen: list[dict[str, Any]] = []
    union: list[int] = []
    for m in members:
        if len(chosen) >= count:
            break
        extra = [j for j in m["columns"] if j not in union]
        if chosen and not _within(union + extra, terms, max_sensors, max_terms):
            continue
        chosen.append(m)
        union += extra
    return chosen


def _solve(A: np.ndarray, y: np.ndarray, ridge: float, o: int) -> np.ndarray | None:
    """Ridge least squares on scaled columns A (intercept first when o), penalty ridge x samples, not on the intercept."""
    P = ridge * A.shape[0] * np.eye(A.shape[1])
    if o:
        P[0, 0] = 0.0
    M = A.T @ A + P
    if np.linalg.cond(M) > 1e12:
        return None
    return np.linalg.solve(M, A.T @ y)


def simplex(k: int, step: float = WEIGHT_STEP) -> list[np.ndarray]:
    """Every weight vector of ``k`` entries >= 0 summing to 1 on the grid ``step``; the first member's weight descending."""
    n = int(round(1.0 / step))
    out = []
    for combo in itertools.product(range(n, -1, -1), repeat=k):
        if sum(combo) == n:
            out.append(np.asarray(combo, dtype=float) / n)
    return out


class AveragedRegression:
    """The weighted sum of several fitted structures as one linear model over the union of their terms.

    Built by :func:`average` from the selection's fitted estimator(s); offers what fitting.py and ``tcomp fit`` read
    of a DynamicRegression: ``terms_``, ``coef_``, ``intercept_``, ``coefficients_on(rows)`` (every member refitted
    on ``rows`` with its own penalty, combined with the weights), ``statistics()`` and the scalars printed."""

    def __init__(self, anchor: Any, F: np.ndarray, y: np.ndarray, terms: Sequence[tuple[str, float]], members: Sequence[dict[str, Any]],
                 weights: np.ndarray, union: Sequence[int], score: float, single_score: float, o: int) -> None:
        self.anchor = anchor
        self.members = [m for m, w in zip(members, weights) if w > 0]
        self.weights = np.asarray([w for w in weights if w > 0], dtype=float)
        used = sorted({j for m in self.members for j in m["columns"]}, key=list(union).index)
        self.union = used
        self._F = np.asarray(F, dtype=float)[:, used]
        self._y = np.asarray(y, dtype=float)
        self._o = o
        # the selection's column scaling (RMS over every training sample), so a member's penalty means what it meant there
        whole = np.column_stack([np.ones(y.size), self._F]) if o else self._F
        self._scale = np.sqrt((whole ** 2).mean(axis=0))
        self._scale[self._scale == 0] = 1.0
        self.terms_ = [(terms[j][0], float(terms[j][1])) for j in used]
        self.intercept_, self.coef_ = self.coefficients_on(np.ones(y.size, dtype=bool))
        self.cv_rmse_ = float(score)
        self.single_score_ = float(single_score)
        for key in ("ridge_", "n_groups_", "cv_score_", "selection", "n_samples_", "fit_intercept"):
            setattr(self, key, getattr(anchor, key))
        r = self._y - (self.intercept_ + self._F @ self.coef_)
        self.rmse_ = float(np.sqrt(np.mean(r ** 2)))
        sst = float(((self._y - self._y.mean()) ** 2).sum())
        self.rsquared_ = 1.0 - float(r @ r) / sst if sst > 0 else float("nan")

    def coefficients_on(self, rows: np.ndarray) -> tuple[float, np.ndarray]:
        """(intercept, coefficients over the union) of the weighted members, each refitted on the samples ``rows``."""
        rows = np.asarray(rows, dtype=bool)
        b0, coef = 0.0, np.zeros(len(self.union))
        for m, w in zip(self.members, self.weights):
            pos = [self.union.index(j) for j in m["columns"]]
            A = self._F[rows][:, pos]
            A = np.column_stack([np.ones(A.shape[0]), A]) if self._o else A
            scale = self._scale[([0] if self._o else []) + [p + self._o for p in pos]]
            beta = _solve(A / scale, self._y[rows], m["ridge"], self._o)
            if beta is None:
                raise EmpiricalDataError("dynamic: a member of the structure average is singular on the samples given")
            beta = beta / scale
            b0 += w * (beta[0] if self._o else 0.0)
            coef[pos] += w * beta[self._o:]
        return float(b0), coef

    def predict(self, F: np.ndarray) -> np.ndarray:
        return self.intercept_ + np.asarray(F, dtype=float) @ self.coef_

    def statistics(self) -> dict[str, Any]:
        st = self.anchor.statistics()
        st.update({
            "cv_rmse": finite_or_none(self.cv_rmse_), "rmse": finite_or_none(self.rmse_), "r2": finite_or_none(self.rsquared_),
            "residual_std_error": finite_or_none(self.rmse_),
            "terms": [{"signal": n, "tau_s": tau, "coefficient": finite_or_none(c)} for (n, tau), c in zip(self.terms_, self.coef_)],
            "sensors_used": sorted({n[2:] for n, _ in self.terms_ if n.startswith("T:")}),
        })
        return st

    def summary(self, terms: Sequence[tuple[str, float]]) -> dict[str, Any]:
        """``statistics.structure_average``: the members, their weights and scores, and what averaging scored."""
        return {"rule": RULE, "single_score_um": self.single_score_, "averaged_score_um": self.cv_rmse_,
                "members": [{"terms": [[terms[j][0], float(terms[j][1])] for j in m["columns"]], "ridge": m["ridge"],
                             "score_um": m["score_um"], "weight": float(w)} for m, w in zip(self.members, self.weights)]}


def average(anchor: Any, F: np.ndarray, y: np.ndarray, terms: Sequence[tuple[str, float]], groups: np.ndarray,
            searches: Sequence[tuple[Any, Sequence[int]]], count: int,
            block_columns: dict[Any, Any] | None = None, members_from: str = "ridge") -> tuple[AveragedRegression | None, dict[str, Any]]:
    """(the forward-weighted average of up to ``count`` structures of ``searches`` (see the module), or None when only
    one structure fits the limits or no weighting scores lower than the single structure; the record
    ``statistics.structure_average``: every candidate structure, the members and weights, or why the single one stays).

    ``anchor``: the selection's chosen estimator (its settings: max_sensors, fit_intercept; its score);
    F, y, terms, groups: every candidate column, the targets and the forward blocks it was fitted on;
    ``block_columns``: the scored blocks' switched-on columns over every candidate (DynamicRegression.with_block_columns;
    None: the blocks' rows of F, filters running since the run start). Averaging is kept only when it scores lower
    than the anchor's own score."""
    if members_from not in MEMBERS:
        raise EmpiricalDataError("dynamic: average_members must be one of %s, got %r" % (", ".join(MEMBERS), members_from))
    candidates = member_structures(searches) if members_from == "ridge" else path_structures(anchor, terms)
    members = pick_members(candidates, count, terms, int(anchor.max_sensors), BOARD_TERMS)
    record = {"rule": RULE if members_from == "ridge" else PATH_RULE, "members": None, "candidates": [
        {"terms": [[terms[j][0], float(terms[j][1])] for j in m["columns"]], "ridge": m["ridge"], "score_um": m["score_um"],
         "within_limits_with_the_best": any(m is p for p in members)} for m in candidates]}
    if len(members) < 2:
        record["why_single"] = "no other structure keeps the union within %d sensors and %d terms" % (int(anchor.max_sensors), BOARD_TERMS)
        return None, record
    union: list[int] = []
    for m in members:
        union += [j for j in m["columns"] if j not in union]
    o = int(bool(anchor.fit_intercept))
    F = np.asarray(F, dtype=float)
    y = np.asarray(y, dtype=float)
    groups = np.asarray(groups)
    labels = np.unique(groups)
    # the same column scaling as the selection (dynamic.DynamicRegression._fit_one): RMS over every training sample
    A_all = np.column_stack([np.ones(y.size), F]) if o else F
    scale = np.sqrt((A_all ** 2).mean(axis=0))
    scale[scale == 0] = 1.0
    idx_union = ([0] if o else []) + [j + o for j in union]
    held_cols = block_columns or {}
    from host.learning.empirical.dynamic import _fixed_moments, _held_moments

    # per scored block: the union's held-out moments, and every member's coefficients (scaled, union coordinates)
    quad = np.zeros((len(members), len(members)))
    lin = np.zeros(len(members))
    const, n_held = 0.0, 0
    for k in range(1, labels.size):
        train = groups < labels[k]
        rows = groups == labels[k]
        if labels[k] in held_cols:
            held = _held_moments(held_cols[labels[k]], scale, o, labels[k])
        else:
            Ak = A_all[rows] / scale
            held = _fixed_moments(Ak.T @ Ak, Ak.T @ y[rows], float(y[rows] @ y[rows]), int(rows.sum()))
        Gv, cv_, yy, nv = held(idx_union, union)
        B = np.zeros((len(idx_union), len(members)))
        for i, m in enumerate(members):
            idx = ([0] if o else []) + [j + o for j in m["columns"]]
            beta = _solve(A_all[train][:, idx] / scale[idx], y[train], m["ridge"], o)
            if beta is None:  # the member cannot be fitted on this fold: it cannot be averaged
                record["why_single"] = "a member is singular on the fold scoring block %s" % (labels[k],)
                return None, record
            B[[idx_union.index(i_) for i_ in idx], i] = beta
        quad += B.T @ Gv @ B
        lin += B.T @ cv_
        const += yy
        n_held += nv
    best_w, best_sse = None, np.inf
    for w in simplex(len(members)):
        sse = max(const - 2 * w @ lin + w @ quad @ w, 0.0)
        if sse < best_sse * (1.0 - 1e-9):
            best_w, best_sse = w, sse
    assert best_w is not None
    score = float(np.sqrt(best_sse / n_held))
    record.update(best_weights=best_w.tolist(), best_score_um=score, single_score_um=float(anchor.cv_rmse_))
    if best_w[0] == 1.0 or not score < float(anchor.cv_rmse_):
        record["why_single"] = "no weighting of the members scores lower than the single best structure"
        return None, record
    averaged = AveragedRegression(anchor, F, y, terms, members, best_w, union, score, float(anchor.cv_rmse_), o)
    record.update(averaged.summary(terms))
    return averaged, record
