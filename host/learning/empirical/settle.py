"""Settle-bounded structure choice of the dynamic model (option ``settle_max_s``, issue 21).

The observer (host/learning/empirical/observer.py) leaves each lag state j of a board switched on on a warm machine
with a start error bounded by E_j (the largest training residual of its static estimate), forgotten as
exp(−t/τ_j); the document's ``thermal.observer.settle_s`` is when B(t) = scale·Σ_j |b_j|·E_j·exp(−t/τ_j) reaches the
tolerance (1 µm). How long that takes is a property of the *structure*: a long lag of a sensor that the other inputs
do not reveal cannot be recovered at switch-on, and a large coefficient on it keeps B above 1 µm for hours.

With ``settle_max_s`` set, the structure search (host/learning/empirical/dynamic.py) admits only structures whose
settle_s, computed by the same function as the document's (observer.settle_time on observer.fit_observer's E_j), is
<= ``settle_max_s``. For a candidate structure:

- the coefficients b_j are those of the fit on all training samples with the penalty being tried (what the model
  would carry if the candidate were chosen);
- E_j comes from one observer of the candidate's signal set fitted on the whole training span (the same runs,
  spans and exclusions as the final model's observer). An observer's estimate of one state does not depend on the
  other states, so one fit per signal set, with every lag of the grid, gives E_j of every structure on those
  signals. Not the fold observers: the bound is about the document the board gets, whose observer is this one; so
  for the structure finally chosen the check is exactly the document's settle_s, not an estimate of it.

A structure without lag terms (τ = 0 only, e.g. the static fallback's) has no state to recover: settle_s = 0,
always admissible.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from host.learning.empirical import EmpiricalDataError

RULE = ("a structure is admitted only if its observer's settle_s (the start-error bound's 1-um time, observer.settle_time, "
        "with the coefficients of its fit on all training samples and E_j of one observer of its signals fitted on the whole "
        "training span) is <= settle_max_s; structures without lags have settle_s 0")


def settle_max_option(value: Any, name: str = "settle_max_s") -> float | None:
    """Option ``name`` (``settle_max_s`` or ``settle_without_record_max_s``) as given (None, "none", 0: off; a finite
    number of seconds > 0) -> seconds or None (off)."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "none"):
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value) or value < 0:
        raise EmpiricalDataError("dynamic: %s must be a finite number of seconds >= 0 (0 or none: off), got %r" % (name, value))
    return None if value == 0 else float(value)


