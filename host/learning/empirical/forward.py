"""Forward-chaining validation: fit on the past, score on the next block, for every block.

Leave-one-cycle-out lets a model be fitted on cycles *after* the one it is
scored on, and scores it with filters that have run since the run's cold start.
Neither holds on a machine: a model is fitted once, on what has happened, and
then predicts what comes next, often after the board was switched on on a warm
machine. Forward chaining measures that:

* the training data are cut into **blocks in time order**: with several
  training runs, each run is a block (in the order given, which must be time
  order); with one run, its spindle's phases (:func:`phase_edges`: a block from
  every start out of standstill and every stop to standstill, so heating and
  cooling are scored apart, each the "next regime" a model must predict), a
  phase cut to less than a quarter of the longest merged into the one before
  it; with no spindle log, ``FORWARD_BLOCKS`` (4) equal time blocks;
  ``forward_blocks=N`` asks for N equal time blocks instead,
  ``forward_blocks="cycles"`` the spindle cycles (host/learning/empirical/
  schedule.py; the default before stop 30). At least ``MIN_BLOCKS`` (3) blocks,
  so at least two are scored and no single period decides;
* for every block k >= 1 the model is fitted on blocks 0..k-1 only and scored
  on block k **as its own run**: :func:`host.data.runs.slice_run` cuts the run
  at the block's first sample, and the model's ``predict`` is called on that
  run, i.e. as a board switched on at the block's start computes it (its state
  and its latched reference start there). That call is the interface to the
  model's state handling: a model with an observer is scored with it;
* reported: per block its samples, RMSE, and the same model's RMSE with its
  filters running since the run start (``continuous_rmse_um``), then the worst
  block and the pooled RMSE over every scored sample.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from host.data.runs import slice_run
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.schedule import block_labels, cycles, segments

if TYPE_CHECKING:  # for the hints only
    from host.data.runs import Run
    from host.learning.empirical.targets import RunArrays

FORWARD_BLOCKS = 4  # equal time blocks of one run without a spindle log
MIN_BLOCKS = 3  # two scored blocks at least (the same rule as dynamic.py's selection)
RULE = ("blocks in time order: the training runs (several runs), else the spindle's running and stopped phases of the run "
        "(a phase under a quarter of the longest joins the one before), else %d equal time blocks (forward_blocks=N: N equal "
        "time blocks; forward_blocks=\"cycles\": the spindle cycles, a cycle under a quarter of the longest joining the one "
        "before); block k >= 1 scored by the model fitted on blocks < k, predicting block k as its own run (a board "
        "switched on at its start)" % FORWARD_BLOCKS)
PHASES = "phases"  # forward_blocks value (the default with a spindle log): a block per running and per stopped phase (phase_edges)
CYCLES = "cycles"  # forward_blocks value: a block per spindle cycle (the default before stop 30)
# dynamic option controller_scoring (with spindle_states=controller): how a switched-on block is scored
RECORD = "record"  # the default: the states the controller supplies start at its record's values
WORSE = "worse"  # the worse of that start and a start without the record (those states at the observer's estimate)
CONTROLLER_SCORINGS = (RECORD, WORSE)


def phase_edges(run: Run) -> list[float]:
    """Times at which the spindle starts from standstill or stops to standstill (ascending): the edges of the
    ``forward_blocks="phases"`` blocks. A change between two running speeds is no edge (a mixed cycle's running phase
    is one block, as in the cycles rule), nor is the log's first sample. Heating (running) and cooling (stopped) are
    scored apart: the next regime a model must predict is often heating at a new speed or cooling from a new state."""
    if run.spindle is None:
        raise EmpiricalDataError("%s: forward_blocks=\"%s\" cuts the run at the spindle's starts and stops, but the run has "
                                 "no spindle.csv; give forward_blocks=N (N equal time blocks) instead" % (run.name, PHASES))
    segs = segments(run)
    return [t0 for (t0, _, rpm), (_, _, before) in zip(segs[1:], segs[:-1]) if (rpm > 0) != (before > 0)]


def forward_blocks(runs: Iterable[Run], arrays: Iterable[RunArrays],
                   forward_blocks: int | str | None = None) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Blocks of the stacked training samples -> (labels (n,) ascending in time, [block dict]).

    ``forward_blocks``: None (the rule above), an integer N >= ``MIN_BLOCKS`` (N equal time blocks) or ``"phases"``
    (:func:`phase_edges`). Each block: ``{"block": k, "run": i, "t_start_s", "t_end_s"}`` (its first and last target time).
    """
    from host.learning.empirical.fitting import merge_small_groups

    runs, arrays = list(runs), list(arrays)
    if len(arrays) >= 2:
        if forward_blocks is not None:
            raise EmpiricalDataError("forward_blocks applies to a single training run; with %d runs each run is a block" % len(arrays))
        # runs carry no absolute clock: the order given is the time order (documented)
        labels = np.concatenate([np.full(a.y.size, i) for i, a in enumerate(arrays)])
    else:
        t = arrays[0].time_s
        choices = "an integer >= %d, \"%s\" or \"%s\"" % (MIN_BLOCKS, PHASES, CYCLES)
        if forward_blocks is None:
            forward_blocks = FORWARD_BLOCKS if runs[0].spindle is None else PHASES
        if isinstance(forward_blocks, str):
            if forward_blocks not in (PHASES, CYCLES):
                raise EmpiricalDataError("forward_blocks must be %s, got %r" % (choices, forward_blocks))
            if forward_blocks == CYCLES and runs[0].spindle is None:
                raise EmpiricalDataError("%s: forward_blocks=\"%s\" cuts the run at the spindle's cycles, but the run has no "
                                         "spindle.csv; give forward_blocks=N (N equal time blocks) instead" % (runs[0].name, CYCLES))
            edges = phase_edges(runs[0]) if forward_blocks == PHASES else [c["t_start_s"] for c in cycles(runs[0])[1:]]
            # a phase or cycle cut to under a quarter of the longest by the training window (or a short stop) would otherwise
            # be a block of a few samples weighing as much as a whole one
            labels = merge_small_groups(block_labels(t, edges))
        else:
            k = forward_blocks
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < MIN_BLOCKS:
                raise EmpiricalDataError("forward_blocks must be %s, got %r" % (choices, k))
            labels = block_labels(t, np.linspace(t.min(), t.max(), int(k) + 1)[1:-1])
        labels = np.unique(labels, return_inverse=True)[1].reshape(-1)  # 0..K-1, ascending in time
    labels = np.asarray(labels, dtype=int)
    blocks = []
    offset = 0
    for i, a in enumerate(arrays):
        lab = labels[offset:offset + a.y.size]
        for k in np.unique(lab):
            tk = a.time_s[lab == k]
            blocks.append({"block": int(k), "run": i, "t_start_s": float(tk.min()), "t_end_s": float(tk.max())})
        offset += a.y.size
    if len(blocks) < MIN_BLOCKS:
        raise EmpiricalDataError("forward-chaining validation needs at least %d time blocks (%d scored), got %d (%s); give "
                                 "forward_blocks=N for one run, or more runs" % (MIN_BLOCKS, MIN_BLOCKS - 1, len(blocks), RULE))
    return labels, blocks


