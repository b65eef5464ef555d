"""The dynamic model's lag states recovered from the sensors when a board starts on a warm machine.

A dynamic model (host/learning/empirical/dynamic.py) carries a state: each lag
term's filter output y_j = L_τj[u_j], with time constants up to hours. Started at
rest, as the run-start convention does, the state is right only on a machine
that is itself at rest; a board switched on (or reset) on a warm machine then
predicts from a zero state, and the error lasts as long as the longest lag.

The observer replaces "at rest" by an estimate from what the board reads at the
moment it starts:

1. Inputs are referenced to a fixed temperature, the training's ``reference_C``
   (u = T − reference_C), not to the run's first sample, so that a rise does not
   depend on when the board was switched on.
2. Each lag state is estimated from what the board reads at that moment, its
   filter inputs u_i (the model sensors' rises over reference_C, and the
   spindle speed, its square and the feed where the model uses them; with the
   option ``observer_sensors``, also the rises of sensors no term reads,
   :func:`choose_observer_sensors`), by a static linear map fitted on the
   training runs, where the true states are known (the filters run through
   each training run from its cold start):

       ŷ_j = Σ_i G_ji · u_i                                  (least squares)

   There is no constant term: a machine at rest at its reference temperatures
   (every u_i = 0) has every state at zero, so a cold start is exactly the
   model's own start from rest. (A constant term lowers the training residual
   but moves that start: on FL_THERMAL it put 4-21 µm RMS of error into the
   first 4 h of a cold start; docs/empirical.md has the variants tried.)

   At power-on the filters start at ŷ_j; from then on they run as the model was
   fitted (no correction is injected afterwards, so once settled the board
   computes exactly the fitted model).
3. Its largest residual on the training runs, E_j = max |y_j − ŷ_j|, bounds the
   start error of state j (on conditions like the training's); the filter
   forgets it as exp(−t/τ_j). The prediction's start error is then bounded by

       B(t) = Σ_j |b_j| · E_j · exp(−t/τ_j)

   and the observer is *settling* while B(t) > ``SETTLE_TOLERANCE``. The time at
   which B falls to the tolerance, ``settle_s``, is computed once here and
   recorded in the model document: the board's SETTLING flag is the elapsed time
   since it started compared with it.

Why not a fixed-gain output injection running for ever (a steady-state Kalman
filter): the difference between a restarted and an uninterrupted board would
then decay at the observer's rate, but any gain that makes it decay within
30 min turns every lag longer than ~30 min into a blend of the static estimate,
i.e. the model loses exactly the memory that made it better than a static one.
What the sensors cannot say about the past is not recoverable from them; the
observer states how much is missing (E_j) and for how long it matters.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import FEED, SPINDLE, signals

NONNEGATIVE = SPINDLE + (FEED,)  # signals whose lag states cannot be negative

if TYPE_CHECKING:  # for the hints only
    from host.data.runs import Run
    from host.learning.empirical.dynamic import DynamicModel

SETTLE_TOLERANCE_UM = 1.0  # the restart goal: within 1 um of an uninterrupted board


class Observer:
    """Static estimate of every lag state from the model's sensors (see the module doc).

    ``states``: one entry per model term with τ > 0, in term order: {"term": index,
    "gains": {signal: G_ji}, "bound": E_j, "rms": RMS residual}; signals are the
    model's ("T:<sensor>" = T − reference_C, "spindle_krpm", "spindle_krpm2", "feed_m_min").
    ``settle_s``: when the start-error bound B(t) reaches ``tolerance`` (µm); ``scale``:
    µm of offset per unit of the model's thermal output (1 for a direct model, the
    largest training position in mm for a slope model). ``settle_without_record_s`` (only with states the controller
    supplies): the same time for a board whose controller does not send them (those states at their gains' estimate,
    bound ``bound_without_record``); None: not known (a document written before stop 33), the board then stays
    SETTLING until the values come.
    """

    def __init__(self, states: Iterable[Mapping[str, Any]], settle_s: float, tolerance: float = SETTLE_TOLERANCE_UM,
                 scale: float = 1.0, settle_without_record_s: float | None = None) -> None:
        self.states = [dict(s) for s in states]
        self.settle_s = float(settle_s)
        self.tolerance = float(tolerance)
        self.scale = float(scale)
        self.settle_without_record_s = None if settle_without_record_s is None else float(settle_without_record_s)

    def start_error_bound(self, model: DynamicModel, elapsed_s: float = 0.0) -> float:
        """B(elapsed_s) in µm (module doc)."""
        return start_error_bound(model, self.states, elapsed_s, self.scale)

    def initial_states(self, u: Mapping[str, float]) -> dict[int, float]:
        """{term index: ŷ_j} from the filter inputs {signal: value} read at power-on.

        A lag of the spindle speed, its square or the feed (inputs >= 0) is >= 0: a negative estimate is projected to
        0, as the board projects every estimate onto its state's box (firmware Evaluator.observe; the true state is
        in it, so the projection only removes error and the bound E_j still holds)."""
        out: dict[int, float] = {}
        for s in self.states:
            v = sum(g * u[name] for name, g in s["gains"].items())
            out[s["term"]] = 0.0 if s.get("signal") in NONNEGATIVE and v < 0 else v
        return out

    def to_document(self) -> dict[str, Any]:
        return {"method": "static_state_estimate", "tolerance": self.tolerance, "settle_s": self.settle_s, "scale": self.scale,
                **({} if self.settle_without_record_s is None else {"settle_without_record_s": self.settle_without_record_s}),
                "states": [{"term": int(s["term"]),
                            "gains": {k: float(v) for k, v in s["gains"].items()},
                            "bound": float(s["bound"]), "rms": float(s["rms"]),
                            **({"source": CONTROLLER} if s.get("source") == CONTROLLER else {}),
                            **({"bound_without_record": float(s["bound_without_record"])} if "bound_without_record" in s else {})}
                           for s in self.states]}

    @classmethod
    def from_document(cls, obs: Any, terms: Sequence[tuple[str, float]], observer_only: Sequence[str] = ()) -> Observer:
        """``observer_only``: the document's sensors that no term reads (the observer's own regressors "T:<sensor>")."""
        import math

        from host.learning.documents import ModelFormatError

        def num(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        where = "dynamic model document: thermal.observer"
        if not isinstance(obs, dict):
            raise ModelFormatError("%s must be an object" % where)
        if obs.get("method") != "static_state_estimate":
            raise ModelFormatError("%s.method must be 'static_state_estimate', found %r" % (where, obs.get("method")))
        for key in ("tolerance", "settle_s", "scale"):
            if not num(obs.get(key)) or obs[key] < 0 or (key == "scale" and obs[key] == 0):
                raise ModelFormatError("%s.%s must be a number %s, found %r" % (where, key, "> 0" if key == "scale" else ">= 0", obs.get(key)))
        states = obs.get("states")
        lagged = [j for j, (_, tau) in enumerate(terms) if tau > 0]
        if not isinstance(states, list) or [s.get("term") if isinstance(s, dict) else None for s in states] != lagged:
            raise ModelFormatError("%s.states must list one object per lag term (thermal.terms with tau_s > 0), in term order: "
                                   "terms %s" % (where, lagged))
        regressors = signals_of(terms) + ["T:" + v for v in observer_only]
        for i, s in enumerate(states):
            for key in ("bound", "rms"):
                if not num(s.get(key)) or s[key] < 0:
                    raise ModelFormatError("%s.states[%d].%s must be a finite number >= 0, found %r" % (where, i, key, s.get(key)))
            if "source" in s:
                if s["source"] != CONTROLLER or terms[s["term"]][0] not in CONTROLLER_SIGNALS or s["bound"] != 0:
                    raise ModelFormatError("%s.states[%d]: source %r is allowed only as 'controller', on a lag of %s, with bound 0 "
                                           "(the controller supplies that state exactly; its gains are the estimate until it does); "
                                           "found %r" % (where, i, s["source"], " / ".join(CONTROLLER_SIGNALS), s))
            if "bound_without_record" in s and ("source" not in s or not num(s["bound_without_record"]) or s["bound_without_record"] < 0):
                raise ModelFormatError("%s.states[%d].bound_without_record belongs to a state the controller supplies and must be a "
                                       "finite number >= 0, found %r" % (where, i, s.get("bound_without_record")))
            g = s.get("gains")
            if not isinstance(g, dict) or any(k not in regressors for k in g) or not all(num(v) for v in g.values()):
                raise ModelFormatError("%s.states[%d].gains must map the model's signals (%s) to finite numbers, found %r"
                                       % (where, i, ", ".join(regressors), g))
        states = [dict(s, signal=terms[s["term"]][0]) for s in states]
        nr = obs.get("settle_without_record_s")
        if "settle_without_record_s" in obs and (not num(nr) or nr < obs["settle_s"] or not any("source" in s for s in states)):
            raise ModelFormatError("%s.settle_without_record_s belongs to an observer with states the controller supplies and must "
                                   "be a finite number >= settle_s (%r), found %r" % (where, obs["settle_s"], nr))
        return cls(states, obs["settle_s"], obs["tolerance"], obs["scale"], nr)


def signals_of(terms: Iterable[tuple[str, float]]) -> list[str]:
    """The distinct signals of ``terms`` in first-use order (the observer's regressors, without observer-only sensors)."""
    return list(dict.fromkeys(n for n, _ in terms))


def regressors_of(model: DynamicModel) -> list[str]:
    """The observer's regressors: the terms' signals, then "T:<sensor>" of each sensor only the observer reads."""
    names = signals_of(model.terms)
    return names + ["T:" + s for s in model.observer_sensors if "T:" + s not in names]


def inputs(model: DynamicModel, run: Run) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Time base and every filter input {signal: (n,)} with temperatures referenced to ``reference_C`` (fixed)."""
    t, sig = signals(run, model.sensors)
    for s in model.sensors:
        if s not in model.reference_C:
            raise EmpiricalDataError("dynamic: the observer needs reference_C of sensor %s (the model document lacks it)" % s)
        sig["T:" + s] = np.asarray(run.temperatures.column(s), dtype=float) - model.reference_C[s]
    return t, sig


def _chain(model, runs):
    """Inputs of consecutive runs on one clock, as one record (each run must start at or after the previous one's end)."""
    parts = [inputs(model, r) for r in runs]
    for (ta, _), (tb, _), a, b in zip(parts, parts[1:], runs, runs[1:]):
        if ta[-1] > tb[0]:
            raise EmpiricalDataError("%s ends at %g s, after %s starts at %g s: a history must end before (or when) the run "
                                     "starts, both times on one clock (temperatures.csv time_s)" % (a.path or a.name, ta[-1], b.path or b.name, tb[0]))
    t = np.concatenate([p[0][:-1] if k + 1 < len(parts) and p[0][-1] == parts[k + 1][0][0] else p[0] for k, p in enumerate(parts)])
    sig = {}
    for name in regressors_of(model):
        cols = []
        for k, (tk, sk) in enumerate(parts):
            if name not in sk:
                what = "spindle.csv" if name in SPINDLE else "motion.csv" if name == FEED else "temperatures.csv"
                raise EmpiricalDataError("%s: the dynamic model needs the signal %s (from %s), which the run lacks" % (runs[k].name, name, what))
            drop = k + 1 < len(parts) and tk[-1] == parts[k + 1][0][0]
            cols.append(sk[name][:-1] if drop else sk[name])
        sig[name] = np.concatenate(cols)
        bad = np.flatnonzero(~np.isfinite(sig[name]))
        if bad.size:
            raise EmpiricalDataError("signal %s reads NaN/inf at %g s; no prediction from it" % (name, t[bad[0]]))
    return t, sig


def _filter_from(t, u, tau_s, y0):
    """First-order lag of u from y0 at t[0] (the recurrence of dynamic.lag_filter, zero-order hold)."""
    if tau_s <= 0:
        return np.asarray(u, dtype=float).copy()
    from scipy.signal import lfilter

    a = 1.0 - np.exp(-np.diff(t) / float(tau_s))
    dt = np.diff(t)
    if dt.size and np.allclose(dt, dt[0], rtol=1e-9, atol=1e-9):
        # y[k] = (1 − a)·y[k−1] + a·u[k−1]; with numerator [0, a] the output at k = 0 is the state zi = y0
        y, _ = lfilter([0.0, a[0]], [1.0, -(1.0 - a[0])], u, zi=[y0])
        return y
    y = np.empty(t.size)
    y[0] = y0
    for k in range(1, t.size):
        y[k] = y[k - 1] + a[k - 1] * (u[k - 1] - y[k - 1])
    return y


def board_terms(model: DynamicModel, runs: Sequence[Run], observer: bool = True,
                controller_history: Sequence[Run] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Term columns over the chained runs' time base as a board switched on at the first run's first sample computes them.

    ``observer``: start each lag state at the observer's estimate (True) or at the
    steady state of the first inputs (False: y_j = u_j, which is "at rest" for a
    machine at its reference). ``controller_history``: earlier runs (oldest first) whose spindle/feed logs are the
    controller's record before the first run, for the states the controller supplies (:func:`controller_states`).
    Returns (t, columns (n, terms)).
    """
    t, sig = _chain(model, runs)
    est = model.observer.initial_states({n: sig[n][0] for n in regressors_of(model)}) if observer and model.observer is not None else {}
    if est and model.observer is not None:
        est.update(controller_states(model, controller_history, runs[0], {n: sig[n][0] for n in signals_of(model.terms)}))
    cols = np.empty((t.size, len(model.terms)))
    for j, (name, tau) in enumerate(model.terms):
        y0 = est.get(j, sig[name][0])
        cols[:, j] = _filter_from(t, sig[name], tau, y0)
    return t, cols


CONTROLLER = "controller"  # an observer state's ``source`` when the controller supplies it (option spindle_states)
CONTROLLER_SIGNALS = NONNEGATIVE  # the signals the controller itself commands: their past is in its record, not in a sensor


def reads_controller(model: Any) -> bool:
    """Whether ``model`` (any kind) has a lag state the controller supplies."""
    return any(s.get("source") == CONTROLLER for s in getattr(getattr(model, "observer", None), "states", None) or [])


def controller_states(model: DynamicModel, record: Sequence[Run] | None, run: Run, first: Mapping[str, float]) -> dict[int, float]:
    """{term index: y_j} of the lag states the controller supplies (observer states of ``source`` "controller") when a
    board starts at ``run``'s first sample: the lag of the signal over the controller's ``record`` (earlier runs, oldest
    first, one clock, ending at or before the run starts; their spindle.csv / motion.csv only) and the run's first
    sample, started at the record's first input (at rest, as the training's states start). An empty record: the steady
    state of the run's first input (a controller that starts with the run). ``None``, no controller's values at all
    (the board's start after _SUPPLY_WAIT_MS): the observer's estimate where the state has gains (left out here: the
    caller's estimate stands), else the steady state of the first input ``first[signal]``."""
    states = [s for s in (model.observer.states if model.observer is not None else []) if s.get("source") == CONTROLLER]
    if not states:
        return {}
    if record is None:
        return {s["term"]: first[model.terms[s["term"]][0]] for s in states if not s["gains"]}
    values = record_lags(record, run, [model.terms[s["term"]] for s in states])
    return {s["term"]: v for s, v in zip(states, values)}


def record_lags(record: Sequence[Run], run: Run, lags: Sequence[tuple[str, float]]) -> list[float]:
    """The lag (signal, τ) of each of ``lags`` at ``run``'s first sample over the controller's ``record`` (earlier runs,
    oldest first, one clock, their spindle.csv / motion.csv) and that sample, started at the record's first input
    (:func:`controller_states`; the selection's switched-on blocks use it too, forward.observer_block_columns)."""
    parts = []
    for r in list(record) + [run]:
        tr, sr = signals(r, [])
        parts.append((r, tr, sr))
    for (ra, ta, _), (rb, tb, _) in zip(parts, parts[1:]):
        if ta[-1] > tb[0]:
            raise EmpiricalDataError("%s ends at %g s, after %s starts at %g s: the controller's record must end before (or when) "
                                     "the run starts, both times on one clock" % (ra.path or ra.name, ta[-1], rb.path or rb.name, tb[0]))
    t0 = parts[-1][1][0]
    out = []
    for name, tau in lags:
        if any(name not in sr for _, _, sr in parts):
            bad = next(r for r, _, sr in parts if name not in sr)
            raise EmpiricalDataError("%s: the controller's record of %s (spindle.csv or motion.csv) is missing" % (bad.path or bad.name, name))
        t = np.concatenate([tr for _, tr, _ in parts[:-1]] + [[t0]])
        u = np.concatenate([sr[name] for _, _, sr in parts[:-1]] + [[parts[-1][2][name][0]]])
        out.append(float(_filter_from(t, u, tau, u[0])[-1]))
    return out


def fit_observer(model: DynamicModel, runs: Sequence[Run], spans: Sequence[tuple[float, float]] | None = None,
                 exclude: tuple[float | None, float | None] | None = None, tolerance: float = SETTLE_TOLERANCE_UM,
                 scale: float = 1.0, controller: Iterable[str] = ()) -> Observer:
    """Fit the static state estimate of ``model``'s lag states on its training runs -> Observer.

    The true states on each training run are the filters run through it from its
    first sample, started in equilibrium with the first inputs (the cold start the
    training assumes). ``scale``: the thermal output's size in µm per model unit
    (1 for a direct model; a slope model's largest position in mm), so that the
    tolerance is in µm of offset. ``controller``: signals (spindle/feed) whose lag states the controller supplies at
    power-on from its own record of the signal (exact: bound 0, ``source`` "controller"; their gains and
    ``bound_without_record`` are the estimate until the record's value comes). ``spans``: per run, the (first, last) training time; samples
    outside it, or inside ``exclude`` = (lo, hi), do not enter the fit (what the model was not
    fitted on, e.g. a held-out period, must not shape its observer either).
    """
    lagged = [j for j, (_, tau) in enumerate(model.terms) if tau > 0]
    names = regressors_of(model)
    A, Y = [], []
    for i, r in enumerate(runs):
        t, sig = inputs(model, r)
        keep = np.ones(t.size, dtype=bool)
        if spans is not None:
            keep &= (t >= spans[i][0]) & (t <= spans[i][1])
        if exclude is not None:
            lo, hi = exclude
            keep &= ~((t >= (-np.inf if lo is None else lo)) & (t < (np.inf if hi is None else hi)))
        Yr = (np.column_stack([_filter_from(t, sig[model.terms[j][0]], model.terms[j][1], sig[model.terms[j][0]][0]) for j in lagged])
              if lagged else np.zeros((t.size, 0)))
        Y.append(Yr[keep])
        A.append(np.column_stack([sig[n] for n in names])[keep])
    A, Y = np.vstack(A), np.vstack(Y)
    if A.shape[0] < A.shape[1] + 1:
        raise EmpiricalDataError("dynamic: %d training samples cannot fit the observer's %d coefficients per state" % (A.shape[0], A.shape[1]))
    if not np.isfinite(A).all() or not np.isfinite(Y).all():
        raise EmpiricalDataError("dynamic: NaN/inf in the training inputs; the observer cannot be fitted")
    states = []
    controller = set(controller)
    for k, j in enumerate(lagged):
        coef = np.linalg.lstsq(A, Y[:, k], rcond=None)[0]
        res = Y[:, k] - A @ coef
        state = {"term": j, "signal": model.terms[j][0], "gains": dict(zip(names, (float(v) for v in coef))),
                 "bound": float(np.abs(res).max()), "rms": float(np.sqrt(np.mean(res**2)))}
        if model.terms[j][0] in controller:
            # supplied by the controller: exact with its record (bound 0, what settle_s counts); the gains are the
            # estimate a board uses until the record's value comes (a controller that does not send it)
            state.update(source=CONTROLLER, bound=0.0, bound_without_record=state["bound"])
        states.append(state)
    without = None
    if any(s.get("source") == CONTROLLER for s in states):
        # a board whose controller does not send the values: those states start at their gains' estimate
        without = settle_time(model, [dict(s, bound=s.get("bound_without_record", s["bound"])) for s in states], tolerance, scale)
    return Observer(states, settle_time(model, states, tolerance, scale), tolerance, scale, without)


def start_error_bound(model: DynamicModel, states: Iterable[Mapping[str, Any]], elapsed_s: float, scale: float = 1.0) -> float:
    """B(t) in µm: the bound of the prediction's start error ``elapsed_s`` after the board started (module doc)."""
    out = 0.0
    for s in states:
        tau = model.terms[s["term"]][1]
        out += abs(model.term_coefficients[s["term"]]) * s["bound"] * np.exp(-elapsed_s / tau)
    return out * scale


def settle_time(model: DynamicModel, states: Sequence[Mapping[str, Any]], tolerance: float = SETTLE_TOLERANCE_UM,
                scale: float = 1.0) -> float:
    """Smallest elapsed time (s, to 1 s) at which start_error_bound <= tolerance; B decreases monotonically."""
    if start_error_bound(model, states, 0.0, scale) <= tolerance:
        return 0.0
    lo, hi = 0.0, 1.0
    while start_error_bound(model, states, hi, scale) > tolerance:
        lo, hi = hi, hi * 2.0
    while hi - lo > 1.0:
        mid = 0.5 * (lo + hi)
        if start_error_bound(model, states, mid, scale) > tolerance:
            lo = mid
        else:
            hi = mid
    return float(np.ceil(hi))


OBSERVER_SENSORS_RULE = ("greedy, on the training samples only: each round refits the observer with every candidate sensor added "
                         "in turn as a regressor T:<sensor> (no term reads it) and keeps the one that lowers settle_s most "
                         "(ties: the lower start-error bound B(0)); it stops when no candidate lowers settle_s, after "
                         "observer_sensors additions, when the model reads max_sensors sensors, or when its terms and "
                         "observer-only sensors fill the table's 8 filters")


def observer_sensors_option(value: Any) -> int:
    """The dynamic option ``observer_sensors``: how many sensors beyond the terms' the observer may read (0: none)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise EmpiricalDataError("dynamic: observer_sensors must be a whole number >= 0 (how many sensors beyond the terms' the "
                                 "observer may read; 0: none), got %r" % (value,))
    return value


def choose_observer_sensors(model: DynamicModel, runs: Sequence[Run], candidates: Sequence[str], reference_C: Mapping[str, float],
                            count: int, max_sensors: int, spans: Sequence[tuple[float, float]] | None = None,
                            exclude: tuple[float | None, float | None] | None = None, scale: float = 1.0) -> dict[str, Any]:
    """Let ``model``'s observer read up to ``count`` sensors that no term reads (OBSERVER_SENSORS_RULE), the model's sensors
    staying <= ``max_sensors``. A lag state j's estimate Σ G_ji·u_i over the terms' own signals misses what those signals
    cannot say about the past; the *present* reading of another sensor (one behind a slower thermal path) can carry it.

    Sets ``model.observer_sensors``, ``model.reference_C`` of those sensors (``reference_C``: the training's reference of
    every candidate) and ``model.observer``; fitted on what the model's own observer is (``spans``, ``exclude``).
    Returns the record for the model's statistics (``observer_sensors``)."""
    model.observer_sensors = []
    observer = fit_observer(model, runs, spans=spans, exclude=exclude, scale=scale)
    record: dict[str, Any] = {"allowed": int(count), "max_sensors": int(max_sensors), "rule": OBSERVER_SENSORS_RULE,
                              "settle_s_without": observer.settle_s, "bound_um_without": observer.start_error_bound(model),
                              "chosen": [], "steps": []}
    from host.learning.empirical.averaging import BOARD_TERMS

    # the table carries each observer-only sensor as a filter of coefficient 0 (models_export/exact.py): within its 8
    room = min(int(count), int(max_sensors) - len(model.term_sensors), BOARD_TERMS - len(model.terms))
    if not observer.states:  # no lag state (e.g. the static fallback): nothing to recover
        room = 0
    own_reference = dict(model.reference_C)
    chosen: list[str] = []
    key = (observer.settle_s, observer.start_error_bound(model))
    while len(chosen) < room and key[0] > 0:
        best = None
        for c in candidates:
            if c in model.term_sensors or c in chosen:
                continue
            if c not in reference_C:
                raise EmpiricalDataError("dynamic: observer_sensors: no reference temperature of candidate sensor %s" % c)
            model.observer_sensors = chosen + [c]
            model.reference_C = dict(own_reference, **{s: float(reference_C[s]) for s in model.observer_sensors})
            trial = fit_observer(model, runs, spans=spans, exclude=exclude, scale=scale)
            k = (trial.settle_s, trial.start_error_bound(model))
            if best is None or k < best[0]:
                best = (k, c, trial)
        if best is None or not best[0][0] < key[0]:
            break
        key, observer = best[0], best[2]
        chosen.append(best[1])
        record["steps"].append({"sensor": best[1], "settle_s": key[0], "bound_um": key[1]})
    model.observer_sensors = chosen
    model.reference_C = dict(own_reference, **{s: float(reference_C[s]) for s in chosen})
    model.observer = observer
    record["chosen"] = list(chosen)
    record["settle_s"] = observer.settle_s
    return record