class SettleBound:
    """The admissibility test of one training set: ``settle_s(terms, coefficients)`` as the document would carry it.

    ``runs``, ``spans``, ``exclude``, ``reference_C`` (every candidate sensor), ``target``, ``channel`` and ``scale``
    are what the final model's observer is fitted with (host/learning/empirical/fitting.py _fit_dynamic);
    ``lag_taus``: the candidate grid's τ > 0.
    """

    def __init__(self, settle_max_s: float, runs: Sequence[Any], spans: Sequence[tuple[float, float]],
                 exclude: tuple[float | None, float | None] | None, reference_C: dict[str, float], target: str,
                 channel: str | None, scale: float, lag_taus: Sequence[float], tolerance: float | None = None,
                 controller: Sequence[str] = (), without_record_max_s: float | None = None) -> None:
        from host.learning.empirical.observer import SETTLE_TOLERANCE_UM

        self.settle_max_s = float(settle_max_s)
        self.runs, self.spans, self.exclude = list(runs), list(spans), exclude
        self.reference_C, self.target, self.channel, self.scale = dict(reference_C), target, channel, float(scale)
        self.lag_taus = sorted({float(t) for t in lag_taus if t > 0})
        self.tolerance = SETTLE_TOLERANCE_UM if tolerance is None else float(tolerance)
        self.controller = tuple(controller)
        # also admit only structures whose board without the controller's record settles within this (None: no such bound)
        self.without_record_max_s = None if without_record_max_s is None else float(without_record_max_s)
        self._bounds: dict[frozenset, dict[tuple[str, float], tuple[float, float]]] = {}

    def _state_bounds(self, signals: Sequence[str]) -> dict[tuple[str, float], tuple[float, float]]:
        """{(signal, τ): (E_j, E_j without the controller's record)} of every lag of ``signals`` on the grid, for an
        observer whose regressors are ``signals`` (the two differ only for the states the controller supplies)."""
        from host.learning.empirical.dynamic import DynamicModel
        from host.learning.empirical.observer import fit_observer

        key = frozenset(signals)
        out = self._bounds.get(key)
        if out is None:
            lagged = [(n, tau) for n in signals for tau in self.lag_taus]
            model = DynamicModel(lagged, np.zeros(len(lagged)), 0.0, self.target, self.channel, reference_C=self.reference_C)
            obs = fit_observer(model, self.runs, spans=self.spans, exclude=self.exclude, scale=self.scale, controller=self.controller)
            out = self._bounds[key] = {lagged[s["term"]]: (float(s["bound"]), float(s.get("bound_without_record", s["bound"])))
                                       for s in obs.states}
        return out

    def settle_s(self, terms: Sequence[tuple[str, float]], coefficients: ArrayLike, without_record: bool = False) -> float:
        """settle_s of the structure ``terms`` with ``coefficients``: observer.settle_time on this training's E_j
        (``without_record``: settle_without_record_s, the supplied states at their estimate's bound)."""
        from host.learning.empirical.dynamic import DynamicModel
        from host.learning.empirical.observer import settle_time, signals_of

        terms = [(str(n), float(tau)) for n, tau in terms]
        if not any(tau > 0 for _, tau in terms):
            return 0.0
        bounds = self._state_bounds(signals_of(terms))
        model = DynamicModel(terms, coefficients, 0.0, self.target, self.channel, reference_C=self.reference_C)
        states = [{"term": j, "bound": bounds[term][1 if without_record else 0]} for j, term in enumerate(terms) if term[1] > 0]
        return settle_time(model, states, self.tolerance, self.scale)

    def screen(self, score: Callable[[list[int]], float], coefficients: Callable[[list[int]], np.ndarray],
               terms: Sequence[tuple[str, float]]) -> Screen:
        """``score`` (candidate columns -> validation score) restricted to admissible structures, for one search."""
        return Screen(self, score, coefficients, terms)


class Screen:
    """A search's score with inadmissible structures scored inf; counts what it refused (``record``)."""

    def __init__(self, bound: SettleBound, score: Callable[[list[int]], float], coefficients: Callable[[list[int]], np.ndarray],
                 terms: Sequence[tuple[str, float]]) -> None:
        self.bound, self.score, self.coefficients, self.terms = bound, score, coefficients, list(terms)
        self.settle: dict[tuple[int, ...], float] = {}
        self.refused: dict[tuple[int, ...], float] = {}  # structure -> its validation score
        self.settle_without_record: dict[tuple[int, ...], float] = {}  # of the structures the first bound admitted

    def __call__(self, cols: Sequence[int]) -> float:
        cols = list(cols)
        s = self.score(cols)
        if not np.isfinite(s) or not any(self.terms[c][1] > 0 for c in cols):
            return s
        key = tuple(sorted(cols))
        if key not in self.settle:
            structure, coef = [self.terms[c] for c in cols], self.coefficients(cols)
            self.settle[key] = self.bound.settle_s(structure, coef)
            if self.bound.without_record_max_s is not None and self.settle[key] <= self.bound.settle_max_s:
                self.settle_without_record[key] = self.bound.settle_s(structure, coef, without_record=True)
        nr_max = self.bound.without_record_max_s
        if self.settle[key] > self.bound.settle_max_s or (nr_max is not None and self.settle_without_record[key] > nr_max):
            self.refused[key] = s
            return float("inf")
        return s

    def record(self) -> dict[str, Any]:
        """What the bound did in this search (``statistics.settle_bound``)."""
        return {"settle_max_s": self.bound.settle_max_s, "tolerance_um": self.bound.tolerance,
                "structures_checked": len(self.settle), "structures_refused": len(self.refused),
                "best_refused_score_um": min(self.refused.values()) if self.refused else None,
                **({"without_record_max_s": self.bound.without_record_max_s,
                    "refused_without_record": sum(v > self.bound.without_record_max_s for v in self.settle_without_record.values())}
                   if self.bound.without_record_max_s is not None else {}),
                "observer": "one per candidate signal set, fitted on the whole training span (the final model's observer)",
                "rule": RULE}