def folds(labels: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """[(k, training mask, scored mask)] for every block k >= 1: training = blocks before k, scored = block k."""
    labels = np.asarray(labels)
    return [(int(k), labels < k, labels == k) for k in np.unique(labels)[1:]]


def block_run(runs: Sequence[Run], block: dict[str, Any]) -> Run:
    """Block ``block`` of the training runs as its own run: from its first target time's temperature sample to its
    last target time (a whole run when the runs are the blocks)."""
    run = runs[block["run"]]
    if len(runs) >= 2:
        return run
    tt = np.asarray(run.temperatures.time_s, dtype=float)
    i0 = max(int(np.searchsorted(tt, block["t_start_s"], side="right")) - 1, 0)
    i1 = int(np.searchsorted(tt, block["t_end_s"], side="left"))  # the first sample at or after the last target time
    end = None if i1 + 1 >= tt.size else float(tt[i1 + 1])
    try:
        return slice_run(run, float(tt[i0]), end)
    except ValueError as exc:
        raise EmpiricalDataError(str(exc))


def block_record(runs: Sequence[Run], block: dict[str, Any]) -> list[Run]:
    """The controller's record before block ``block`` as its own run (:func:`block_run`): the run up to the block's first
    sample (one run); none when the runs are the blocks (each starts its machine cold)."""
    run = runs[block["run"]]
    if len(runs) >= 2:
        return []
    first, start = float(run.temperatures.time_s[0]), float(block_run(runs, block).temperatures.time_s[0])
    if start <= first:
        return []
    try:
        return [slice_run(run, first, start)]
    except ValueError as exc:
        raise EmpiricalDataError(str(exc))


def block_residuals(model: Any, run: Run, block: dict[str, Any], controller_history: Sequence[Run] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(measured, predicted) of ``model.predict(run)`` over the rows of ``run`` inside ``block``'s time span;
    ``controller_history``: the controller's record before ``run``, for a model with states the controller supplies."""
    from host.learning.empirical.observer import reads_controller

    # an empty record is a controller that starts with the run (the supplied states at its first input); None, no
    # controller's values at all (the states the controller supplies then start at the observer's estimate)
    pred = (model.predict(run, controller_history=controller_history) if controller_history is not None and reads_controller(model)
            else model.predict(run))
    rows = model._rows(run)
    t = run.errors.time_s[rows]
    rows = rows[(t >= block["t_start_s"]) & (t <= block["t_end_s"])]
    rows = rows[np.isfinite(pred[rows])]
    if not rows.size:
        raise EmpiricalDataError("%s: no prediction in block %d" % (run.name, block["block"]))
    return run.errors.error_um[rows], pred[rows]


def forward_chaining(runs: Sequence[Run], blocks: Sequence[dict[str, Any]], refit: Callable[[int], Any],
                     target: str = "direct") -> dict[str, Any]:
    """Score ``refit(k)`` (a model fitted on blocks < k) on every block k >= 1 -> the ``forward_chaining`` statistics.

    The model predicts block k as its own run (:func:`block_run`) and, for comparison, with its filters running since
    the start of the block's training run (``continuous_rmse_um``). A model with lag states the controller supplies
    predicts it with the controller's record before the block, and also without it (``without_record_rmse_um``: those
    states at the observer's estimate, a controller that does not send them), and the pooled worse of the two per block
    (``worse_of_starts_pooled_um``: controller_scoring=worse's criterion, so that structures chosen by either scoring
    compare on it; for a model without supplied states it is ``pooled_um``). For slope targets the score is on the
    whole error (geometric + thermal, as ``comprehensive`` in scoring.py): a block has no cold sweep of its own.
    """
    from host.learning.empirical.observer import reads_controller

    out, sq, sq_without, sq_worse, n_all = [], 0.0, 0.0, 0.0, 0
    for b in blocks:
        if b["block"] == 0:
            continue
        model = refit(b["block"])
        m, p = block_residuals(model, block_run(runs, b), b, block_record(runs, b))
        mc, pc = block_residuals(model, runs[b["run"]], b)
        r = m - p
        out.append({"block": b["block"], "run": b["run"], "t_start_s": b["t_start_s"], "t_end_s": b["t_end_s"], "n": int(r.size),
                    "rmse_um": float(np.sqrt(np.mean(r ** 2))), "continuous_rmse_um": float(np.sqrt(np.mean((mc - pc) ** 2))),
                    "rms_measured_um": float(np.sqrt(np.mean(m ** 2)))})
        if reads_controller(model):
            mw, pw = block_residuals(model, block_run(runs, b), b)
            out[-1]["without_record_rmse_um"] = float(np.sqrt(np.mean((mw - pw) ** 2)))
            sq_without += float((mw - pw) @ (mw - pw))
            sq_worse += max(float(r @ r), float((mw - pw) @ (mw - pw)))
        sq += float(r @ r)
        n_all += r.size
    fc = {"rule": RULE, "score": "whole error (slope: geometric + thermal)" if target == "slope" else "error of the channel",
          "blocks": len(blocks), "scored": out, "rmse_um": [f["rmse_um"] for f in out],
          "worst_um": max(f["rmse_um"] for f in out), "pooled_um": float(np.sqrt(sq / n_all))}
    # how much of the pooled score one block carries: a structure chosen mostly by one period (FL_THERMAL 24.13 h ch2:
    # the 2500 rpm heating predicted from 4 h at 1250 rpm, 84 %) rests on how that period resembles the future
    block_sq = [f["n"] * f["rmse_um"] ** 2 for f in out]
    k = int(np.argmax(block_sq))
    fc["largest_share"] = {"block": out[k]["block"], "share": block_sq[k] / sum(block_sq) if sum(block_sq) > 0 else 0.0}
    if all("without_record_rmse_um" in f for f in out):
        fc["without_record_rmse_um"] = [f["without_record_rmse_um"] for f in out]
        fc["without_record_pooled_um"] = float(np.sqrt(sq_without / n_all))
        fc["worse_of_starts_pooled_um"] = float(np.sqrt(sq_worse / n_all))
    return fc


def linear_forward_chaining(model: Any, runs: Iterable[Run], target: str = "slope", channel: str | None = None,
                            fit_intercept: bool = True,
                            window: tuple[float | None, float | None] | None = None) -> dict[str, Any]:
    """``forward_chaining`` statistics of a static linear model: MLR on the model's own sensors refitted on the blocks
    before each scored block (the document contract: temperatures over the fixed reference, so a board switched on at
    a block's start predicts as one that never stopped). Its sensor choice was made on all training data."""
    from host.learning.empirical.fitting import fit_model
    from host.learning.empirical.targets import training_arrays

    runs = list(runs)
    arrays = training_arrays(runs, target, channel, list(model.sensors), window=window)
    labels, blocks = forward_blocks(runs, arrays)
    start = {b["block"]: b["t_start_s"] for b in blocks}
    lo = None if window is None else window[0]

    def refit(k):
        if len(runs) >= 2:
            return fit_model(runs[:k], "mlr", target, channel, list(model.sensors), fit_intercept, forward_chaining=False)
        return fit_model(runs, "mlr", target, channel, list(model.sensors), fit_intercept, window=(lo, start[k]), forward_chaining=False)

    out = forward_chaining(runs, blocks, refit, target)
    out["structure"] = "the method's sensors as chosen on all training data; MLR on them refitted on the blocks before each scored block"
    return out


def fit_fold_observer(model: Any, runs: Sequence[Run], blocks: Sequence[dict[str, Any]], k: int,
                      exclude: tuple[float | None, float | None] | None = None, scale: float = 1.0, controller: Sequence[str] = ()) -> Any:
    """The observer of ``model`` as the board scored on block ``k`` has it: fitted on the blocks before ``k`` only
    (several runs: the runs before it; one run: the span of the blocks before it), never on block ``k`` or later.
    The one place that says which samples a fold's observer sees: the reported score (fitting.py's refit) and the
    switched-on selection (:func:`observer_block_columns`) both call it."""
    from host.learning.empirical.observer import fit_observer

    if len(runs) >= 2:
        return fit_observer(model, list(runs[:k]), exclude=exclude, scale=scale, controller=controller)
    past = [b for b in blocks if b["block"] < k]
    span = [(min(b["t_start_s"] for b in past), max(b["t_end_s"] for b in past))]
    return fit_observer(model, runs, spans=span, exclude=exclude, scale=scale, controller=controller)


def short_blocks(runs: Sequence[Run], blocks: Sequence[dict[str, Any]], min_s: float) -> list[int]:
    """The scored blocks of one run (block >= 1) that last less than ``min_s``: the selection scores them with the
    filters running since the run start, not as a board switched on at the block's start (fitting.SWITCHED_ON_MIN_S).
    Several runs: none (each run is a block and really starts its board)."""
    if len(runs) >= 2:
        return []
    return [int(b["block"]) for b in blocks if b["block"] >= 1 and b["t_end_s"] - b["t_start_s"] < min_s]


def observer_block_columns(runs: Sequence[Run], arrays: Sequence[RunArrays], labels: np.ndarray, blocks: Sequence[dict[str, Any]],
                           terms: Sequence[tuple[str, float]], reference_C: dict[str, float], target: str = "direct",
                           channel: str | None = None, exclude: tuple[float | None, float | None] | None = None,
                           scale: float = 1.0, scored: Sequence[dict[str, Any]] | None = None,
                           controller: Sequence[str] = (), scoring: str = RECORD) -> dict[int, Any]:
    """{block k >= 1: StartedColumns}: every candidate term's column on block k as a board switched on at the block's
    start with its observer computes it, for whichever structure the selection tries. ``scored``: only these of
    ``blocks`` (default: all); the observers are still fitted on ``blocks`` before k.

    The inputs are the board's (temperatures over the fixed ``reference_C``, host/learning/empirical/observer.py
    ``inputs``) on the block as its own run (:func:`block_run`); each lag column is its filter from rest plus the
    start estimate decaying (dynamic.StartedColumns). The start estimate of a structure's term is what the observer
    of *that structure* gives: fitted for the structure's own signals (its regressors on the board), on the blocks
    before k only (:func:`fit_fold_observer`), read at the block's first sample (``Observer.initial_states``). An
    observer's estimate of one state does not depend on the other states, so one observer fitted with every lag of
    the structure's signals gives the starts of every structure with those signals: one fit per (block, signal set).

    The lag states of ``controller``'s signals start at the controller's record (the run before the block). With
    ``scoring`` = "worse" (CONTROLLER_SCORINGS) each block is a dynamic.WorseOfStarts of that start and of the start a
    board gets whose controller does not send the record (those states at the observer's estimate, as the rest).
    """
    from host.learning.empirical.dynamic import DynamicModel, StartedColumns, WorseOfStarts, _lag_filter_fast
    from host.learning.empirical.observer import inputs, record_lags, signals_of

    terms = [(str(n), float(tau)) for n, tau in terms]
    names = signals_of(terms)
    lag_taus = sorted({tau for _, tau in terms if tau > 0})
    index = {term: j for j, term in enumerate(terms)}
    times = np.concatenate([a.time_s for a in arrays])
    y = np.concatenate([a.y for a in arrays])
    everything = DynamicModel([(n, 0.0) for n in names], np.zeros(len(names)), 0.0, target, channel, reference_C=reference_C)
    out = {}
    for b in blocks if scored is None else scored:
        k = b["block"]
        if k == 0:
            continue
        rows = labels == k
        tk = times[rows]
        t, sig = inputs(everything, block_run(runs, b))
        missing = [n for n in names if n not in sig]
        if missing:
            raise EmpiricalDataError("block %d: the signal(s) %s are missing from the block's logs" % (k, ", ".join(missing)))
        rest = np.empty((tk.size, len(terms)))
        decay = np.zeros((tk.size, len(terms)))
        U = np.column_stack([sig[n] for n in names])
        for tau in sorted({tau for _, tau in terms}):
            filtered = np.asarray(_lag_filter_fast(t, U, tau))  # from 0 at the block's first sample (tau 0: the input)
            d = np.interp(tk, t, np.exp(-(t - t[0]) / tau)) if tau > 0 else None
            for i, n in enumerate(names):
                j = index.get((n, tau))
                if j is not None:
                    rest[:, j] = np.interp(tk, t, filtered[:, i])
                    if d is not None:
                        decay[:, j] = d
        u0 = {n: float(sig[n][0]) for n in names}
        # the controller's record of its own signals: their lag states at the block's start (what predict computes)
        supplied = [(n, tau) for n in names if n in controller for tau in lag_taus if (n, tau) in index]
        exact = dict(zip((index[q] for q in supplied), record_lags(block_record(runs, b), block_run(runs, b), supplied))) if supplied else {}
        starts = _StartEstimates(runs, blocks, k, terms, index, lag_taus, u0, reference_C, target, channel, exclude, scale,
                                 controller, exact)
        out[k] = StartedColumns(rest, decay, y[rows], starts)
        if scoring == WORSE and exact:
            out[k] = WorseOfStarts([out[k], StartedColumns(rest, decay, y[rows], starts.without_record)])
    return out


class _StartEstimates:
    """start(cols) of StartedColumns for one block: the observer of the structure's signal set, fitted on the blocks
    before it, read at the block's first sample; cached per signal set."""

    def __init__(self, runs, blocks, k, terms, index, lag_taus, u0, reference_C, target, channel, exclude, scale, controller=(), exact=None):
        self.runs, self.blocks, self.k, self.terms, self.index = runs, blocks, k, terms, index
        self.lag_taus, self.u0, self.reference_C = lag_taus, u0, reference_C
        self.target, self.channel, self.exclude, self.scale = target, channel, exclude, scale
        self.controller, self.exact = tuple(controller), dict(exact or {})
        self.cache: dict[frozenset, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, cols):
        """The starts of ``cols`` with the controller's record (its exact values for the states it supplies)."""
        cols = list(cols)
        return self._estimates(cols)[1][cols]

    def without_record(self, cols):
        """The starts of ``cols`` on a board whose controller does not send the record: every state at the observer's
        estimate (its gains for the states the controller would supply, as fit_observer writes them)."""
        cols = list(cols)
        return self._estimates(cols)[0][cols]

    def _estimates(self, cols):
        """(the observer's estimates, the same with the record's values) over every candidate, for ``cols``' signals."""
        from host.learning.empirical.dynamic import DynamicModel

        order = list(dict.fromkeys(self.terms[c][0] for c in cols))  # the structure's signals, first-use order
        key = frozenset(order)
        pair = self.cache.get(key)
        if pair is None:
            vec = np.zeros(len(self.terms))
            lagged = [(n, tau) for n in order for tau in self.lag_taus]
            if lagged:
                model = DynamicModel(lagged, np.zeros(len(lagged)), 0.0, self.target, self.channel, reference_C=self.reference_C)
                obs = fit_fold_observer(model, self.runs, self.blocks, self.k, self.exclude, self.scale, self.controller)
                for j, v in obs.initial_states({n: self.u0[n] for n in order}).items():
                    if lagged[j] in self.index:  # a lag of the structure's signals that is among the candidates
                        vec[self.index[lagged[j]]] = v
            recorded = vec.copy()
            for c, v in self.exact.items():
                recorded[c] = v
            pair = self.cache[key] = (vec, recorded)
        return pair


BASELINE = "mlr_all"  # the fixed reference a dynamic model's forward-chaining score is reported beside


def baseline_mlr_all(runs: Sequence[Run], blocks: Sequence[dict[str, Any]], target: str, channel: str | None,
                     sensors: Sequence[str], fit_intercept: bool = True,
                     window: tuple[float | None, float | None] | None = None,
                     exclude: tuple[float, float] | None = None) -> dict[str, Any]:
    """Forward-chaining score of a plain MLR on every candidate sensor (temperatures over the fixed reference, so
    switched on at a block's start it predicts as one that never stopped) on the same ``blocks``: block k scored by
    the MLR fitted on the blocks before it. A fixed reference, chosen by nothing, that a dynamic model's own score is
    reported beside (``statistics.forward_chaining.baseline_mlr_all``)."""
    from host.learning.empirical.fitting import fit_model

    runs = list(runs)
    start = {b["block"]: b["t_start_s"] for b in blocks}
    lo = None if window is None else window[0]

    def refit(k):
        if len(runs) >= 2:
            return fit_model(runs[:k], "mlr", target, channel, list(sensors), fit_intercept, window=window, exclude=exclude,
                             forward_chaining=False)
        return fit_model(runs, "mlr", target, channel, list(sensors), fit_intercept, window=(lo, start[k]), exclude=exclude,
                         forward_chaining=False)

    out = forward_chaining(runs, blocks, refit, target)
    return {"method": "mlr", "sensors": list(sensors), "rmse_um": out["rmse_um"], "worst_um": out["worst_um"],
            "pooled_um": out["pooled_um"],
            "structure": "MLR on all %d candidate sensors (fixed reference), refitted on the blocks before each scored block" % len(sensors)}
