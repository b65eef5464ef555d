"""Dynamic thermal-error model: first-order-lag-filtered signals with identified time constants.

A static regression on temperatures cannot represent the lag between a heat
source and the structure's deformation. This model adds it explicitly:

    δ(t) = b0 + Σ_j b_j · L_τj[u_j](t)

where each u_j is a *signal* the board has online — a temperature rise
T_s − T_s(start) of a sensor, the spindle speed (krpm) and its square as the
controller reports them, or the axis feed (m/min) — and L_τ is the causal
first-order lag 𝜏·dy/dt = u − y (τ = 0: the signal itself), started at rest
(y = 0) at the run start, when every rise is zero. The discrete form, exact for
an input held constant over each sample interval Δt (zero-order hold):

    y[k] = y[k−1] + (1 − exp(−Δt/τ)) · (u[k−1] − y[k−1])

Structure selection (which signals, which time constants) is a greedy forward
search with sequential replacement, scored by forward-chaining validation
(``selection="forward"``, the default since issue 21: the groups are time blocks
in ascending order, block k scored by the fit on blocks < k, the pooled RMSE;
host/learning/empirical/forward.py; each scored block's columns are, by default, the ones a board switched on at
the block's start computes with the observer of the structure being scored: :class:`StartedColumns`) or by
leave-one-group-out cross-validation
(``selection="loo"``: groups are the training runs or, for one run, its spindle
cycles, host/learning/empirical/schedule.py; the *worst* held-out group's RMSE:
a compensation model has to hold on every operating condition). At each step the
candidate term (signal, τ) that lowers the score most is added while the gain is
at least ``min_gain`` (1 %, relative); after each addition, single exchanges of
a chosen term for any other are made while they lower the score. At most
``max_sensors`` distinct temperature sensors (5) and ``max_terms`` terms (8).
``cv_score`` overrides the score ("worst" or "pooled"). The time constants come from the grid ``taus_s``, so
"identified" means chosen by cross-validation among them. Coefficients are
ridge least squares on RMS-scaled terms, the penalty chosen from ``ridge`` by
the same cross-validation (0 is plain least squares); lag-filtered copies of one
signal at neighbouring τ are nearly collinear, and the penalty keeps their
coefficients from cancelling each other out of the training range.

Scoring uses per-group Gram matrices of the candidate columns, so one CV
evaluation costs O(k³ · groups) whatever the number of samples.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike

from host.data.runs import check_model_reference
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import check_predict_x, finite_or_none
from host.learning.empirical.kinds import DocumentFields, _geometric_from_document, document_target

if TYPE_CHECKING:  # for the hints only (observer.py imports this module)
    from host.data.runs import Run
    from host.learning.empirical.observer import Observer
    from host.learning.empirical.settle import SettleBound

# 0 (the signal itself), 15 min .. 16 h: from a sensor's own lag to two 8 h heating/cooling cycles of a machine structure
TAUS_S = (0.0, 900.0, 1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 57600.0)
# penalty per sample on RMS-scaled terms, chosen by the same validation; 0.1 and 1 (issue 21) bound the gains: lagged copies of
# hot sensors fitted with large cancelling coefficients (33 x lag(T11, 8 h)) extrapolate badly into the next duty cycle
RIDGE = (0.0, 1e-3, 1e-2, 1e-1, 1.0)
# how the structure and the penalty are scored: "forward" (default) fits on the blocks before each block and scores that
# block (host/learning/empirical/forward.py); "loo" leaves each group (run or spindle cycle) out in turn, as before issue 21
SELECTIONS = ("forward", "loo")
# forward: the pooled held-out RMSE (the first folds are fitted on little data; the worst fold would be the first one
# whatever the structure); loo: the worst group, so that a model holds on every operating condition
DEFAULT_SCORE = {"forward": "pooled", "loo": "worst"}
MIN_BLOCKS = 3  # forward chaining: at least two scored blocks, so no single period decides the structure
# a lag is kept as a candidate only when the training span shows its response settle: a first-order lag reaches 98 % of a
# step after 4 τ, so τ <= span / 4 (docs/empirical.md)
TAU_MAX_FRACTION = 0.25


def lag_filter(time_s: ArrayLike, u: ArrayLike, tau_s: float) -> np.ndarray:
    """First-order lag of u (n,) or (n, m) sampled at time_s, from rest, zero-order-hold exact."""
    u = np.asarray(u, dtype=float)
    if tau_s <= 0:
        return u.copy()
    t = np.asarray(time_s, dtype=float)
    a = 1.0 - np.exp(-np.diff(t) / float(tau_s))
    y = np.zeros_like(u)
    for k in range(1, t.size):
        y[k] = y[k - 1] + a[k - 1] * (u[k - 1] - y[k - 1])
    return y


def _lag_filter_fast(time_s, U, tau_s):
    """lag_filter of every column of U at once with scipy's lfilter when the sampling is uniform."""
    U = np.asarray(U, dtype=float)
    if tau_s <= 0:
        return U.copy()
    dt = np.diff(time_s)
    if dt.size and np.allclose(dt, dt[0], rtol=1e-9, atol=1e-9):
        from scipy.signal import lfilter

        a = 1.0 - np.exp(-dt[0] / float(tau_s))
        # y[k] = (1 − a)·y[k−1] + a·u[k−1]: numerator [0, a], denominator [1, −(1 − a)]
        return lfilter([0.0, a], [1.0, -(1.0 - a)], U, axis=0)
    return lag_filter(time_s, U, tau_s)


SPINDLE = ("spindle_krpm", "spindle_krpm2")
FEED = "feed_m_min"


