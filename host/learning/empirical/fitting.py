"""Fit a model document from runs: targets -> regression -> PolySlopeModel / LinearDirectModel.

Envelope rule (recorded in the document's ``envelope.rule``): for each model
sensor, the absolute temperatures and the rises seen over the training span
(first to last target time of each training run), widened by
``envelope_margin_K`` (default 2 K) on both sides; positions 0..stroke_mm when
the run declares its stroke, else the measured position range; a direct model
has its fixed measuring position.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.geometric import fit_geometric
from host.learning.empirical.kinds import LinearDirectModel, NetworkModel, PolySlopeModel, PPRModel
from host.learning.empirical.methods import CROSS_VALIDATED, make_estimator
from host.learning.empirical.schedule import block_labels, cycles
from host.data.runs import common_error_reference
from host.learning.empirical.targets import _channel_rows, stack, start_temperatures, training_arrays

if TYPE_CHECKING:
    from host.data.runs import Run
    from host.learning.empirical.targets import RunArrays

ENVELOPE_MARGIN_K = 2.0
NONLINEAR = {"ann": NetworkModel, "ppr": PPRModel}  # estimators that are not a linear function of the rises: their model class


def _envelope(runs, arrays, sensors, margin, target, channel):
    tlo, thi, rlo, rhi = {}, {}, {}, {}
    for r, a in zip(runs, arrays):
        temps = r.temperatures
        keep = (temps.time_s >= a.time_s.min()) & (temps.time_s <= a.time_s.max())
        if not keep.any():
            keep = np.ones(temps.time_s.size, bool)
        for s in sensors:
            col = temps.column(s)
            v = col[keep]
            rise = v - col[0]
            tlo[s] = min(tlo.get(s, np.inf), float(v.min()))
            thi[s] = max(thi.get(s, -np.inf), float(v.max()))
            rlo[s] = min(rlo.get(s, np.inf), float(rise.min()))
            rhi[s] = max(rhi.get(s, -np.inf), float(rise.max()))
    pos = []
    for r in runs:
        rows = _channel_rows(r, channel)
        pos.append(r.errors.position_mm[rows])
    pos = np.concatenate(pos)
    strokes = [r.stroke_mm for r in runs if r.stroke_mm]
    if target == "slope" and strokes:
        prange = [0.0, float(min(strokes))]
    else:
        prange = [float(pos.min()), float(pos.max())]
    return {
        "temperature_C": {s: [tlo[s] - margin, thi[s] + margin] for s in sensors},
        "temperature_rise_K": {s: [rlo[s] - margin, rhi[s] + margin] for s in sensors},
        "position_mm": prange,
        "margin_K": float(margin),
        "rule": "training temperatures and rises over the training span widened by margin_K; "
                + ("positions 0..stroke_mm" if target == "slope" and strokes else "measured position range"),
    }


def select_columns(arrays: Sequence[RunArrays], sensors: Sequence[str]) -> list[RunArrays]:
    """RunArrays restricted to ``sensors`` (a new list, same runs)."""
    from host.learning.empirical.targets import RunArrays

    out = []
    for a in arrays:
        missing = [s for s in sensors if s not in a.names]
        if missing:
            raise EmpiricalDataError("%s: sensor(s) %s not available (have %s)" % (a.run, ", ".join(missing), ", ".join(a.names)))
        idx = [a.names.index(s) for s in sensors]
        out.append(RunArrays(a.X[:, idx], a.y, list(sensors), a.time_s, a.run, None if a.start is None else a.start[idx],
                             a.log_columns(idx)))
    return out


def merge_small_groups(groups: np.ndarray, fraction: float = 0.25) -> np.ndarray:
    """Merge groups smaller than ``fraction`` of the largest into the group before them in time.

    A training window that ends just after a cycle starts would otherwise make
    a group of a few samples whose CV error counts as much as a whole cycle's.
    """
    groups = np.asarray(groups).copy()
    labels, counts = np.unique(groups, return_counts=True)
    small = set(labels[counts < fraction * counts.max()].tolist())
    order = list(dict.fromkeys(groups.tolist()))  # labels in time order
    for i, lab in enumerate(order):
        if lab in small:
            into = order[i - 1] if i > 0 else next((o for o in order if o not in small), lab)
            groups[groups == lab] = into
    return groups


def cv_groups(runs: Sequence[Run], arrays: Sequence[RunArrays], cv_blocks: int | None = None) -> np.ndarray:
    """Cross-validation group of every stacked sample.

    Several runs: the run. One run: ``cv_blocks`` equal-length contiguous time
    blocks if given, else the run's spindle cycles (host/learning/empirical/schedule.py).
    """
    if len(arrays) >= 2:
        if cv_blocks is not None:
            raise EmpiricalDataError("cv_blocks applies to a single training run; with %d runs the runs are the groups" % len(arrays))
        return np.concatenate([np.full(a.y.size, i) for i, a in enumerate(arrays)])
    t = np.concatenate([a.time_s for a in arrays])
    if cv_blocks is not None:
        k = int(cv_blocks)
        if k < 2:
            raise EmpiricalDataError("cv_blocks must be >= 2, got %d" % k)
        edges = np.linspace(t.min(), t.max(), k + 1)[1:-1]
        return block_labels(t, edges)
    if runs[0].spindle is None:
        # no schedule to cut along: three contiguous time blocks (early, middle, late part of the run)
        edges = np.linspace(t.min(), t.max(), 4)[1:-1]
        return block_labels(t, edges)
    edges = [c["t_start_s"] for c in cycles(runs[0])[1:]]
    g = merge_small_groups(block_labels(t, edges))
    if np.unique(g).size < 2:
        raise EmpiricalDataError("cv-subset: the training span covers a single spindle cycle; give cv_blocks=N")
    return g


def fit_model(runs: Sequence[Run], method: str = "mlr", target: str = "slope", channel: str | None = None,
              sensors: Sequence[str] | None = None, fit_intercept: bool = True,
              window: tuple[float | None, float | None] | None = None, reference: str = "fixed",
              envelope_margin_K: float = ENVELOPE_MARGIN_K, geometric_max_degree: int = 5, geometric_criterion: str = "cv",
              cv_blocks: int | None = None, exclude: tuple[float | None, float | None] | None = None, geometric_degree: int | None = None,
              forward_chaining: bool = True, **options: Any) -> Any:
    """Fit ``method`` (an ESTIMATORS name, or dynamic) on ``runs`` -> model object with ``estimator_`` and ``arrays_``.

    ``options`` go to the estimator (e.g. variance_threshold=0.9, f_enter=50).
    ``reference``: "fixed" (default: inputs are T − reference_C, the document
    contract the exporter and firmware implement; reference_C is the mean
    cold-start temperature of the training runs) or "run_start" (rises over
    each evaluated run's own first sample, the literature's ΔT; the document
    then says so in thermal.reference). Training always uses each training
    run's own rises, so with one training run both give the same model.
    ``cv_blocks``: cross-validation groups of ``cv-subset`` (see :func:`cv_groups`).
    ``exclude=(lo, hi)``: targets in that span are left out of the fit (leave-one-cycle-out).
    ``geometric_degree=N``: the cold polynomial has exactly degree N (else the degree is chosen up to
    ``geometric_max_degree`` by ``geometric_criterion``).
    ``method="mr-poly"``: S004's Eq. 12 on the nut and base sensors (roles, or ``nut=``/``base=`` options;
    host/learning/empirical/mrpoly.py).
    ``forward_chaining``: add ``statistics.forward_chaining`` (host/learning/empirical/forward.py) to linear and dynamic
    models; its own refits pass False.
    """
    runs = list(runs)
    if not runs:
        raise EmpiricalDataError("fit: no training run given")
    if method == "mr-poly":
        from host.learning.empirical.mrpoly import role_sensors

        options = dict(options)
        pair = role_sensors(runs, options.pop("nut", None), options.pop("base", None))
        if sensors is not None:
            outside = [s for s in pair if s not in sensors]
            if outside:
                raise EmpiricalDataError("mr-poly: the nut/base sensor(s) %s are not among the candidate sensors %s"
                                         % (", ".join(outside), ", ".join(sensors)))
        sensors = pair
    arrays = training_arrays(runs, target=target, channel=channel, sensors=sensors, window=window, exclude=exclude)
    error_reference = common_error_reference(runs)  # training_arrays has refused a mix
    names = arrays[0].names
    X, y = stack(arrays)
    if method == "dynamic":
        model = _fit_dynamic(runs, arrays, y, target, channel, window, fit_intercept, envelope_margin_K,
                            (geometric_max_degree, geometric_criterion, geometric_degree), cv_blocks, options, exclude, forward_chaining)
        model.training["error_reference"] = error_reference
        return model
    est = make_estimator(method, fit_intercept=fit_intercept, **options)
    # cv-subset cross-validates over the groups; the ann validates on the last one
    groups = cv_groups(runs, arrays, cv_blocks) if method in CROSS_VALIDATED else None
    est.fit(X, y, names, groups=groups)
    if method in NONLINEAR or method == "mr-poly":
        used, coefs = list(names), None
    elif hasattr(est, "selected_names_"):
        used = list(est.selected_names_)
        coefs = est.mlr_.coef_
    else:
        used = list(names)
        coefs = est.coef_
    start = np.mean([start_temperatures(r, used) for r in runs], axis=0)
    ref = dict(zip(used, start.tolist()))
    stats = est.statistics()
    training = {
        "runs": [r.path or r.name for r in runs],
        "target": target,
        "window_s": list(window) if window is not None else None,
        "excluded_s": list(exclude) if exclude is not None else None,
        "n_samples": int(y.size),
        "rises": True,
        "error_reference": error_reference,  # the convention of the targets (the model predicts errors in it)
        "fit_intercept": bool(fit_intercept),
        "candidate_sensors": list(names),
        "options": {k: v for k, v in options.items()},
    }
    kw: dict = dict(reference=reference, channel=channel, method=method, axis=runs[0].meta.get("axis"),
              envelope=_envelope(runs, arrays, used, envelope_margin_K, target, channel), statistics=stats, training=training)
    if method == "mr-poly":
        from host.learning.empirical.mrpoly import MRPolyModel

        geo = fit_geometric(runs, channel, geometric_max_degree, geometric_criterion, geometric_degree) if target == "slope" else None
        if geo is not None:
            stats["geometric"] = {"degree": int(geo.degree_), "rmse_um": geo.rmse_, "selection": geo.scores_,
                                  "criterion": geometric_criterion if geometric_degree is None else "fixed"}
        model = MRPolyModel(used, est.nut_coef_, est.base_coef_, est.intercept_, ref, target=target,
                            geometric_coef=geo.coef_ if geo is not None else (0.0,), **kw)
        model.geometric_ = geo
    elif target == "direct":
        model = NONLINEAR[method](used, est, ref, "direct", **kw) if method in NONLINEAR else LinearDirectModel(used, coefs, est.intercept_, ref, **kw)
    else:
        geo = fit_geometric(runs, channel, geometric_max_degree, geometric_criterion, geometric_degree)
        stats["geometric"] = {"degree": int(geo.degree_), "rmse_um": geo.rmse_, "selection": geo.scores_,
                              "criterion": geometric_criterion if geometric_degree is None else "fixed"}
        if method in NONLINEAR:
            model = NONLINEAR[method](used, est, ref, "slope", geometric_coef=geo.coef_, **kw)
        else:
            assert coefs is not None  # a linear method's, set above (None only for NONLINEAR and mr-poly, handled before)
            model = PolySlopeModel(used, coefs, est.intercept_, ref, geometric_coef=geo.coef_, **kw)
        model.geometric_ = geo
    model.estimator_ = est
    model.arrays_ = arrays
    if forward_chaining and exclude is None and coefs is not None and method != "mr-poly":
        from host.learning.empirical.forward import linear_forward_chaining

        try:
            stats["forward_chaining"] = linear_forward_chaining(model, runs, target, channel, fit_intercept, window)
        except EmpiricalDataError as exc:
            stats["forward_chaining"] = {"error": str(exc)}
    return model


INPUT_MARGIN = 1.25  # spindle speed and feed envelopes: the training maximum x this (the board clamps beyond)


def _input_envelope(runs, terms):
    """Envelopes of the controller's inputs a dynamic model reads: [0, training maximum x INPUT_MARGIN],
    rounded up to 100 rpm / 100 mm/min (the exporter certifies the table over them)."""
    sig = {n for n, _ in terms}
    out = {}
    if sig & {"spindle_krpm", "spindle_krpm2"}:
        top = max([float(np.max(np.abs(r.spindle.rpm))) for r in runs if r.spindle is not None and r.spindle.rpm.size] + [0.0])
        out["spindle_rpm"] = [0, float(100 * np.ceil(top * INPUT_MARGIN / 100))]
    if "feed_m_min" in sig:
        top = max([float(np.max(np.abs(r.motion.feed_mm_min))) for r in runs if r.motion is not None and len(r.motion)] + [0.0])
        out["feed_mm_min"] = [0, float(100 * np.ceil(top * INPUT_MARGIN / 100))]
    if out:
        out["input_rule"] = "spindle speed and feed: [0, training maximum x %g], rounded up to 100" % INPUT_MARGIN
    return out


def _sample_interval(runs):
    """The training runs' temperature sample interval (median, whole ms): the board's filter step, at which
    its recurrence is the host's (host/learning/empirical/dynamic.py filters at each run's own sample times)."""
    dts = np.concatenate([np.diff(np.asarray(r.temperatures.time_s, dtype=float)) for r in runs])
    dts = dts[dts > 0]
    return float(np.round(np.median(dts) * 1000) / 1000) if dts.size else None


def _fit_dynamic(runs, arrays, y, target, channel, window, fit_intercept, margin, geometric, cv_blocks, options, exclude=None, report_forward=True):
    """``method="dynamic"``: lag-filtered signals chosen by forward chaining (default) or leave-one-group-out
    (host/learning/empirical/dynamic.py, forward.py); lags bounded by the training span."""
    from host.learning.empirical import averaging, forward
    from host.learning.empirical.dynamic import TAU_MAX_FRACTION, TAUS_S, DynamicModel, DynamicRegression, candidate_matrix
    from host.learning.empirical.settle import SettleBound, settle_max_option

    opts = dict(options)
    taus = tuple(float(v) for v in opts.pop("taus_s", TAUS_S))
    if not taus or any(not np.isfinite(v) or v < 0 for v in taus):
        raise EmpiricalDataError("dynamic: taus_s must be time constants >= 0 s, got %r" % (taus,))
    use_spindle = bool(opts.pop("use_spindle", True))
    use_feed = bool(opts.pop("use_feed", True))
    use_observer = opts.pop("observer", True)
    if not isinstance(use_observer, bool):
        raise EmpiricalDataError("dynamic: observer must be true or false, got %r" % (use_observer,))
    # N equal time blocks of one run: forward_blocks, or cv_blocks (its meaning for the other cross-validated methods)
    forward_blocks = opts.pop("forward_blocks", None)
    if forward_blocks is None and opts.get("selection", "forward") == "forward":
        forward_blocks = cv_blocks
    forward_state = opts.pop("forward_state", FORWARD_STATE)
    if forward_state not in FORWARD_STATES:
        raise EmpiricalDataError("dynamic: forward_state must be one of %s, got %r" % (", ".join(FORWARD_STATES), forward_state))
    # with the observer, the defaults are the controller's record, the settle bound and the worse-start scoring
    # (docs/results.md, "A second start for worse"); without it none of them means anything
    settle_max_s = settle_max_option(opts.pop("settle_max_s", SETTLE_MAX_S if use_observer else None))  # settle.py
    spindle_states = opts.pop("spindle_states", SPINDLE_STATES if use_observer else "observer")
    if spindle_states not in ("observer", "controller"):
        raise EmpiricalDataError("dynamic: spindle_states must be observer or controller, got %r" % (spindle_states,))
    if spindle_states == "controller" and not use_observer:
        raise EmpiricalDataError("dynamic: spindle_states=controller sets lag states of the observer's start; it needs observer=true")
    from host.learning.empirical.observer import CONTROLLER_SIGNALS

    # the spindle/feed lag states the controller supplies at a board's start (docs/empirical.md "Controller's record")
    controller = CONTROLLER_SIGNALS if spindle_states == "controller" else ()
    # how a switched-on block scores those states: from the record, or the worse of that and without it (forward.py)
    controller_scoring = opts.pop("controller_scoring", None)
    if controller_scoring is not None and (controller_scoring not in forward.CONTROLLER_SCORINGS or not controller):
        raise EmpiricalDataError("dynamic: controller_scoring must be one of %s, and needs spindle_states=controller; got %r "
                                 "with spindle_states=%s" % (", ".join(forward.CONTROLLER_SCORINGS), controller_scoring, spindle_states))
    controller_scoring = controller_scoring or (CONTROLLER_SCORING if controller else forward.RECORD)
    # the settle bound of a board whose controller does not send the record (settle_without_record_s): off by default
    nr_max_s = settle_max_option(opts.pop("settle_without_record_max_s", None), "settle_without_record_max_s")
    if nr_max_s is not None and (not controller or settle_max_s is None):
        raise EmpiricalDataError("dynamic: settle_without_record_max_s bounds the settle time of a board without the controller's "
                                 "record; it needs spindle_states=controller and settle_max_s")
    static_fallback = opts.pop("static_fallback", True)
    if not isinstance(static_fallback, bool):
        raise EmpiricalDataError("dynamic: static_fallback must be true or false, got %r" % (static_fallback,))
    if settle_max_s is not None and not use_observer:
        raise EmpiricalDataError("dynamic: settle_max_s bounds the observer's settle time; it needs observer=true")
    from host.learning.empirical.observer import observer_sensors_option

    observer_count = observer_sensors_option(opts.pop("observer_sensors", 0))  # sensors only the observer reads (observer.py)
    if observer_count and not use_observer:
        raise EmpiricalDataError("dynamic: observer_sensors adds sensors the observer reads; it needs observer=true")
    average_count = averaging.check_count(opts.pop("average_structures", averaging.AVERAGE_STRUCTURES))
    average_members = opts.pop("average_members", "ridge")
    if controller_scoring == forward.WORSE and average_count > 1:
        # the average's weights minimise each block's squared error as a quadratic in them; the worse of two starts is not one
        raise EmpiricalDataError("dynamic: controller_scoring=worse (the default with the observer) and average_structures > 1 "
                                 "cannot be combined (the average's weights are fitted on one start per block); give "
                                 "controller_scoring=record and settle_max_s=none to average")
    if settle_max_s is not None and average_count > 1:
        # the average's union would carry an observer the bound never checked: not combined (neither measured with the other)
        raise EmpiricalDataError("dynamic: settle_max_s and average_structures > 1 cannot be combined (the averaged union's observer is not bounded)")
    lag_bound = _lag_bound(arrays, opts.pop("tau_max_fraction", TAU_MAX_FRACTION))
    lag_bound["excluded_taus_s"] = [v for v in taus if v > lag_bound["max_tau_s"]]
    taus = tuple(v for v in taus if v <= lag_bound["max_tau_s"])
    if not taus:
        raise EmpiricalDataError("dynamic: every time constant in taus_s (%s s) exceeds %g s, the longest the training span of %.0f s "
                                 "can identify (tau_max_fraction=%g); give shorter taus_s or longer training data"
                                 % ("/".join("%g" % v for v in lag_bound["excluded_taus_s"]), lag_bound["max_tau_s"],
                                    lag_bound["training_span_s"], lag_bound["fraction"]))
    names = arrays[0].names
    F, terms = candidate_matrix(runs, [a.time_s for a in arrays], names, taus, use_spindle, use_feed)
    assert terms is not None  # None only without runs; arrays[0] above has read the first
    selection = opts.get("selection", "forward")
    labels, blocks, fc_error = None, None, None
    try:
        labels, blocks = forward.forward_blocks(runs, arrays, forward_blocks)
    except EmpiricalDataError as exc:
        if selection == "forward":
            raise EmpiricalDataError("dynamic: %s" % exc)
        fc_error = str(exc)
    if selection == "forward":
        groups = labels
    else:
        groups = cv_groups(runs, arrays, cv_blocks)
    try:
        est = DynamicRegression(fit_intercept=fit_intercept, **opts)
    except TypeError as exc:
        raise EmpiricalDataError("dynamic: %s" % exc)
    # the training runs' mean start temperature of every candidate sensor: the fixed reference of the observer's inputs
    # (the model's reference_C below is this, restricted to the sensors it uses)
    reference_all = dict(zip(names, np.mean([start_temperatures(r, names) for r in runs], axis=0).tolist()))
    # the observer's tolerance is in um of offset: a slope (um/mm) times the largest training position
    obs_scale = 1.0 if target == "direct" else float(max(np.nanmax(np.abs(r.errors.position_mm)) for r in runs))
    scored_as = None
    if selection == "forward" and forward_state == "switched_on":
        assert blocks is not None and labels is not None  # selection "forward" raised above when forward_blocks failed
        # a block of one run shorter than SWITCHED_ON_MIN_S is scored with its filters running since the run start
        short = forward.short_blocks(runs, blocks, SWITCHED_ON_MIN_S)
        long_blocks = [b for b in blocks if b["block"] not in short]
        scored_as = {"switched_on_min_s": SWITCHED_ON_MIN_S, "continuous_blocks": short, "rule": SHORT_BLOCK_RULE}
        if use_observer:
            # each block as a board switched on at its start computes it: filters from the estimate of the observer of the
            # structure being scored, fitted on the blocks before it (forward.observer_block_columns)
            est.with_block_columns(forward.observer_block_columns(runs, arrays, labels, blocks, terms, reference_all, target,
                                                                  channel, exclude, obs_scale, scored=long_blocks,
                                                                  controller=controller, scoring=controller_scoring))
        elif len(runs) == 1:
            # without an observer: filters from rest on rises over the block's start (several runs: each run already is)
            held = {}
            for b in long_blocks:
                if b["block"] == 0:  # never scored
                    continue
                rows = labels == b["block"]
                Fk, _ = candidate_matrix([forward.block_run(runs, b)], [np.concatenate([a.time_s for a in arrays])[rows]], names, taus,
                                         use_spindle, use_feed)
                held[b["block"]] = (Fk, y[rows])
            est.with_block_columns(held)
    if settle_max_s is not None:
        # only structures whose observer (the one the document will carry) settles within settle_max_s
        est.with_settle_bound(SettleBound(settle_max_s, runs, [(a.time_s.min(), a.time_s.max()) for a in arrays], exclude,
                                          reference_all, target, channel, obs_scale, taus, controller=controller,
                                          without_record_max_s=nr_max_s))
    est.fit(F, y, terms, groups=groups)
    record_start = None
    if controller_scoring == forward.WORSE and selection == "forward" and _scored_by_two_starts(est.block_columns):
        est, record_start = _search_from_record_structure(est, opts, fit_intercept, F, y, terms, groups)
    settle_record = est.settle_bound_
    searched = est  # the search over every term (the static fallback may replace est)
    plain = None
    fallback: dict[str, Any] | None = None
    static = [j for j, (_, tau) in enumerate(terms) if tau == 0]
    if static_fallback and selection == "forward" and static and len(static) < len(terms):
        # the same search over the static terms (tau = 0) alone, scored the same way: the greedy search over every term can
        # end in a dynamic structure that predicts the next block worse than a static one it never reached (docs/empirical.md)
        plain = DynamicRegression(fit_intercept=fit_intercept, **opts)
        if est.block_columns:
            plain.with_block_columns({k: _columns_subset(v, static) for k, v in est.block_columns.items()})
        try:
            plain.fit(F[:, static], y, [terms[j] for j in static], groups=groups)
        except EmpiricalDataError as exc:  # e.g. no static term lowers the score: the dynamic search stands
            fallback = {"static_score_um": None, "static_error": str(exc)}
        else:
            fallback = {"static_score_um": float(plain.cv_rmse_)}
        fallback.update(rule=STATIC_FALLBACK_RULE, dynamic_score_um=float(est.cv_rmse_),
                        chosen="static" if fallback["static_score_um"] is not None and fallback["static_score_um"] < est.cv_rmse_ else "dynamic")
        if fallback["chosen"] == "static":
            est = plain
    single = est
    averaged, average_record = None, None
    if selection == "forward" and average_count > 1:
        averaged, average_record = _average_structures(est, searched, plain, static, F, y, terms, groups, average_count,
                                                       average_members)
    if averaged is not None:
        est = averaged
    stats = est.statistics()
    if average_record is not None:
        stats["structure_average"] = average_record
    if fallback is not None:
        stats["static_fallback"] = fallback
    if record_start is not None:
        stats["record_structure_start"] = record_start
    stats["lag_bound"] = lag_bound
    if use_observer:
        stats["spindle_states"] = spindle_states  # "controller": the controller's record supplies the spindle/feed lag states
        if controller:
            stats["controller_scoring"] = controller_scoring
    if selection == "forward":
        stats["forward_state"] = forward_state
        if scored_as is not None:
            stats["forward_scored_as"] = scored_as
    used = [n[2:] for n, _ in est.terms_ if n.startswith("T:")]
    used = list(dict.fromkeys(used))
    start = np.mean([start_temperatures(r, used) for r in runs], axis=0) if used else []
    training = {
        "runs": [r.path or r.name for r in runs], "target": target, "window_s": list(window) if window is not None else None,
        "n_samples": int(y.size), "rises": True, "fit_intercept": bool(fit_intercept), "candidate_sensors": list(names),
        "taus_s": list(taus), "signals": sorted({n for n, _ in terms}), "options": {k: v for k, v in options.items()},
    }
    geo = None
    if target == "slope":
        geo = fit_geometric(runs, channel, *geometric)
        stats["geometric"] = {"degree": int(geo.degree_), "rmse_um": geo.rmse_, "selection": geo.scores_,
                              "criterion": geometric[1] if geometric[2] is None else "fixed"}
    env = _envelope(runs, arrays, used, margin, target, channel) if used else {}
    env.update(_input_envelope(runs, est.terms_))
    model = DynamicModel(est.terms_, est.coef_, est.intercept_, target, channel, geo.coef_ if geo is not None else (0.0,), "dynamic",
                         runs[0].meta.get("axis"), dict(zip(used, np.atleast_1d(start).tolist())), env, stats, training,
                         _sample_interval(runs))
    if use_observer:
        # the lag states estimated from the sensors when a board starts (host/learning/empirical/observer.py),
        # fitted on the training samples only (window, exclude): never on what is held out
        from host.learning.empirical.observer import fit_observer

        model.observer = fit_observer(model, runs, spans=[(a.time_s.min(), a.time_s.max()) for a in arrays], exclude=exclude, scale=obs_scale,
                                      controller=controller)
        if observer_count:
            # sensors beyond the terms' whose present reading recovers the lag states better, chosen on the training
            # samples only, the model's sensors staying within max_sensors (docs/empirical.md "Observer-only sensors")
            from host.learning.empirical.observer import choose_observer_sensors

            stats["observer_sensors"] = choose_observer_sensors(
                model, runs, names, reference_all, observer_count, int(searched.max_sensors),
                spans=[(a.time_s.min(), a.time_s.max()) for a in arrays], exclude=exclude, scale=obs_scale)
            if model.observer_sensors:  # their training envelope too: the table's inputs need one (models_export)
                extra_env = _envelope(runs, arrays, model.observer_sensors, margin, target, channel)
                for key in ("temperature_C", "temperature_rise_K"):
                    model.envelope.setdefault(key, {}).update(extra_env[key])
    if settle_record is not None:
        # what the bound refused in the search over every term, and the settle_s of the model as written (the static
        # fallback's, when it won: 0, it has no lag state)
        stats["settle_bound"] = dict(settle_record, chosen=fallback["chosen"] if fallback else "dynamic",
                                     settle_s=model.observer.settle_s if model.observer is not None else None)
    model.estimator_ = est
    model.arrays_ = arrays
    model.geometric_ = geo
    if averaged is not None:
        # the single structure the average replaced, as a model of its own (not in the document): for comparisons
        model.single_ = _single_model(single, model, reference_all, runs, arrays, exclude, obs_scale, use_observer)
    if report_forward and blocks is None:
        stats["forward_chaining"] = {"error": fc_error}
    elif report_forward:
        assert blocks is not None  # the branch above took None
        def refit(k):
            b0, coef = est.coefficients_on(labels < k)
            m = DynamicModel(est.terms_, coef, b0, target, channel, model.geometric_coef, "dynamic", model.axis,
                             reference_C=model.reference_C, training={"error_reference": common_error_reference(runs)})
            m.observer_sensors = list(model.observer_sensors)  # the fold's observer reads what the model's reads
            if use_observer:
                # the board scored on block k starts with an observer fitted on the blocks before it, as the model's own
                # was on all of them (reference_C: the training runs' start temperatures, as the model's)
                m.observer = forward.fit_fold_observer(m, runs, blocks, k, exclude, obs_scale, controller)
            return m

        fc = stats["forward_chaining"] = forward.forward_chaining(runs, blocks, refit, target)
        fc["structure"] = "terms and penalty as chosen on all training data; coefficients refitted on the blocks before each scored block"
        # beside it, the same blocks predicted by a plain MLR on every candidate sensor: a user sees whether the dynamic
        # structure beats it (tcomp fit warns when it does not)
        try:
            base = forward.baseline_mlr_all(runs, blocks, target, channel, names, fit_intercept, window, exclude)
        except EmpiricalDataError as exc:  # e.g. a first block with fewer samples than the MLR's parameters: said, not hidden
            fc["baseline_" + forward.BASELINE] = {"method": "mlr", "sensors": list(names), "error": str(exc)}
            fc["beats_baseline"] = None
        else:
            fc["baseline_" + forward.BASELINE] = base
            fc["beats_baseline"] = bool(fc["pooled_um"] < base["pooled_um"])
    return model


def _average_structures(chosen, searched, plain, static, F, y, terms, groups, count, members_from="ridge"):
    """(AveragedRegression or None, its record): structure averaging (host/learning/empirical/averaging.py) over the
    per-ridge structures of the search over every term and, when it ran, of the static search (``plain``)."""
    from host.learning.empirical import averaging

    searches = [(searched, list(range(len(terms))))]
    if plain is not None:
        searches.append((plain, static))
    return averaging.average(chosen, F, y, terms, groups, searches, count, searched.block_columns, members_from)


def _single_model(est, model, reference_all, runs, arrays, exclude, obs_scale, use_observer):
    """The DynamicModel of the single structure ``est`` that structure averaging replaced in ``model`` (same target,
    geometry, reference rule and observer fit as the averaged model)."""
    from host.learning.empirical.dynamic import DynamicModel

    used = list(dict.fromkeys(n[2:] for n, _ in est.terms_ if n.startswith("T:")))
    out = DynamicModel(est.terms_, est.coef_, est.intercept_, model.target, model.channel, model.geometric_coef, "dynamic", model.axis,
                       {s: reference_all[s] for s in used}, training=model.training, dt_s=model.dt_s)
    if use_observer:
        from host.learning.empirical.observer import fit_observer

        out.observer = fit_observer(out, runs, spans=[(a.time_s.min(), a.time_s.max()) for a in arrays], exclude=exclude, scale=obs_scale)
    return out


STATIC_FALLBACK_RULE = ("the structure chosen among every term is compared with the one the same search chooses among the static terms "
                        "(tau = 0) alone, on the same forward-chaining score; the lower score is the model")


RECORD_START_RULE = ("controller_scoring=worse: the greedy search from the empty structure is compared with the same search started "
                     "from the structure record scoring chooses, both scored by the worse of the two starts per block; the lower "
                     "score is the model")


def _scored_by_two_starts(block_columns):
    """Whether some block is scored by the worse of two starts: otherwise (no candidate state the controller supplies)
    record and worse scoring are one criterion, and a second search would only repeat the first."""
    from host.learning.empirical.dynamic import WorseOfStarts

    return any(isinstance(v, WorseOfStarts) for v in (block_columns or {}).values())


def _search_from_record_structure(est, opts, fit_intercept, F, y, terms, groups):
    """controller_scoring=worse: the greedy search scored by the worse of two starts never adds a long spindle lag first
    (alone, without the record, it starts far off), so it can miss a structure that is better by its own criterion, one
    that record scoring finds (docs/results.md, ch3's leave-one-cycle-out). Search again, by the same criterion, from the
    structure record scoring chooses; keep whichever scores lower. Returns (estimator, statistics record)."""
    from host.learning.empirical.dynamic import DynamicRegression, WorseOfStarts

    record_columns = {k: v.starts[0] if isinstance(v, WorseOfStarts) else v for k, v in est.block_columns.items()}
    by_record = DynamicRegression(fit_intercept=fit_intercept, **opts).with_block_columns(record_columns)
    by_record.with_settle_bound(est.settle_bound)
    try:
        by_record.fit(F, y, terms, groups=groups)
    except EmpiricalDataError as exc:  # no term lowers the record-scored score: the search from empty stands
        return est, {"rule": RECORD_START_RULE, "record_structure": None, "record_error": str(exc), "chosen": "from_empty"}
    started = DynamicRegression(fit_intercept=fit_intercept, **opts).with_block_columns(est.block_columns)
    started.with_settle_bound(est.settle_bound).with_start(by_record.terms_)
    started.fit(F, y, terms, groups=groups)
    given = [h for h in started.history_ if h["action"] == "start_from"]
    record = {"rule": RECORD_START_RULE, "record_structure": [[n, tau] for n, tau in by_record.terms_],
              "record_structure_score_um": float(given[0]["cv_rmse"]) if given else None,
              "from_empty_score_um": float(est.cv_rmse_), "from_record_structure_score_um": float(started.cv_rmse_),
              "chosen": "from_record_structure" if started.cv_rmse_ < est.cv_rmse_ else "from_empty"}
    return (started if record["chosen"] == "from_record_structure" else est), record


def _columns_subset(columns, cols):
    """A scored block's switched-on columns (dynamic.with_block_columns) restricted to the candidate columns ``cols``."""
    from host.learning.empirical.dynamic import StartedColumns, WorseOfStarts

    def started(c: StartedColumns) -> StartedColumns:
        return StartedColumns(c.rest[:, cols], c.decay[:, cols], c.y, lambda sub: c.start([cols[i] for i in sub]))

    if isinstance(columns, WorseOfStarts):
        return WorseOfStarts([started(s) for s in columns.starts])
    if isinstance(columns, StartedColumns):
        return started(columns)
    Fk, yk = columns
    return np.asarray(Fk)[:, cols], yk


FORWARD_STATES = ("switched_on", "continuous")
# the dynamic model's defaults with the observer (docs/empirical.md; measured in docs/results.md "A second start for
# worse"): the controller supplies the spindle/feed lag states, the structure's observer settles within 30 min, and a
# structure is chosen by the worse of a board with and without the controller's record
SPINDLE_STATES = "controller"
SETTLE_MAX_S = 1800.0
CONTROLLER_SCORING = "worse"
FORWARD_STATE = "switched_on"  # how the selection scores a block: as the board switched on at its start computes it (docs/empirical.md)
# with forward_state=switched_on, a block of one run shorter than this is scored with its filters running since the run
# start: issue 21's restart goal lets a board settle for 30 min (SETTLING), so a block scored as switched on spends at most
# a third of its length in that window; shorter, its score is mostly the observer's start error, not how the structure
# predicts. Chosen, not fitted: any value in (1 h, 2 h) keeps both synthetic machines' tests and every FL_THERMAL figure
# (its shortest block is 3.87 h); docs/empirical.md, "Forward-chaining validation".
SWITCHED_ON_MIN_S = 3 * 1800.0
SHORT_BLOCK_RULE = ("forward_state=switched_on scores a block of one run as a board switched on at its start only when the block "
                    "lasts >= switched_on_min_s (3 x the 30 min a board may take to settle); a shorter block (continuous_blocks) "
                    "is scored with its filters running since the run start")


def _lag_bound(arrays, fraction):
    """The longest time constant the training data can identify: ``fraction`` x the longest training run's span."""
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
        raise EmpiricalDataError("dynamic: tau_max_fraction must be a number in (0, 1], got %r" % (fraction,))
    span = max(float(a.time_s.max() - a.time_s.min()) for a in arrays)
    return {"fraction": float(fraction), "training_span_s": span, "max_tau_s": float(fraction) * span,
            "rule": "a lag tau is a candidate only when tau <= fraction x the longest training run's span (4 tau: 98 % of a step response)"}
