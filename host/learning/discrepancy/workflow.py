"""The discrepancy loop: held-out base model, candidate effects, significance, repeat.

The loop only talks to a *model family* (see :class:`Family`): something that
can fit a base model plus a set of named effects on selected rows of some runs
and predict every row of a run. ``host.learning.discrepancy.family`` is the family of
host/learning/screw's ScrewModel configurations; tests use small linear families.

Every RMSE and every test statistic here is computed on held-out rows:
leave-one-run-out when there are two or more runs, otherwise a blocked time
split of the single run into two halves of its sweeps, each predicted by the
model fitted on the other half.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import math
import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, List, Optional

import numpy as np

from host.learning.discrepancy import stats
from host.learning.discrepancy.localize import localize

if TYPE_CHECKING:
    from host.data.runs import Run

# Thresholds, chosen from the null distribution over seeds (docs/discrepancy.md,
# tools/bench_discrepancy.py): family-wise alpha over the candidates of one round,
# and the smallest held-out relative RMSE reduction worth naming an effect for.
ALPHA = 0.01
MIN_GAIN = 0.10
MIN_HELDOUT_SWEEPS = 2  # sweeps (distinct error times) a held-out block needs: one would test an offset, not a drift
LOG_LOSS = True  # test the per-sweep log MSE ratio (see stats.dm_test)


class Family:
    """Interface the loop needs from a model family (duck-typed; this documents it).

    ``fit(runs, masks, effects, start)`` -> fitted object (picklable); ``masks[i]``
    is a boolean array over ``runs[i].errors`` rows to fit on, or None to leave
    run i out entirely; ``start`` is a previous fitted object whose parameters
    seed the fit (or None).
    ``predict(fitted, run)`` -> predicted error (um) per row of ``run.errors``.
    ``applicable(runs, effect)`` -> None, or a reason why the effect cannot be
    tested on these runs (e.g. no bidirectional sweeps).
    ``candidates`` -> effect names to test, in catalog order.
    Optional ``fit_final(runs, effects, start)`` -> the fitted object the workflow reports (all rows; the
    screw family adds the firmware's reduced form there); without it ``fit`` on every row.
    """


@dataclass
class Fold:
    train: list  # per run: bool mask or None
    test: list  # per run: bool mask or None


@dataclass
class HeldOut:
    effects: tuple
    residuals: list  # per run, aligned with run.errors; NaN where never tested
    fits: list  # per fold

    def rmse(self) -> float:
        return stats.rmse(np.concatenate(self.residuals))

    def rmse_per_run(self) -> list[float]:
        return [stats.rmse(r) for r in self.residuals]


@dataclass
class Candidate:
    name: str
    score: float = float("nan")  # held-out relative RMSE reduction, 1 - after/before
    p_value: float = 1.0  # Holm-adjusted one-sided DM p-value
    p_raw: float = 1.0
    statistic: float = float("nan")
    rmse_um: float = float("nan")
    accepted: bool = False
    skipped: Optional[str] = None  # reason the candidate was not tested
    error: Optional[str] = None  # fit failure message
    heldout: Any = field(default=None, repr=False)
    note: Optional[str] = None  # caveat about the test on these runs
    joint_with: Optional[List[str]] = None  # accepted together with these (pair test)
    single_score: Optional[float] = None
    single_p_value: Optional[float] = None
    single_rmse_um: Optional[float] = None

    def as_dict(self) -> dict[str, Any]:
        # a candidate that could not be tested (skipped, fit failed) reports score 0 and p 1:
        # nothing was added, nothing was shown; the reason is in "skipped"/"error"
        untested = not math.isfinite(self.score)
        d = {"name": self.name, "score": 0.0 if untested else float(self.score), "p_value": 1.0 if untested else _num(self.p_value),
             "accepted": bool(self.accepted),
             "p_raw": _num(self.p_raw), "dm_statistic": _num(self.statistic), "rmse_um": _num(self.rmse_um)}
        if self.skipped:
            d["skipped"] = self.skipped
        if self.error:
            d["error"] = self.error
        if self.note:
            d["note"] = self.note
        if self.joint_with:
            d["joint_with"] = list(self.joint_with)
            d["single_score"] = _num(self.single_score)
            d["single_p_value"] = _num(self.single_p_value)
        return d


@dataclass
class Round:
    base_effects: tuple
    rmse_before_um: float
    candidates: list
    accepted: Optional[str] = None
    rmse_after_um: float = float("nan")
    localization: list = field(default_factory=list)
    pairs: list = field(default_factory=list)


@dataclass
class Result:
    effects: list
    before: HeldOut
    after: HeldOut
    rounds: list
    runs: list
    final_fit: Any = None  # the family's fitted object (duck-typed, Family); the screw family's is a ScrewModel
    reference: Optional[dict] = None  # host.learning.discrepancy.reference.check_declaration's finding, when run

    def as_json(self) -> dict[str, Any]:
        cand = {}
        # one entry per catalog effect: its figures from the round it was accepted in,
        # or from the last round it was tested in
        for rnd in self.rounds:
            for c in rnd.candidates:
                prev = cand.get(c.name)
                tested = math.isfinite(c.score) or c.skipped or c.error
                if prev is None or (not prev.accepted and tested):
                    cand[c.name] = c
        return {
            "effects": list(self.effects),
            "rmse_before_um": _num(self.before.rmse()),
            "rmse_after_um": _num(self.after.rmse()),
            "per_run": [
                {"run": r.name, "rmse_before_um": _num(a), "rmse_after_um": _num(b)}
                for r, a, b in zip(self.runs, self.before.rmse_per_run(), self.after.rmse_per_run())
            ],
            "localization": self.rounds[0].localization if self.rounds else [],
            "candidates": [c.as_dict() for c in cand.values()],
            "rounds": [
                {
                    "base_effects": list(r.base_effects),
                    "rmse_before_um": _num(r.rmse_before_um),
                    "accepted": r.accepted,
                    "rmse_after_um": _num(r.rmse_after_um),
                    "localization": r.localization,
                    "candidates": [c.as_dict() for c in r.candidates],
                    "pairs": [c.as_dict() for c in r.pairs],
                }
                for r in self.rounds
            ],
            "test": {
                "name": "one-sided Diebold-Mariano test on per-sweep held-out MSE differentials, "
                "Newey-West variance within runs, HLN correction, Holm-adjusted over the round's candidates",
            },
        }


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


# ---------------------------------------------------------------- folds


def make_folds(runs: Sequence[Run]) -> list[Fold]:
    """Leave-one-run-out for >= 2 runs; a two-block time split of the sweeps for one run."""
    if len(runs) >= 2:
        for r in runs:
            n = np.unique(r.errors.time_s).size
            if n < MIN_HELDOUT_SWEEPS:
                # held out, it would be the whole evidence of one fold: one sweep tests a constant, not a drift
                raise ValueError("run %s has only %d sweep%s; each run is held out once and needs at least %d (as each "
                                 "half of a one-run time split does)" % (r.path or r.name, n, "" if n == 1 else "s",
                                                                          MIN_HELDOUT_SWEEPS))
        folds = []
        for k in range(len(runs)):
            train = [None if i == k else np.ones(len(r.errors), bool) for i, r in enumerate(runs)]
            test = [np.ones(len(r.errors), bool) if i == k else None for i, r in enumerate(runs)]
            folds.append(Fold(train, test))
        return folds
    e = runs[0].errors
    times = np.unique(e.time_s)
    if times.size < 2 * MIN_HELDOUT_SWEEPS:
        raise ValueError("run %s has only %d sweeps; a held-out time split needs at least %d (or give more runs)"
                         % (runs[0].name, times.size, 2 * MIN_HELDOUT_SWEEPS))
    cut = times[times.size // 2]
    first = e.time_s < cut
    return [Fold([~first], [first]), Fold([first], [~first])]


# ---------------------------------------------------------------- parallel plumbing

_STATE = {}


def _init_worker(family, runs, folds):
    _STATE["family"], _STATE["runs"], _STATE["folds"] = family, runs, folds


def _fit_fold(task):
    effects, k, start = task
    family, runs, fold = _STATE["family"], _STATE["runs"], _STATE["folds"][k]
    try:
        fitted = family.fit(runs, fold.train, tuple(effects), start)
        preds = [None if m is None else np.asarray(family.predict(fitted, r), dtype=float) for r, m in zip(runs, fold.test)]
    except Exception as exc:  # a failing candidate fit must not sink the whole analysis
        return None, None, "%s: %s" % (type(exc).__name__, exc)
    return fitted, preds, None


class _Pool:
    """Runs fold fits serially or in forked worker processes (``jobs`` > 1)."""

    def __init__(self, family, runs, folds, jobs):
        self.jobs = jobs
        self.ex = None
        _init_worker(family, runs, folds)
        if jobs > 1 and "fork" in mp.get_all_start_methods():
            self.ex = ProcessPoolExecutor(jobs, mp_context=mp.get_context("fork"), initializer=_init_worker, initargs=(family, runs, folds))

    def map(self, tasks):
        if self.ex is None:
            return [_fit_fold(t) for t in tasks]
        return list(self.ex.map(_fit_fold, tasks))

    def close(self):
        if self.ex is not None:
            self.ex.shutdown()


def _assemble(runs, folds, effects, results):
    res = [np.full(len(r.errors), np.nan) for r in runs]
    fits = []
    for fold, (fitted, preds, err) in zip(folds, results):
        if err:
            return None, err
        fits.append(fitted)
        for i, (m, p) in enumerate(zip(fold.test, preds)):
            if m is not None:
                res[i][m] = runs[i].errors.error_um[m] - p[m]
    return HeldOut(tuple(effects), res, fits), None


def _losses(runs, residuals):
    return [stats.sweep_losses(r, run.errors.time_s) for run, r in zip(runs, residuals)]


# ---------------------------------------------------------------- the loop


def _score(pool, runs, folds, effects, current, sets, cands):
    """Held-out fits of base+set for each set; fills the Candidate records, returns {name: HeldOut}."""
    tasks = [(tuple(effects) + tuple(st), k, current.fits[k]) for st in sets for k in range(len(folds))]
    out = pool.map(tasks)
    loss0 = _losses(runs, current.residuals)
    held = {}
    for j, (st, c) in enumerate(zip(sets, cands)):
        ho, err = _assemble(runs, folds, tuple(effects) + tuple(st), out[j * len(folds):(j + 1) * len(folds)])
        if err or ho is None:
            c.error = err
            continue
        held[c.name] = ho
        c.heldout = ho
        c.rmse_um = ho.rmse()
        c.score = 1.0 - c.rmse_um / current.rmse() if current.rmse() > 0 else 0.0
        t = stats.dm_test(loss0, _losses(runs, ho.residuals), log=LOG_LOSS)
        c.p_raw, c.statistic = t["p_value"], t["statistic"]
    tested = [c for c in cands if c.name in held]
    for c, p in zip(tested, stats.holm_adjust([c.p_raw for c in tested])):
        c.p_value = float(p)
    return held


def _try_pairs(pool, runs, folds, effects, current, singles, rnd, alpha, min_gain, log):
    """Effects can mask each other: with two missing, neither alone may fit well (the base
    parameters absorb part of each). When no single candidate passes, test every pair
    jointly (Holm over the pairs); accept the best pair if it passes, and if it also beats
    each of its members alone (one-sided DM at ``alpha``), so no passenger rides along."""
    by = {c.name: c for c in singles}
    names = [c.name for c in singles]
    sets = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    cands = [Candidate("+".join(st)) for st in sets]
    held = _score(pool, runs, folds, effects, current, sets, cands)
    rnd.pairs = cands
    for c in cands:
        if c.name in held:
            log("  pair %-29s held-out RMSE %.3f  gain %+.1f%%  p %.2g" % (c.name, c.rmse_um, 100 * c.score, c.p_value))
    ok = [c for c, st in zip(cands, sets) if c.name in held and c.score >= min_gain and c.p_value < alpha]
    if not ok:
        return None, None
    best = max(ok, key=lambda c: c.score)
    st = sets[cands.index(best)]
    ho = held[best.name]
    lp = _losses(runs, ho.residuals)
    for name in st:
        if not math.isfinite(by[name].rmse_um) or by[name].heldout is None:
            return None, None
        t = stats.dm_test(_losses(runs, by[name].heldout.residuals), lp, log=LOG_LOSS)
        if not (t["p_value"] < alpha and ho.rmse() < by[name].rmse_um):
            log("  pair %s does not beat %s alone (p %.2g)" % (best.name, name, t["p_value"]))
            return None, None
    best.accepted = True
    order = sorted(st, key=lambda n: -by[n].score)
    for name in order:
        c = by[name]
        c.accepted, c.joint_with = True, [n for n in order if n != name]
        c.single_score, c.single_p_value, c.single_rmse_um = c.score, c.p_value, c.rmse_um
        c.score, c.p_value, c.rmse_um = best.score, best.p_value, best.rmse_um
    return tuple(order), ho


def discover(runs: Sequence[Run], family: Any, candidates: Sequence[str] | None = None, alpha: float = ALPHA, min_gain: float = MIN_GAIN, max_effects: int | None = None, jobs: int | None = None, base_effects: Sequence[str] = (), log: Callable[[str], None] | None = None) -> Result:
    """Find the catalog effects the base model is missing, one per round.

    Returns a :class:`Result`. ``candidates`` defaults to ``family.candidates``.
    A candidate passes when its held-out RMSE reduction is at least ``min_gain``
    and its Holm-adjusted DM p-value is below ``alpha``; of the passing ones the
    largest reduction is accepted. With none passing, pairs are tried.
    """
    log = log or (lambda msg: None)
    candidates = list(family.candidates if candidates is None else candidates)
    jobs = jobs or min(2, os.cpu_count() or 1)
    folds = make_folds(runs)
    pool = _Pool(family, runs, folds, jobs)
    try:
        effects = list(base_effects)
        base_res = pool.map([(tuple(effects), k, None) for k in range(len(folds))])
        current, err = _assemble(runs, folds, effects, base_res)
        if err or current is None:
            raise RuntimeError("the base model could not be fitted: %s" % err)
        first = current
        log("base model %s: held-out RMSE %.3f um" % ("+".join(effects) or "(no effects)", current.rmse()))
        rounds = []
        while True:
            rnd = Round(tuple(effects), current.rmse(), [], localization=localize(runs, current.residuals))
            rounds.append(rnd)
            todo = []
            for name in candidates:
                if name in effects:
                    continue
                c = Candidate(name)
                c.skipped = family.applicable(runs, name)
                c.note = getattr(family, "note", lambda runs, name: None)(runs, name)
                rnd.candidates.append(c)
                if not c.skipped:
                    todo.append(c)
            if not todo or (max_effects is not None and len(effects) >= max_effects):
                break
            held = _score(pool, runs, folds, effects, current, [(c.name,) for c in todo], todo)
            tested = [c for c in todo if c.name in held]
            for c in todo:
                log("  %-22s held-out RMSE %s  gain %s  p %s%s" % (
                    c.name, "%.3f" % c.rmse_um if math.isfinite(c.rmse_um) else "-", "%+.1f%%" % (100 * c.score) if math.isfinite(c.score) else "-",
                    "%.2g" % c.p_value, "  (fit failed: %s)" % c.error if c.error else "") + ("\n      note: %s" % c.note if c.note else ""))
            # the best of the candidates that pass both rules (Holm keeps the family-wise
            # error of the round at alpha whichever of them is taken)
            passing = [c for c in tested if c.score >= min_gain and c.p_value < alpha]
            best = max(passing, key=lambda c: c.score, default=None)
            if best is not None:
                best.accepted = True
                rnd.accepted = best.name
                effects.append(best.name)
                current = held[best.name]
            else:
                pair, current_pair = None, None
                if len(tested) >= 2 and (max_effects is None or len(effects) + 2 <= max_effects):
                    pair, current_pair = _try_pairs(pool, runs, folds, effects, current, tested, rnd, alpha, min_gain, log)
                if pair is None or current_pair is None:
                    log("no catalog effect explains the remaining gap")
                    break
                current = current_pair
                rnd.accepted = "+".join(pair)
                effects.extend(pair)
            rnd.rmse_after_um = current.rmse()
            log("accepted %s: held-out RMSE %.3f -> %.3f um" % (rnd.accepted, rnd.rmse_before_um, rnd.rmse_after_um))
    finally:
        pool.close()
    result = Result(effects[len(base_effects):], first, current, rounds, list(runs))
    start = current.fits[0] if current.fits else None
    if hasattr(family, "fit_final"):
        result.final_fit = family.fit_final(runs, tuple(effects), start)
    else:
        result.final_fit = family.fit(runs, [np.ones(len(r.errors), bool) for r in runs], tuple(effects), start)
    return result