def signals(run: Run, sensors: Iterable[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Time base (the temperature log) and the raw signals {name: (n,)} the model can filter.

    Temperature rises over the run's first sample are named ``T:<sensor>``; the
    spindle speed (held from each spindle.csv sample to the next) gives
    ``spindle_krpm`` and ``spindle_krpm2``; motion.csv gives ``feed_m_min`` (the
    commanded feed while the axis moves, 0 when idle).
    """
    temps = run.temperatures
    t = np.asarray(temps.time_s, dtype=float)
    out = {}
    for s in sensors:
        if s not in temps.names:
            raise EmpiricalDataError("%s: the dynamic model needs sensor %s, not in temperatures.csv" % (run.name, s))
        col = np.asarray(temps.column(s), dtype=float)
        out["T:" + s] = col - col[0]
    if run.spindle is not None:
        sp = run.spindle
        idx = np.searchsorted(sp.time_s, t, side="right") - 1
        rpm = np.where(idx >= 0, sp.rpm[np.clip(idx, 0, None)], 0.0)
        out["spindle_krpm"] = rpm / 1000.0
        out["spindle_krpm2"] = (rpm / 1000.0) ** 2
    if run.motion is not None:
        m = run.motion
        feed = np.zeros(t.size)
        for t0, t1, f in zip(m.t_start_s, m.t_end_s, m.feed_mm_min):
            feed[(t >= t0) & (t < t1)] = f / 1000.0
        out[FEED] = feed
    return t, out


def features(run: Run, terms: Sequence[tuple[str, float]], times: ArrayLike) -> np.ndarray:
    """Columns of the model terms [(signal, tau_s)] at ``times`` (interpolated from the temperature time base)."""
    names = sorted({sig[2:] for sig, _ in terms if sig.startswith("T:")})
    t, sig = signals(run, names)
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if times.size and (times.min() < t[0] or times.max() > t[-1]):
        bad = times[(times < t[0]) | (times > t[-1])][0]
        raise EmpiricalDataError("%s: time %g s is outside the temperature log %g..%g s (no extrapolation)" % (run.name, bad, t[0], t[-1]))
    cols = []
    cache = {}
    for name, tau in terms:
        if name not in sig:
            what = "spindle.csv" if name in SPINDLE else "motion.csv" if name == FEED else "temperatures.csv"
            raise EmpiricalDataError("%s: the dynamic model needs the signal %s (from %s), which the run lacks" % (run.name, name, what))
        bad = np.flatnonzero(~np.isfinite(sig[name]))
        if bad.size:  # a filter carries a NaN into every later output: refuse, as the static models do
            raise EmpiricalDataError("%s: signal %s reads NaN/inf at %g s; no prediction from it" % (run.name, name, t[bad[0]]))
        key = (name, float(tau))
        if key not in cache:
            cache[key] = np.interp(times, t, _lag_filter_fast(t, sig[name], float(tau)))
        cols.append(cache[key])
    return np.column_stack(cols) if cols else np.zeros((times.size, 0))


def candidate_matrix(runs: Iterable[Run], times_per_run: Iterable[np.ndarray], sensors: Sequence[str], taus_s: Iterable[float],
                     use_spindle: bool = True, use_feed: bool = True) -> tuple[np.ndarray, list[tuple[str, float]] | None]:
    """Every candidate column (signal × τ) stacked over the runs -> (F (n, m), [(signal, tau)])."""
    blocks, terms = [], None
    for run, times in zip(runs, times_per_run):
        t, sig = signals(run, sensors)
        names = ["T:" + s for s in sensors]
        if use_spindle:
            names += [s for s in SPINDLE if s in sig]
        if use_feed and FEED in sig:
            names.append(FEED)
        these = [(n, float(tau)) for n in names for tau in taus_s]
        if terms is None:
            terms = these
        elif these != terms:
            raise EmpiricalDataError("%s: has different signals (%s) from the first training run; give runs with the same logs"
                                     % (run.name, ", ".join(sorted(set(n for n, _ in these) ^ set(n for n, _ in terms)))))
        U = np.column_stack([sig[n] for n in names])
        cols = []
        for tau in taus_s:
            cols.append(_lag_filter_fast(t, U, float(tau)))
        # reorder to (signal, tau) order
        stack = np.stack(cols, axis=2)  # (n_t, signals, taus)
        full = stack.reshape(t.size, -1)
        blocks.append(np.column_stack([np.interp(times, t, full[:, j]) for j in range(full.shape[1])]))
    return np.vstack(blocks), terms


class StartedColumns:
    """One forward block's candidate columns as a board switched on at the block's start computes them, when the lag
    states start at an estimate that depends on the structure (the observer is fitted for the structure's own inputs).

    The lag filter is linear and its recurrence (zero-order hold) gives, for a filter started at y0 at the block's
    first sample t0, exactly y(t) = y_rest(t) + y0 · exp(−(t − t0)/τ), with y_rest the filter of the same input from 0.
    So column j = ``rest[:, j] + start_j · decay[:, j]``: ``rest`` (n, m) the candidates filtered from 0 at t0 (τ = 0:
    the input itself), ``decay`` (n, m) exp(−(t − t0)/τ_j) (0 for τ = 0), ``y`` (n,) the block's targets, and
    ``start(cols)`` the start estimates of the candidate columns ``cols`` for the structure made of them (0 where a
    column has no state). Built by host/learning/empirical/forward.py (``observer_block_columns``).
    """

    def __init__(self, rest: np.ndarray, decay: np.ndarray, y: np.ndarray, start: Any) -> None:
        self.rest = np.asarray(rest, dtype=float)
        self.decay = np.asarray(decay, dtype=float)
        self.y = np.asarray(y, dtype=float)
        self.start = start

    def columns(self, cols: Sequence[int]) -> np.ndarray:
        """The columns ``cols`` of the structure made of them, as the board computes them."""
        cols = list(cols)
        return self.rest[:, cols] + self.decay[:, cols] * np.asarray(self.start(cols), dtype=float)


class WorseOfStarts:
    """One forward block scored by the worse of several starts of the same board (dynamic option
    ``controller_scoring=worse``): :class:`StartedColumns` that share the block's inputs and targets and differ only in
    their start estimates, e.g. the spindle lag states from the controller's record and from the observer's estimate
    (a controller that does not send them). The block's squared error for a structure is the largest over the starts.
    Built by host/learning/empirical/forward.py (``observer_block_columns``)."""

    def __init__(self, starts: Sequence[StartedColumns]) -> None:
        self.starts = list(starts)
        if not self.starts:
            raise EmpiricalDataError("dynamic: a block scored by the worse of its starts needs at least one start")


def _block_sse(moments, beta, idx, cols):
    """Held-out squared error of coefficients ``beta`` (scaled, on ``idx``) from a block's moments."""
    Gv, cv_, yy, _ = moments(idx, cols)
    return max(yy - 2 * beta @ cv_ + beta @ Gv @ beta, 0.0)


class _FixedMoments:
    """A scored block's moments when its columns do not depend on the structure: Gram, moment, y'y, n."""

    def __init__(self, G: np.ndarray, c: np.ndarray, yy: float, n: int) -> None:
        self.G, self.c, self.yy, self.n = G, c, yy, n

    def __call__(self, idx, cols):
        return self.G[np.ix_(idx, idx)], self.c[idx], self.yy, self.n

    def sse(self, beta, idx, cols):
        return _block_sse(self, beta, idx, cols)


class _StartedMoments:
    """A scored block's moments for a structure whose columns start at structure-dependent estimates (StartedColumns):
    from the moments of the rest and decay parts, Gram_ij = r_i·r_j + w_j r_i·d_j + w_i d_i·r_j + w_i w_j d_i·d_j."""

    def __init__(self, block: StartedColumns, scale: np.ndarray, o: int) -> None:
        n = block.y.size
        R = np.column_stack([np.ones(n), block.rest]) if o else block.rest
        D = np.column_stack([np.zeros(n), block.decay]) if o else block.decay
        R, D = R / scale, D / scale
        self.RR, self.RD, self.DD = R.T @ R, R.T @ D, D.T @ D
        self.ry, self.dy = R.T @ block.y, D.T @ block.y
        self.yy, self.n, self.o, self.block = float(block.y @ block.y), int(n), o, block

    def __call__(self, idx, cols):
        w = np.concatenate([np.zeros(self.o), np.asarray(self.block.start(list(cols)), dtype=float)])
        ix = np.ix_(idx, idx)
        RDw = self.RD[ix] * w[None, :]
        G = self.RR[ix] + RDw + RDw.T + self.DD[ix] * np.outer(w, w)
        return G, self.ry[idx] + w * self.dy[idx], self.yy, self.n

    def sse(self, beta, idx, cols):
        return _block_sse(self, beta, idx, cols)


class _WorseMoments:
    """A block scored by the worse of its starts (:class:`WorseOfStarts`): the largest squared error over them."""

    def __init__(self, starts: Sequence[_StartedMoments]) -> None:
        self.starts = list(starts)
        self.n = self.starts[0].n

    def sse(self, beta, idx, cols):
        return max(m.sse(beta, idx, cols) for m in self.starts)

    def __call__(self, idx, cols):
        # what needs one set of moments (structure averaging's weights: a quadratic in them) cannot use the worse of two
        raise EmpiricalDataError("dynamic: a block scored by the worse of its starts has no single Gram matrix")


def _fixed_moments(G, c, yy, n):
    return _FixedMoments(G, c, yy, n)


def _started_moments(spec: StartedColumns, scale, o, label) -> _StartedMoments:
    if not (np.isfinite(spec.rest).all() and np.isfinite(spec.decay).all() and np.isfinite(spec.y).all()):
        raise EmpiricalDataError("dynamic: NaN/inf in the switched-on columns of block %s" % label)
    return _StartedMoments(spec, scale, o)


def _held_moments(spec, scale, o, label):
    """Moments of a scored block given as switched-on columns: (F_k, y_k), StartedColumns, or WorseOfStarts."""
    if isinstance(spec, WorseOfStarts):
        return _WorseMoments([_started_moments(s, scale, o, label) for s in spec.starts])
    if isinstance(spec, StartedColumns):
        return _started_moments(spec, scale, o, label)
    Fk, yk = spec
    Ak = np.column_stack([np.ones(len(yk)), Fk]) if o else np.asarray(Fk, dtype=float)
    Ak = Ak / scale
    if not np.isfinite(Ak).all():
        raise EmpiricalDataError("dynamic: NaN/inf in the switched-on columns of block %s" % label)
    return _FixedMoments(Ak.T @ Ak, Ak.T @ yk, float(yk @ yk), int(len(yk)))


class DynamicRegression:
    """Greedy forward choice of lag-filtered terms by group cross-validation; scikit-learn style.

    ``fit(F, y, terms, groups)``: F holds every candidate column, ``terms`` their
    (signal, tau_s). Parameters (keyword-only): ``max_sensors`` (distinct
    temperature sensors, default 5), ``max_terms`` (default 8), ``min_gain``
    (relative CV reduction a term must bring, default 0.01), ``cv_score``
    ("worst" or "pooled"; None: pooled for forward, worst for loo), ``swaps``
    (sequential replacement), ``ridge`` (a value or a grid chosen by CV),
    ``selection`` ("forward": ``groups`` are time blocks in ascending order, each
    block k >= 1 scored by the fit on blocks < k; "loo": leave each group out),
    ``fit_intercept``. :meth:`with_block_columns` gives forward blocks their
    switched-on columns. Also learned: ``fold_rmse_`` and ``fold_labels_`` (the
    chosen structure's score per scored block or group).
    Learned: ``selected_`` (column indices), ``terms_``, ``coef_``,
    ``intercept_``, ``ridge_``, ``cv_rmse_``, ``cv_by_ridge_``, ``history_``,
    ``rmse_``, ``rsquared_``, ``n_samples_``, ``n_groups_``.
    """

    method = "dynamic"
    # learned by fit (the winning ridge value's _fit_one result, set by name, and what fit computes after it)
    intercept_: float
    coef_: np.ndarray
    selected_: list[int]
    fold_rmse_: list[float]
    scale_: np.ndarray
    fold_labels_: list[Any]
    terms_: list[tuple[str, float]]
    cv_rmse: float
    cv_rmse_: float
    history_: list[dict[str, Any]]
    n_samples_: int
    n_groups_: int
    ridge_: float
    settle_bound_: dict[str, Any] | None
    cv_score_: str
    cv_by_ridge_: dict[float, float | None]  # None: no term lowered the score with that penalty
    fits_by_ridge_: dict[float, dict[str, Any]]
    rmse_: float
    rsquared_: float

    def __init__(self, *, max_sensors: int = 5, max_terms: int = 8, min_gain: float = 0.01, cv_score: str | None = None,
                 swaps: bool = True, ridge: float | Sequence[float] = RIDGE, selection: str = "forward",
                 fit_intercept: bool = True) -> None:
        self.ridge = ridge
        self.cv_score = cv_score
        self.selection = selection
        self.block_columns: dict[Any, tuple[np.ndarray, np.ndarray] | StartedColumns | WorseOfStarts] | None = None
        self.settle_bound: SettleBound | None = None  # with_settle_bound: only structures that settle in time
        self.start_terms: list[tuple[str, float]] | None = None  # with_start: the structure the greedy search starts from
        self.swaps = swaps
        self.max_sensors = max_sensors
        self.max_terms = max_terms
        self.min_gain = min_gain
        self.fit_intercept = fit_intercept

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[tuple[str, float]] | None = None,
            groups: np.ndarray | None = None) -> DynamicRegression:
        """Structure and coefficients for every ridge value in ``ridge``; the lowest CV score wins.
        ``X``: the lag-filtered candidates (fitting.candidate_matrix), ``names``: their (signal, tau) terms,
        ``groups``: the cross-validation groups (both required)."""
        if names is None or groups is None:
            raise EmpiricalDataError("dynamic: fit needs the candidates' (signal, tau) terms and the cross-validation groups")
        F, terms = X, names
        if self.selection not in SELECTIONS:
            raise EmpiricalDataError("dynamic: selection must be one of %s, got %r" % (", ".join(SELECTIONS), self.selection))
        self.cv_score_ = DEFAULT_SCORE[self.selection] if self.cv_score is None else self.cv_score
        if self.cv_score_ not in ("worst", "pooled"):
            raise EmpiricalDataError("dynamic: cv_score must be 'worst' or 'pooled', got %r" % (self.cv_score,))
        # np.isscalar does not narrow for pyright; an entry that is not a number is rejected just below
        grid = cast("list[float]", [self.ridge] if np.isscalar(self.ridge) else list(self.ridge))  # pyright: ignore[reportArgumentType]
        if not grid or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0 for v in grid):
            raise EmpiricalDataError("dynamic: ridge must be a number >= 0 or a list of them, got %r" % (self.ridge,))
        best, tried = None, {}
        self.fits_by_ridge_ = {}  # every ridge value's best structure: the members structure averaging draws on (averaging.py)
        for lam in grid:
            fitted = self._fit_one(F, y, terms, groups, float(lam))
            if fitted is None:  # no term lowers the score with this penalty: not a candidate; another value may find one
                tried[float(lam)] = None
                continue
            tried[float(lam)] = fitted["cv_rmse"]
            self.fits_by_ridge_[float(lam)] = fitted
            if best is None or fitted["cv_rmse"] < best["cv_rmse"]:
                best = fitted
        if best is None:
            raise EmpiricalDataError("dynamic: no lag-filtered term lowers the cross-validation error by %.0f %% with any ridge value "
                                     "(%s)" % (100 * self.min_gain, ", ".join("%g" % v for v in grid)))
        for k, v in best.items():
            setattr(self, k, v)
        self.cv_by_ridge_ = tried
        self._y = np.asarray(y, dtype=float)
        self._F_selected = np.asarray(F, dtype=float)[:, self.selected_]
        r = y - self.predict(self._F_selected)
        self.rmse_ = float(np.sqrt(np.mean(r**2)))
        sst = float(((y - np.mean(y)) ** 2).sum())
        self.rsquared_ = 1.0 - float(r @ r) / sst if sst > 0 else float("nan")
        return self

    def _fit_one(self, F, y, terms, groups, ridge):
        for key in ("max_sensors", "max_terms"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise EmpiricalDataError("dynamic: %s must be an integer >= 1, got %r" % (key, v))
        if not 0.0 <= float(self.min_gain) < 1.0:
            raise EmpiricalDataError("dynamic: min_gain must be in [0, 1), got %r" % (self.min_gain,))
        F = np.asarray(F, dtype=float)
        y = np.asarray(y, dtype=float)
        groups = np.asarray(groups)
        labels = np.unique(groups)  # forward: block labels ascend with time (host/learning/empirical/forward.py)
        forward = self.selection == "forward"
        if not forward and labels.size < 2:
            raise EmpiricalDataError("dynamic: cross-validation needs at least 2 groups (runs or spindle cycles), got %d" % labels.size)
        if forward and labels.size < MIN_BLOCKS:
            raise EmpiricalDataError("dynamic: forward-chaining validation needs at least %d time blocks (runs or spindle cycles; "
                                     "%d scored), got %d; give forward_blocks=N or selection=loo" % (MIN_BLOCKS, MIN_BLOCKS - 1, labels.size))
        held_cols = self.block_columns or {}
        if forward and set(held_cols) - set(labels.tolist()):
            raise EmpiricalDataError("dynamic: block_columns name blocks %s that are not among the groups" % sorted(set(held_cols) - set(labels.tolist())))
        if not np.isfinite(F).all() or not np.isfinite(y).all():
            raise EmpiricalDataError("dynamic: NaN/inf in the signals or the target")
        o = int(bool(self.fit_intercept))
        A = np.column_stack([np.ones(len(y)), F]) if o else F
        # scale columns so the Gram matrices are well conditioned (krpm² and K live on different scales)
        scale = np.sqrt((A**2).mean(axis=0))
        scale[scale == 0] = 1.0
        A = A / scale
        G = [(A[groups == g].T @ A[groups == g], A[groups == g].T @ y[groups == g], float(y[groups == g] @ y[groups == g]), int((groups == g).sum()))
             for g in labels]
        # sums of arrays (one per group) are arrays; pyright types sum() from its int start
        Gall = cast(np.ndarray, sum(g[0] for g in G))
        call = cast(np.ndarray, sum(g[1] for g in G))
        n_all = len(y)
        # folds: (training Gram, training moment, training samples, held-out (Gram, moment, y'y, samples))
        folds = []
        if forward:
            for k in range(1, labels.size):
                if labels[k] in held_cols:  # the block as a board switched on at its start computes it
                    held = _held_moments(held_cols[labels[k]], scale, o, labels[k])
                else:
                    held = _fixed_moments(*G[k])
                folds.append((sum(g[0] for g in G[:k]), sum(g[1] for g in G[:k]), sum(g[3] for g in G[:k]), held))
        else:
            folds = [(Gall - Gv, call - cv_, n_all - nv, _fixed_moments(Gv, cv_, yy, nv)) for Gv, cv_, yy, nv in G]

        def penalty(idx, n):
            # ridge on the scaled terms, never on the intercept
            P = ridge * n * np.eye(len(idx))
            if o:
                P[0, 0] = 0.0
            return P

        def fold_sse(cols):
            """Held-out squared error of every fold, or None when a training Gram matrix is singular."""
            idx = ([0] if o else []) + [c + o for c in cols]
            sse = []
            for Gt, ct, nt, held in folds:
                M = Gt[np.ix_(idx, idx)] + penalty(idx, nt)
                if np.linalg.cond(M) > 1e12:
                    return None
                beta = np.linalg.solve(M, ct[idx])
                sse.append(held.sse(beta, idx, cols))  # the scored block's error on these columns (idx: with the intercept)
            return sse

        def cv(cols):
            sse = fold_sse(cols)
            if sse is None:
                return np.inf
            if self.cv_score_ == "worst":
                return float(max(np.sqrt(s / f[3].n) for s, f in zip(sse, folds)))
            return float(np.sqrt(sum(sse) / sum(f[3].n for f in folds)))

        def sensor_of(j):
            return terms[j][0][2:] if terms[j][0].startswith("T:") else None

        def allowed(sel, j):
            used = {sensor_of(i) for i in sel} - {None}
            s = sensor_of(j)
            return j not in sel and (s is None or s in used or len(used) < int(self.max_sensors))

        def best_swap(sel, score):
            """Sequential replacement: the single exchange of a chosen term that lowers the CV error most."""
            best = (score, None)
            for pos in range(len(sel)):
                rest = sel[:pos] + sel[pos + 1:]
                for j in range(F.shape[1]):
                    if allowed(rest, j) and j != sel[pos]:
                        s = cv(rest[:pos] + [j] + rest[pos:])
                        if s < best[0] * (1.0 - 1e-9):
                            best = (s, rest[:pos] + [j] + rest[pos:])
            return best

        screen = None
        if self.settle_bound is not None:
            # only structures whose observer settles within settle_max_s (host/learning/empirical/settle.py), judged
            # with the coefficients they would carry: the fit on every training sample with this penalty
            def all_data_coefficients(cols):
                idx = ([0] if o else []) + [c + o for c in cols]
                return (np.linalg.solve(Gall[np.ix_(idx, idx)] + penalty(idx, n_all), call[idx]) / scale[idx])[o:]

            screen = cv = self.settle_bound.screen(cv, all_data_coefficients, terms)
        selected, history = [], []
        current = cv([]) if o else np.inf
        history.append({"step": 0, "action": "start", "term": None, "cv_rmse": current})

        def replace_while_better():
            nonlocal selected, current
            while self.swaps:
                score, sel = best_swap(selected, current)
                if sel is None:
                    break
                out_ = [j for j in selected if j not in sel][0]
                in_ = [j for j in sel if j not in selected][0]
                selected, current = sel, score
                history.append({"step": len(history), "action": "swap", "term": [terms[in_][0], terms[in_][1]],
                                "replaces": [terms[out_][0], terms[out_][1]], "cv_rmse": current})

        if self.start_terms:
            # a given structure (with_start), kept when it scores better than the empty one; the search goes on from it
            where = {(str(n), float(tau)): j for j, (n, tau) in enumerate(terms)}
            missing = [t for t in self.start_terms if (str(t[0]), float(t[1])) not in where]
            if missing:
                raise EmpiricalDataError("dynamic: the start structure's term(s) %s are not among the candidates" % missing)
            given = [where[(str(n), float(tau))] for n, tau in self.start_terms]
            score = cv(given)
            history.append({"step": 1, "action": "start_from", "terms": [[terms[j][0], terms[j][1]] for j in given],
                            "cv_rmse": score, "kept": bool(score < current)})
            if score < current:
                selected, current = given, score
                replace_while_better()
        while len(selected) < int(self.max_terms):
            best = (np.inf, None)
            for j in range(F.shape[1]):
                if allowed(selected, j):
                    score = cv(selected + [j])
                    if score < best[0]:
                        best = (score, j)
            if best[1] is None or not best[0] < current * (1.0 - float(self.min_gain)):
                break
            selected.append(best[1])
            current = best[0]
            history.append({"step": len(history), "action": "add", "term": [terms[best[1]][0], terms[best[1]][1]], "cv_rmse": current})
            replace_while_better()
        if not selected:
            return None  # fit() tries the other ridge values and raises if none finds a term
        idx = ([0] if o else []) + [c + o for c in selected]
        beta = np.linalg.solve(Gall[np.ix_(idx, idx)] + penalty(idx, n_all), call[idx]) / scale[idx]
        sse = fold_sse(selected) or [np.nan] * len(folds)
        fold_rmse = [float(np.sqrt(s / f[3].n)) for s, f in zip(sse, folds)]
        return {"intercept_": float(beta[0]) if o else 0.0, "coef_": beta[o:], "selected_": selected, "fold_rmse_": fold_rmse,
                "scale_": scale[idx], "fold_labels_": labels[1:].tolist() if forward else labels.tolist(),
                "terms_": [(terms[j][0], float(terms[j][1])) for j in selected], "cv_rmse": current, "cv_rmse_": current,
                "history_": history, "n_samples_": n_all, "n_groups_": int(labels.size), "ridge_": ridge,
                "settle_bound_": None if screen is None else screen.record()}

    def with_block_columns(self, columns: Mapping[Any, tuple[np.ndarray, np.ndarray] | StartedColumns | WorseOfStarts]) -> DynamicRegression:
        """Score forward block ``label`` on ``columns[label]``: the candidate columns as a board switched on at the
        block's start computes them (host/learning/empirical/forward.py), instead of the rows of ``X`` (filters running
        since the run start): ``(F_k, y_k)`` when they do not depend on the structure (filters from rest), a
        :class:`StartedColumns` when the states start at the structure's observer estimate, a :class:`WorseOfStarts`
        when the block is scored by the worse of several starts. Returns self."""
        self.block_columns = dict(columns)
        return self

    def with_start(self, terms: Sequence[tuple[str, float]] | None) -> DynamicRegression:
        """Start the greedy search of every ridge value from ``terms`` (signal, tau) instead of the empty structure, when
        they score better than it; the search then adds and exchanges terms from there as usual (None: from empty).
        ``controller_scoring=worse``'s second search uses it (fitting.py). Returns self."""
        self.start_terms = None if terms is None else [(str(n), float(tau)) for n, tau in terms]
        return self

    def with_settle_bound(self, bound: SettleBound | None) -> DynamicRegression:
        """Admit only structures whose observer settles within ``bound.settle_max_s`` (host/learning/empirical/settle.py;
        None: every structure). The record of what it refused, for the winning penalty, is ``settle_bound_``. Returns self."""
        self.settle_bound = bound
        return self

    def coefficients_on(self, rows: ArrayLike) -> tuple[float, np.ndarray]:
        """(intercept, coefficients) of the chosen terms refitted on the samples ``rows`` (a mask over the fitted samples)
        with the chosen penalty and the same column scaling: the fit of one forward-chaining fold."""
        rows = np.asarray(rows, dtype=bool)
        o = int(bool(self.fit_intercept))
        A = self._F_selected[rows]
        A = (np.column_stack([np.ones(A.shape[0]), A]) if o else A) / self.scale_
        P = self.ridge_ * int(rows.sum()) * np.eye(A.shape[1])
        if o:
            P[0, 0] = 0.0
        beta = np.linalg.solve(A.T @ A + P, A.T @ self._y[rows]) / self.scale_
        return (float(beta[0]) if o else 0.0), beta[o:]

    def predict(self, F: np.ndarray) -> np.ndarray:
        """``F``: the selected terms' signals, one column per ``terms_`` entry."""
        F = check_predict_x(self, F, "coef_", lambda: self.coef_.size)
        return self.intercept_ + F @ self.coef_

    def statistics(self) -> dict[str, Any]:
        return {
            "n_samples": int(self.n_samples_), "r2": finite_or_none(self.rsquared_), "rmse": finite_or_none(self.rmse_), "cv_rmse": finite_or_none(self.cv_rmse_),
            "cv_groups": self.n_groups_, "cv_score": self.cv_score_, "selection": self.selection, "history": self.history_, "ridge": self.ridge_,
            "selection_folds": [{"block" if self.selection == "forward" else "group": int(g) if isinstance(g, (int, np.integer)) else g,
                                 "rmse": finite_or_none(r)} for g, r in zip(self.fold_labels_, self.fold_rmse_)],
            "cv_by_ridge": {str(k): None if v is None else finite_or_none(v) for k, v in self.cv_by_ridge_.items()},
            "terms": [{"signal": n, "tau_s": tau, "coefficient": finite_or_none(c)} for (n, tau), c in zip(self.terms_, self.coef_)],
            "sensors_used": sorted({n[2:] for n, _ in self.terms_ if n.startswith("T:")}),
            "r2_adj": None, "F": None, "F_p": None, "residual_std_error": finite_or_none(self.rmse_),
        }


class DynamicModel(DocumentFields):
    """Model document kind ``dynamic`` (docs/model-format.md): δ = b0 + Σ b_j·L_τj[u_j], direct or slope.

    Without an observer (documents written before issue 21, or fitted with
    ``observer=false``) inputs are referenced to the evaluated run's start
    (``thermal.reference`` is "run_start"): the filters start at rest when the
    board latches its reference temperatures, so a run must be logged from that
    moment. With one (``thermal.observer``, host/learning/empirical/observer.py)
    the reference is "fixed" (T − reference_C) and the lag states start at the
    observer's estimate from the first sample's temperatures: a board switched on
    at the run's first sample, on a warm machine or not.
    """

    # set by host.learning.empirical.fitting (the fitted estimator and its data), absent on loaded documents
    estimator_: Any
    arrays_: Any
    geometric_: Any
    single_: DynamicModel  # with average_structures > 1: the single best structure the average replaced (in memory only)

    kind = "dynamic"
    coefficients = None  # not a linear function of the temperatures
    intercept = 0.0

    def __init__(self, terms: Iterable[tuple[str, float]], coefficients: ArrayLike, intercept: float, target: str = "direct",
                 channel: str | None = None, geometric_coef: ArrayLike = (0.0,), method: str = "dynamic", axis: str | None = None,
                 reference_C: Mapping[str, float] | None = None, envelope: dict[str, Any] | None = None,
                 statistics: dict[str, Any] | None = None, training: dict[str, Any] | None = None, dt_s: float | None = None,
                 observer: Observer | None = None) -> None:
        self.observer = observer  # observer.Observer or None (filters from rest at the run start)
        self.dt_s = dt_s  # the filters' step on the board (the training runs' sample interval); None: not recorded
        self.terms = [(str(n), float(tau)) for n, tau in terms]
        self.term_coefficients = np.asarray(coefficients, dtype=float)
        self.intercept = float(intercept)
        self.target = target
        self.channel = channel
        self.geometric_coef = np.asarray(geometric_coef, dtype=float)
        self.method = method
        self.axis = axis
        self.term_sensors = sorted({n[2:] for n, _ in self.terms if n.startswith("T:")}, key=lambda s: [n for n, _ in self.terms].index("T:" + s))
        # sensors only the observer reads (option observer_sensors, host/learning/empirical/observer.py choose_observer_sensors)
        self.observer_sensors: list[str] = []
        self.reference_C = dict(reference_C or {})
        self.envelope = envelope or {}
        self.statistics = statistics or {}
        self.training = training or {}

    @property
    def sensors(self) -> list[str]:
        """Every sensor the board reads: the terms' (first-use order), then those only the observer reads."""
        return self.term_sensors + [s for s in self.observer_sensors if s not in self.term_sensors]

    @property
    def reference(self) -> str:
        return "run_start" if self.observer is None else "fixed"

    def thermal_at(self, run: Run, times: ArrayLike, history: Sequence[Run] | None = None,
                   controller_history: Sequence[Run] | None = None) -> np.ndarray:
        """Thermal output at ``times`` of ``run``; ``history``: earlier runs (oldest first) the states run through first;
        ``controller_history``: earlier runs whose spindle/feed logs are the controller's record (observer.controller_states);
        None: no controller's values (the supplied states start at the observer's estimate)."""
        if self.observer is None and not history:
            return self.intercept + features(run, self.terms, times) @ self.term_coefficients
        from host.learning.empirical.observer import board_terms

        if self.observer is None:
            raise EmpiricalDataError("dynamic: this model has no observer (thermal.reference 'run_start': its inputs are rises over "
                                     "the run's own start), so a history cannot carry its states into the run; refit it to get one")
        if history and controller_history is None:
            controller_history = []  # the board and the controller ran through the history together, from its first sample
        t, cols = board_terms(self, list(history or []) + [run], controller_history=controller_history)
        times = np.atleast_1d(np.asarray(times, dtype=float))
        t_run = run.temperatures.time_s
        if times.size and (times.min() < t_run[0] or times.max() > t_run[-1]):
            bad = times[(times < t_run[0]) | (times > t_run[-1])][0]
            raise EmpiricalDataError("%s: time %g s is outside the temperature log %g..%g s (no extrapolation)" % (run.name, bad, t_run[0], t_run[-1]))
        return self.intercept + np.column_stack([np.interp(times, t, cols[:, j]) for j in range(cols.shape[1])]) @ self.term_coefficients

    def geometric(self, P: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(P, dtype=float), self.geometric_coef)

    def _rows(self, run):
        from host.learning.empirical.targets import _channel_rows

        if self.channel is not None and run.errors.channel is None:
            return np.arange(len(run.errors))
        return _channel_rows(run, self.channel)

    def predict(self, run: Run, history: Run | Sequence[Run] | None = None,
                controller_history: Run | Sequence[Run] | None = None) -> np.ndarray:
        """Predicted errors of ``run`` as a board switched on at its first sample computes them (with its
        observer, if the model has one); ``history``: a run or list of runs (oldest first, ending before
        ``run`` starts, one clock) the board ran through first, without a restart; ``controller_history``: a run or
        list of runs whose spindle/feed logs are the controller's record before ``run``, for the lag states the
        controller supplies at the start (option spindle_states=controller; host/learning/empirical/observer.py)."""
        if history is not None and not isinstance(history, (list, tuple)):
            history = [cast("Run", history)]  # not a list or tuple: one run, as the hint says
        if controller_history is not None and not isinstance(controller_history, (list, tuple)):
            controller_history = [cast("Run", controller_history)]
        try:
            check_model_reference(run, self.error_reference)
        except ValueError as exc:
            raise EmpiricalDataError(str(exc))
        e = run.errors
        out = np.full(len(e), np.nan)
        rows = self._rows(run)
        th = self.thermal_at(run, e.time_s[rows], history, controller_history)
        out[rows] = self.geometric(e.position_mm[rows]) + th * e.position_mm[rows] if self.target == "slope" else th
        return out

    def to_document(self) -> dict[str, Any]:
        return {
            **self._identity_doc(),
            "geometric": self._geometric_doc(),
            "thermal": {"target": self.target, "unit": "um_per_mm" if self.target == "slope" else "um", "reference": self.reference,
                        "intercept": self.intercept, **({"dt_s": self.dt_s} if self.dt_s is not None else {}),
                        **({"observer": self.observer.to_document()} if self.observer is not None else {}),
                        "terms": [{"signal": n, "tau_s": tau, "coefficient": float(c)} for (n, tau), c in zip(self.terms, self.term_coefficients)]},
            **self._record_doc(),
        }

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> DynamicModel:
        import math

        from host.learning.documents import ModelFormatError

        def num(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        th = doc.get("thermal")
        if not isinstance(th, dict):
            raise ModelFormatError("dynamic model document lacks the object 'thermal'")
        document_target(th, "dynamic")
        if th.get("reference", "run_start") != ("run_start" if th.get("observer") is None else "fixed"):
            raise ModelFormatError("dynamic model document: thermal.reference must be 'run_start' (the filters start at rest) without "
                                   "thermal.observer, 'fixed' (T - reference_C) with it; found %r" % (th.get("reference"),))
        if not num(th.get("intercept")):
            raise ModelFormatError("dynamic model document: thermal.intercept must be a finite number, found %r" % (th.get("intercept"),))
        terms = th.get("terms")
        if not isinstance(terms, list) or not terms:
            raise ModelFormatError("dynamic model document: thermal.terms must be a non-empty list")
        known = SPINDLE + (FEED,)
        out, coefs = [], []
        for i, t in enumerate(terms):
            if not isinstance(t, dict):
                raise ModelFormatError("dynamic model document: thermal.terms[%d] must be an object" % i)
            sig = t.get("signal")
            if not isinstance(sig, str) or not (sig.startswith("T:") and len(sig) > 2 or sig in known):
                raise ModelFormatError("dynamic model document: thermal.terms[%d].signal must be 'T:<sensor>' or one of %s, found %r"
                                       % (i, ", ".join(known), sig))
            if not num(t.get("tau_s")) or t["tau_s"] < 0:
                raise ModelFormatError("dynamic model document: thermal.terms[%d].tau_s must be a number >= 0, found %r" % (i, t.get("tau_s")))
            if not num(t.get("coefficient")):
                raise ModelFormatError("dynamic model document: thermal.terms[%d].coefficient must be a finite number, found %r" % (i, t.get("coefficient")))
            out.append((sig, t["tau_s"]))
            coefs.append(t["coefficient"])
        geo = (0.0,)
        if th["target"] == "slope":
            geo = _geometric_from_document(doc, "dynamic")
        if doc.get("channel") is not None and not isinstance(doc.get("channel"), str):
            raise ModelFormatError("dynamic model document: field 'channel' must be a channel name (string) or null")
        for key in ("reference_C", "envelope", "statistics", "training"):
            if doc.get(key) is not None and not isinstance(doc.get(key), dict):
                raise ModelFormatError("dynamic model document: field '%s' must be an object or null, found %s" % (key, type(doc.get(key)).__name__))
        if th.get("dt_s") is not None and not (num(th["dt_s"]) and th["dt_s"] > 0):
            raise ModelFormatError("dynamic model document: thermal.dt_s must be a number > 0 (seconds), found %r" % (th.get("dt_s"),))
        observer = None
        if th.get("observer") is not None:
            from host.learning.empirical.observer import Observer

            sensors = list(dict.fromkeys(n[2:] for n, _ in out if n.startswith("T:")))
            # a sensor of the document's "sensors" that no term reads is one only the observer reads (its gains' "T:<sensor>")
            listed = doc.get("sensors")
            if listed is not None and (not isinstance(listed, list) or not all(isinstance(v, str) and v for v in listed)):
                raise ModelFormatError("dynamic model document: field 'sensors' must be a list of sensor names, found %r" % (listed,))
            # (a listed sensor that no term and no gain reads is ignored, as documents before observer_sensors had them)
            read = {k for st in (th["observer"].get("states") or []) if isinstance(st, dict) and isinstance(st.get("gains"), dict)
                    for k in st["gains"]} if isinstance(th["observer"], dict) else set()
            observer_only = [v for v in dict.fromkeys(listed or []) if v not in sensors and "T:" + v in read]
            missing = [s for s in sensors + observer_only if not num((doc.get("reference_C") or {}).get(s))]
            if missing:
                raise ModelFormatError("dynamic model document: thermal.observer needs reference_C of sensor %s (a number, °C)" % missing[0])
            observer = Observer.from_document(th["observer"], out, observer_only)
        model = cls(out, coefs, th["intercept"], th["target"], doc.get("channel"), geo, doc.get("method", "dynamic"), doc.get("axis"),
                    doc.get("reference_C"), doc.get("envelope"), doc.get("statistics"), doc.get("training"), th.get("dt_s"), observer)
        if observer is not None:
            model.observer_sensors = list(observer_only)
        return model
