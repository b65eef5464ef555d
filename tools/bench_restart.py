"""Figures of a dynamic model's board restarted on a warm machine, observer on vs off (issue 21), host model in floats.

1. FL_THERMAL (data/fl_thermal), every channel: `tcomp fit` defaults (dynamic, direct) on t < SPLIT_H, and MLR-16
   (all sensors, fixed reference) on the same span. Held-out RMSE on t >= SPLIT_H and its ratio to MLR-16's for the
   dynamic model with the board switched on at the split (observer), the same without observer (filters from rest,
   rises over the split: the behaviour before issue 21), and with the filters running since 0 h (`--history`).
2. Restarts: the same models, board reset at several points of FL_THERMAL, and a twin-trained slope model reset at
   several points of the twin's 24 h day; the deviation of the restarted board's offset from the uninterrupted board
   (at the largest training position for a slope model): largest in the first 30 min and overall, at 30 min, and the
   settle time (from when on it stays within 1 um), observer on vs off; and the observer's SETTLING time (settle_s).
3. `--windows 0,5,10,20,30` (experiment, docs/empirical.md "Observer: two follow-ups measured"): the same resets
   with a second state estimate after a window of W minutes. During the window the board runs from the observer's
   instantaneous estimate (as now); at t0+W each lag state is re-estimated by least squares, without a constant,
   from what the board has then (`--window-regressors`, letters): u the filter inputs at t0+W, d their change
   u(t0+W) - u(t0), y the board's own lag states at t0+W (run from the instantaneous estimate), h a helper filter
   (tau = W/2) of each input started at u(t0), minus u(t0+W). Fitted on the training samples at every start time t0,
   as the observer is. A state takes the window estimate only if its largest training residual E_j^W is below the
   instantaneous one decayed over the window, E_j e^(-W/tau_j). Per W: settle_s (the start-error bound's 1-um time:
   the instantaneous bound before W, the window's after), E_j, resets within 1 um at 30 min, and per reset the
   largest deviation in the first 30 min / at 30 min / settle time / the offset's step at t0+W.
4. `--spindle-history 30,60,120,inf` (experiment, same section): what the speed's recent history, as the controller
   saw it, says about the state at a reset. S0: the spindle/feed lag states set to their uninterrupted values (a
   controller that ran the board's speed filters itself), the temperature states from the observer's instantaneous
   estimate. S(H): every lag state re-estimated by least squares, without a constant, from the inputs and the
   spindle/feed filters run from rest over the last H minutes before the reset (H = inf: their exact values),
   fitted on the training samples at every start time.
5. Warm restarts (``--warm``, docs/firmware.md "Warm restarts of the lag states"): the same resets as a short cut
   (back within seconds), the lag states restored from lags.bin when the firmware's rule trusts them (every model
   sensor within 1 K of its reading at the write, and the observer's estimate moved at most 10 um of offset),
   the observer's start otherwise. The stored state is the last periodic write, AGE_S old: 0 s (a cut right after a
   write, or an X reset, which writes first) and 600 s (a cut just before the next write, the oldest it can be).
   Per reset: warm state (age 0) / warm state (age 600 s) / observer only / neither, each as the largest deviation
   and the settle time; "obs" marks a warm restart that refused the record and started from the observer.
   Then the rule's sweep: a record CUTS_S old (a cut of that length, or a shorter one after an older write) at a
   reset every 2 h of FL_THERMAL, all channels pooled: for each pair of limits (sensor K, observer um), the share of
   records trusted and the mean / largest deviation of the board that applies it, beside restore-always and
   observer-only. The firmware's limits are the row marked "*".

``--option KEY=VALUE`` (JSON value) passes a dynamic setting to every model fitted (FL_THERMAL and twin), e.g.
``--option settle_max_s=1800`` (the settle-bounded structure choice, docs/empirical.md "Settle bound"); each case
prints its terms and, with that option, statistics.settle_bound. The last lines sum sections 1-2 up per case, observer
on: resets within 1 um at 30 min, the largest deviation in the first 30 min, the median settle time, SETTLING.

Usage: .venv/bin/python tools/bench_restart.py [--channels ch1,ch4] [--no-twin] [--no-split] [--warm] [--option KEY=VALUE ...]
       [--windows 0,5,10,20,30 [--window-regressors ud,udy,udh,udhy]] [--spindle-history 30,60,120,inf]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.data.runs import load_run, slice_run
from host.learning.empirical import observer as obs
from host.learning.empirical.fitting import fit_model
from host.options import parse_options

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPLIT_H = 32.13  # start of FL_THERMAL's 5th spindle cycle (docs/results.md)
FL_RESETS_H = (4.0, 12.0, 20.0, 28.0, 36.0, 44.0)
TWIN_RESETS_H = (2.0, 6.0, 10.0, 14.0, 18.0)
TOL_UM = 1.0
WINDOW_S = 1800.0
REGRESSORS = "udyh"


def without_observer(model):
    """The same terms with filters from rest and rises over the run's start (a document without thermal.observer)."""
    doc = model.to_document()
    doc["thermal"] = {k: v for k, v in doc["thermal"].items() if k != "observer"}
    doc["thermal"]["reference"] = "run_start"
    doc["sensors"] = list(model.term_sensors)  # without the observer no sensor is read by the observer alone
    return type(model).from_document(doc)


def rmse(model, run, ch, **kw):
    rows = np.flatnonzero(run.errors.channel == ch) if run.errors.channel is not None else np.arange(len(run.errors))
    r = run.errors.error_um[rows] - model.predict(run, **kw)[rows]
    return float(np.sqrt(np.mean(r**2)))


def deviation_figures(el, dev):
    """(largest in the first 30 min, at 30 min, settle time: from when on within TOL_UM) of a deviation series."""
    over = np.flatnonzero(dev > TOL_UM)
    settle = 0.0 if not over.size else (el[over[-1] + 1] if over[-1] + 1 < el.size else np.inf)
    return dev[el <= WINDOW_S].max(), float(np.interp(WINDOW_S, el, dev)) if el[-1] >= WINDOW_S else np.nan, dev.max(), settle


def restart_figures(model, run, reset_s, scale):
    """Deviation (um) of a board reset at reset_s from the uninterrupted one, observer on and off."""
    t = run.temperatures.time_s
    times = t[t >= reset_s]
    warm = slice_run(run, reset_s)
    full = model.thermal_at(run, times) * scale
    out = {}
    # a model fitted with spindle_states=controller starts those states from the controller's record before the reset
    record = [slice_run(run, float(t[0]), reset_s)] if obs.reads_controller(model) and reset_s > t[0] else None
    for name, m in (("on", model), ("off", without_observer(model))):
        dev = np.abs((m.thermal_at(warm, times, controller_history=record) if name == "on" else m.thermal_at(warm, times)) * scale - full)
        out[name] = deviation_figures(times - times[0], dev)
    if record is not None:
        # the same board whose controller does not send the record: those states at the observer's estimate
        out["no record"] = deviation_figures(times - times[0], np.abs(model.thermal_at(warm, times) * scale - full))
    return out


WARM_DRIFT_K = 1.0  # firmware/app.py _LAG_DRIFT_MK
WARM_AGREE_UM = 10.0  # firmware/app.py _LAG_AGREE (0.01 um)
CUTS_S = (60.0, 600.0, 1800.0, 3600.0, 7200.0, 28800.0)  # the rule's sweep: how long the stored state is old at the restart
RULES = ((0.25, 1.0), (1.0, 5.0), (WARM_DRIFT_K, WARM_AGREE_UM), (1.0, np.inf), (2.0, 10.0), (2.0, np.inf))
AGES_S = (0.0, 600.0)  # the stored state's age: right after a write; just before the next (firmware/warmstate.py _SAVE_MS)


def _settle_of(el, dev):
    over = np.flatnonzero(dev > TOL_UM)
    return 0.0 if not over.size else (el[over[-1] + 1] if over[-1] + 1 < el.size else np.inf)


def warm_figures(model, run, reset_s, scale, age_s):
    """A short cut at reset_s with the lag states of reset_s - age_s stored: (trusted, max deviation, settle time) of
    the board that applies the firmware's rule (restore if trusted, else the observer's start)."""
    from host.learning.empirical.observer import _filter_from, board_terms, inputs

    t, cols = board_terms(model, [run])  # the uninterrupted board (switched on at the run's start, observer)
    _, sig = inputs(model, run)
    coef = np.asarray(model.term_coefficients, dtype=float)
    k = np.flatnonzero(t >= reset_s)
    ts = t[k]
    el = ts - ts[0]
    full = (model.intercept + cols[k] @ coef) * scale
    then = reset_s - age_s
    temps_then = {s: float(np.interp(then, run.temperatures.time_s, run.temperatures.column(s))) for s in model.sensors}
    temps_now = {s: float(run.temperatures.column(s)[k[0]]) for s in model.sensors}
    trusted = max(abs(temps_now[s] - temps_then[s]) for s in model.sensors) <= WARM_DRIFT_K
    if trusted and model.observer is not None:
        u_then = {n: float(np.interp(then, t, v)) for n, v in sig.items()}
        u_now = dict(u_then)  # the temperatures now, the spindle and feed of the write (as the firmware compares)
        for s in model.sensors:
            u_now["T:" + s] = temps_now[s] - model.reference_C[s]
        e0, e1 = model.observer.initial_states(u_then), model.observer.initial_states(u_now)
        moved = abs(sum(coef[j] * (e1[j] - e0[j]) for j in e0)) * scale
        trusted = moved <= WARM_AGREE_UM
    if trusted:
        own = np.column_stack([_filter_from(ts, sig[name][k], tau, float(np.interp(then, t, cols[:, j])))
                               for j, (name, tau) in enumerate(model.terms)])
        warm = (model.intercept + own @ coef) * scale
    else:
        warm = model.thermal_at(slice_run(run, reset_s), ts) * scale
    dev = np.abs(warm - full)
    return trusted, float(dev.max()), _settle_of(el, dev)


def print_warm(label, model, run, resets_h, scale):
    print("\n%s, short cuts: largest deviation from the uninterrupted board (um) / settle time (within 1 um from then on)" % label)
    print("%6s | %-26s | %-26s | %-26s | %-26s" % ("H", "warm state, age 0 s", "warm state, age 600 s", "observer only", "neither"))
    for h in resets_h:
        cells = []
        for age in AGES_S:
            ok, d, st = warm_figures(model, run, h * 3600.0, scale, age)
            cells.append("%7.2f / %-12s %4s" % (d, fmt_settle(st), "" if ok else "obs"))
        f = restart_figures(model, run, h * 3600.0, scale)
        for name in ("on", "off"):
            cells.append("%7.2f / %-17s" % (f[name][2], fmt_settle(f[name][3])))
        print("%6.1f | %s" % (h, " | ".join(cells)))


def _cut_case(model, run, t, cols, sig, coef, reset_s, age_s):
    """(largest sensor change K, observer's move um, deviation restored um, deviation observer um) of one cut."""
    from host.learning.empirical.observer import _filter_from

    k = np.flatnonzero(t >= reset_s)
    ts = t[k]
    then = reset_s - age_s
    now = {s: float(run.temperatures.column(s)[k[0]]) for s in model.sensors}
    old = {s: float(np.interp(then, run.temperatures.time_s, run.temperatures.column(s))) for s in model.sensors}
    u_then = {n: float(np.interp(then, t, v)) for n, v in sig.items()}
    u_now = dict(u_then)
    for s in model.sensors:
        u_now["T:" + s] = now[s] - model.reference_C[s]
    e0, e1 = model.observer.initial_states(u_then), model.observer.initial_states(u_now)
    moved = abs(sum(coef[j] * (e1[j] - e0[j]) for j in e0))
    own = np.column_stack([_filter_from(ts, sig[n][k], tau, float(np.interp(then, t, cols[:, j])))
                           for j, (n, tau) in enumerate(model.terms)])
    dev_r = float(np.abs((own - cols[k]) @ coef).max())
    dev_o = float(np.abs(model.thermal_at(slice_run(run, reset_s), ts) - (model.intercept + cols[k] @ coef)).max())
    return max(abs(now[s] - old[s]) for s in model.sensors), moved, dev_r, dev_o


def print_rule_sweep(models, run):
    from host.learning.empirical.observer import board_terms, inputs

    cases = {c: [] for c in CUTS_S}
    for model in models:
        t, cols = board_terms(model, [run])
        _, sig = inputs(model, run)
        coef = np.asarray(model.term_coefficients, dtype=float)
        for c in CUTS_S:
            for h in np.arange(2.0, 46.0, 2.0):
                if h * 3600.0 - c >= 0:
                    cases[c].append(_cut_case(model, run, t, cols, sig, coef, h * 3600.0, c))
    print("\nthe restore rule on FL_THERMAL (%s pooled, a reset every 2 h): trusted %% / mean / largest deviation (um) "
          "of the board applying it, by the stored state's age" % ",".join(m.channel for m in models))
    print("%-24s | %s" % ("rule", " | ".join("%-22s" % ("%.0f s" % c) for c in CUTS_S)))
    rows = [("restore always", None), ("observer only", None)] + [("%s %.2f K, %s um" % (
        "*" if (dk, au) == (WARM_DRIFT_K, WARM_AGREE_UM) else " ", dk, "any" if not np.isfinite(au) else "%g" % au), (dk, au))
        for dk, au in RULES]
    for label, rule in rows:
        cells = []
        for c in CUTS_S:
            a = np.array(cases[c])
            if label == "restore always":
                acc = np.ones(len(a), dtype=bool)
            elif rule is None:
                acc = np.zeros(len(a), dtype=bool)
            else:
                acc = (a[:, 0] <= rule[0]) & (a[:, 1] <= rule[1])
            chosen = np.where(acc, a[:, 2], a[:, 3])
            cells.append("%3.0f%% %6.2f %6.2f      " % (100 * acc.mean(), chosen.mean(), chosen.max()))
        print("%-24s | %s" % (label, " | ".join(cells)))


def fmt_settle(s):
    return "never (in record)" if not np.isfinite(s) else "%.0f min" % (s / 60)


def print_restarts(label, model, run, resets_h, scale):
    """Print the resets' figures -> [(max30, at30, settle s)] with the observer on, one per reset."""
    print("\n%s: board reset at hour H vs the uninterrupted board (um of offset); SETTLING time of the observer %.0f min"
          % (label, model.observer.settle_s / 60))
    print("terms (signal, tau s, coefficient): %s" % ", ".join("%s %g s %.3g" % (n, tau, c) for (n, tau), c in
                                                              zip(model.terms, model.term_coefficients)))
    bound = model.statistics.get("settle_bound")
    if bound is not None:
        print("settle bound: %s" % {k: v for k, v in bound.items() if k != "rule"})
    print("%6s | %-44s | %-44s" % ("H", "observer on: max30 / at30 / max / settle", "observer off: max30 / at30 / max / settle"))
    out = []
    for h in resets_h:
        f = restart_figures(model, run, h * 3600.0, scale)
        cells = [f[k] for k in ("on", "off", "no record") if k in f]
        print("%6.1f | %s%s" % (h, " | ".join("%7.2f / %6.2f / %7.2f / %-17s" % (a, b, c, fmt_settle(d)) for a, b, c, d in cells),
                                " (the third: observer on, without the controller's record)" if "no record" in f else ""))
        out.append((f["on"][0], f["on"][1], f["on"][3]) + ((f["no record"][0], f["no record"][1]) if "no record" in f else ()))
    return out


# --- experiment 3: a second estimate after a window of W s ---------------------------------------------------------

def _lagged(model):
    return [j for j, (_, tau) in enumerate(model.terms) if tau > 0]


def _true_states(model, t, sig):
    """The lag states as the training defines them: the filters run through the run from its first sample."""
    return np.column_stack([obs._filter_from(t, sig[model.terms[j][0]], model.terms[j][1], sig[model.terms[j][0]][0])
                            for j in _lagged(model)])


def _instant(model, sig):
    """The observer's instantaneous estimate of every lag state at every sample (n, lag states)."""
    U = np.column_stack([sig[n] for n in obs.signals_of(model.terms)])
    cols = []
    for s in model.observer.states:
        v = U @ np.array([s["gains"].get(n, 0.0) for n in obs.signals_of(model.terms)])
        cols.append(np.maximum(v, 0.0) if s["signal"] in obs.NONNEGATIVE else v)
    return np.column_stack(cols)


def _window_regressors(model, t, sig, W, regressors, keep):
    """Rows k whose window starts at a sample k0 with t[k] - t[k0] = W (both kept): regressors X, true states Y."""
    names = obs.signals_of(model.terms)
    Y = _true_states(model, t, sig)
    k0 = np.searchsorted(t, t - W - 1e-6)
    dt = float(np.median(np.diff(t)))
    ok = np.abs((t - t[k0]) - W) < dt / 2
    k, k0 = np.flatnonzero(ok), k0[ok]
    both = keep[k] & keep[k0]
    k, k0 = k[both], k0[both]
    U = np.column_stack([sig[n] for n in names])
    cols = []
    if "u" in regressors:
        cols.append(U[k])
    if "d" in regressors:
        cols.append(U[k] - U[k0])
    if "y" in regressors:
        # the board's states at k, run from the instantaneous estimate at k0: the true ones minus the decayed start error
        taus = np.array([model.terms[j][1] for j in _lagged(model)])
        cols.append(Y[k] - np.exp(-(t[k] - t[k0])[:, None] / taus[None, :]) * (Y[k0] - _instant(model, sig)[k0]))
    if "h" in regressors:
        # helper filter (tau W/2) started at u(k0): the one run from the first sample minus its decayed difference from u(k0)
        H = np.column_stack([obs._filter_from(t, sig[n], W / 2, sig[n][0]) for n in names])
        cols.append(H[k] - np.exp(-(t[k] - t[k0]) / (W / 2))[:, None] * (H[k0] - U[k0]) - U[k])
    return np.column_stack(cols), Y[k]


def _window_regressors_at(model, tt, s, cols, kw, W, regressors):
    """The same regressors on a restarted board at its sample kw (tt, s from the reset; cols its term columns)."""
    names = obs.signals_of(model.terms)
    U, U0 = np.array([s[n][kw] for n in names]), np.array([s[n][0] for n in names])
    x = []
    if "u" in regressors:
        x.append(U)
    if "d" in regressors:
        x.append(U - U0)
    if "y" in regressors:
        x.append(cols[kw, _lagged(model)])
    if "h" in regressors:
        x.append(np.array([obs._filter_from(tt[:kw + 1], s[n][:kw + 1], W / 2, s[n][0])[-1] for n in names]) - U)
    return np.concatenate(x)


def fit_window(model, train, W, regressors):
    """Gains (regressors x lag states), E^W per state, and which states take the window estimate."""
    X, Y = [], []
    for run, (lo, hi) in train:
        t, sig = obs.inputs(model, run)
        Xr, Yr = _window_regressors(model, t, sig, W, regressors, (t >= lo) & (t <= hi))
        X.append(Xr)
        Y.append(Yr)
    X, Y = np.vstack(X), np.vstack(Y)
    if X.shape[0] <= X.shape[1]:
        raise SystemExit("window %g s: %d training rows for %d regressors (is W a multiple of the sample interval, and "
                         "shorter than the training runs?)" % (W, X.shape[0], X.shape[1]))
    gains = np.linalg.lstsq(X, Y, rcond=None)[0]  # no constant: a machine at rest (every regressor 0) stays at zero
    e_w = np.abs(Y - X @ gains).max(axis=0)
    e_0 = np.array([s["bound"] for s in model.observer.states])
    taus = np.array([model.terms[j][1] for j in _lagged(model)])
    return gains, e_w, e_w < e_0 * np.exp(-W / taus)


def bound_settle(model, bounds_before, bounds_after, W, scale):
    """Smallest time (s, 10 s grid) from which the start-error bound stays <= TOL_UM: B uses the instantaneous bounds
    before W and the window's after (each decaying from its own start)."""
    taus = np.array([model.terms[j][1] for j in _lagged(model)])
    b = np.abs(model.term_coefficients[_lagged(model)]) * scale
    grid = np.arange(0.0, 400 * 3600.0, 10.0)
    B = np.where(grid[:, None] < W, bounds_before[None, :] * np.exp(-grid[:, None] / taus),
                 bounds_after[None, :] * np.exp(-np.maximum(grid[:, None] - W, 0) / taus)) @ b
    over = np.flatnonzero(B > TOL_UM)
    return 0.0 if not over.size else (grid[over[-1] + 1] if over[-1] + 1 < grid.size else np.inf)


def restarted_columns(model, run, reset_s, start=None):
    """Time base, inputs and term columns of a board reset at reset_s with the observer's start (or ``start`` {term: y})."""
    t, sig = obs.inputs(model, run)
    r0 = int(np.searchsorted(t, reset_s))
    tt, s = t[r0:], {n: v[r0:] for n, v in sig.items()}
    est = model.observer.initial_states({n: s[n][0] for n in obs.signals_of(model.terms)})
    est.update(start or {})
    cols = np.column_stack([obs._filter_from(tt, s[n], tau, est.get(j, s[n][0])) for j, (n, tau) in enumerate(model.terms)])
    return r0, tt, s, cols


def window_restart(model, run, full, reset_s, W, gains, use, regressors, scale):
    """(max30, at30, settle, |offset step at t0+W|) of a board reset at reset_s with the window estimate."""
    r0, tt, s, cols = restarted_columns(model, run, reset_s)
    step = 0.0
    if W > 0:
        kw = int(np.searchsorted(tt, tt[0] + W - 1e-6))
        before = (model.intercept + cols[kw] @ model.term_coefficients) * scale
        yw = _window_regressors_at(model, tt, s, cols, kw, W, regressors) @ gains
        for q, j in enumerate(_lagged(model)):
            if use[q]:
                n, tau = model.terms[j]
                y0 = max(yw[q], 0.0) if n in obs.NONNEGATIVE else yw[q]
                cols[kw:, j] = obs._filter_from(tt[kw:], s[n][kw:], tau, y0)
        step = abs((model.intercept + cols[kw] @ model.term_coefficients) * scale - before)
    dev = np.abs((model.intercept + cols @ model.term_coefficients) * scale - full[r0:])
    max30, at30, _, settle = deviation_figures(tt - tt[0], dev)
    return max30, at30, settle, step


def print_windows(label, model, train, run, resets_h, scale, windows_min, regressor_sets):
    t, _ = obs.inputs(model, run)
    full = model.thermal_at(run, t) * scale
    e_0 = np.array([s["bound"] for s in model.observer.states])
    print("\n%s, window estimate: per W, settle_s (bound), E_j per lag state, resets within %g um at 30 min; per reset H "
          "(h): max30 / at30 / settle (min) / offset step at t0+W (um)" % (label, TOL_UM))
    print("  lag states: %s" % ", ".join("%s %g s" % model.terms[j] for j in _lagged(model)))
    for regressors in regressor_sets:
        for w_min in windows_min:
            W = 60.0 * w_min
            if W == 0:
                gains, e_w, use = None, e_0, np.zeros(e_0.size, dtype=bool)
            else:
                gains, e_w, use = fit_window(model, train, W, regressors)
            figs = [window_restart(model, run, full, h * 3600.0, W, gains, use, regressors, scale) for h in resets_h]
            settle = bound_settle(model, e_0, np.where(use, e_w, e_0 * np.exp(-W / np.array([model.terms[j][1] for j in _lagged(model)]))), W, scale)
            print("  %-5s W %2g min  settle_s %6s  E %-34s ok30 %d/%d | %s" % (
                regressors if W else "-", w_min, fmt_settle(settle).replace(" min", ""),
                " ".join("%.2f%s" % (e, "*" if u else "") for e, u in zip(np.where(use, e_w, e_0), use)),
                sum(f[1] <= TOL_UM for f in figs), len(figs),
                "  ".join("%g:%.1f/%.2f/%s/%.1f" % (h, a, b, "%.0f" % (c / 60) if np.isfinite(c) else "inf", d)
                          for h, (a, b, c, d) in zip(resets_h, figs))))
        windows_min = [w for w in windows_min if w != 0]  # W = 0 is the same for every regressor set: printed once


# --- experiment 4: the spindle lag states from the controller's history ---------------------------------------------

def _partial(t, Y, taus, H):
    """Each column of Y (lag states run from the first sample) as a filter started at rest H s before each sample
    (at the run's first sample where the run is shorter): Y(k) - e^(-H/tau) Y(k_H), exact for the recurrence; H = inf: Y."""
    if not np.isfinite(H):
        return Y
    kh = np.searchsorted(t, t - H - 1e-6)
    return Y - np.exp(-(t - t[kh])[:, None] / taus[None, :]) * Y[kh]


def print_spindle_history(label, model, train, run, resets_h, scale, histories_min):
    """S0: the spindle/feed lag states exact (their uninterrupted values), the others the observer's; S(H): every lag
    state re-estimated, without a constant, from the inputs and the spindle/feed lag states run from rest over the
    last H minutes before the reset (the controller's history of the speed), fitted on the training samples."""
    lagged = _lagged(model)
    spin = [q for q, j in enumerate(lagged) if model.terms[j][0] in obs.NONNEGATIVE]
    if not spin:
        print("\n%s: no spindle or feed lag state (the spindle history cannot help)" % label)
        return
    names = obs.signals_of(model.terms)
    taus = np.array([model.terms[j][1] for j in lagged])
    e_0 = np.array([s["bound"] for s in model.observer.states])
    t, sig = obs.inputs(model, run)
    full = model.thermal_at(run, t) * scale
    _, uninterrupted = obs.board_terms(model, [run])
    print("\n%s, spindle lag states from the controller's history at the reset: S0 exact, the others the observer's; "
          "S(H min) every state from the inputs and the spindle lag states over the last H min: settle_s (bound), E_j, "
          "resets within %g um at 30 min; per reset H (h): max30 / at30 / settle (min)" % (label, TOL_UM))
    for H in [None] + [60.0 * h for h in histories_min]:
        if H is None:
            e = e_0.copy()
            e[spin] = 0.0
        else:
            X, Y = [], []
            for r, (lo, hi) in train:
                tr, sr = obs.inputs(model, r)
                keep = (tr >= lo) & (tr <= hi)
                Yr = _true_states(model, tr, sr)
                P = _partial(tr, Yr, taus, H)
                X.append(np.column_stack([np.column_stack([sr[n] for n in names]), P[:, spin]])[keep])
                Y.append(Yr[keep])
            X, Y = np.vstack(X), np.vstack(Y)
            gains = np.linalg.lstsq(X, Y, rcond=None)[0]  # no constant (as the observer)
            e = np.abs(Y - X @ gains).max(axis=0)
            U = uninterrupted[:, lagged]
            P_run = _partial(t, U, taus, H)
        figs = []
        for h in resets_h:
            r0 = int(np.searchsorted(t, h * 3600.0))
            if H is None:
                start = {lagged[q]: uninterrupted[r0, lagged[q]] for q in spin}
            else:
                est = np.concatenate([[sig[n][r0] for n in names], P_run[r0, spin]]) @ gains
                start = {j: (max(v, 0.0) if q in spin else v) for q, (j, v) in enumerate(zip(lagged, est))}
            r0, tt, _, cols = restarted_columns(model, run, h * 3600.0, start)
            dev = np.abs((model.intercept + cols @ model.term_coefficients) * scale - full[r0:])
            figs.append(deviation_figures(tt - tt[0], dev))
        print("  %-9s settle_s %6s  E %-34s ok30 %d/%d | %s" % (
            "S0" if H is None else "S(%g)" % (H / 60), fmt_settle(bound_settle(model, e, e, 0.0, scale)).replace(" min", ""),
            " ".join("%.2f" % v for v in e), sum(f[1] <= TOL_UM for f in figs), len(figs),
            "  ".join("%g:%.1f/%.2f/%s" % (h, a, b, "%.0f" % (d / 60) if np.isfinite(d) else "inf") for h, (a, b, _, d) in zip(resets_h, figs))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channels", default="ch1,ch2,ch3,ch4,ch5")
    ap.add_argument("--no-twin", action="store_true")
    ap.add_argument("--split-h", type=float, default=SPLIT_H, help="FL_THERMAL's training/held-out split (h; default the 5th cycle's start)")
    ap.add_argument("--no-split", action="store_true", help="skip sections 1-2 (the split ratios and observer on/off resets)")
    ap.add_argument("--windows", default=None, help="experiment 3: window lengths in minutes, e.g. 0,5,10,20,30")
    ap.add_argument("--window-regressors", default="ud,udy,udh,udhy", help="experiment 3: regressor sets (letters %s)" % REGRESSORS)
    ap.add_argument("--spindle-history", default=None, help="experiment 4: history lengths in minutes, e.g. 30,60,120,inf")
    ap.add_argument("--warm", action="store_true", help="also the short cuts with the lag states restored (lags.bin)")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="a dynamic setting (JSON value) for every model fitted, e.g. settle_max_s=1800")
    args = ap.parse_args()
    opts = parse_options(args.option)  # JSON values or words, any key: fit_model's own settings (host/options.py)
    def minutes(text, flag, positive):
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            ap.error("%s: comma-separated minutes, found %r" % (flag, text))
        if any(np.isnan(v) or v < 0 or (positive and v == 0) or (flag == "--windows" and not np.isfinite(v)) for v in vals):
            ap.error("%s: each length must be %s minutes, found %r" % (flag, "> 0" if positive else "finite >= 0", text))
        return vals

    windows = minutes(args.windows, "--windows", False) if args.windows else []
    regressor_sets = args.window_regressors.split(",")
    histories = minutes(args.spindle_history, "--spindle-history", True) if args.spindle_history else None
    for r in regressor_sets:
        if not r or set(r) - set(REGRESSORS):
            ap.error("--window-regressors: each set is letters of %s, found %r" % (REGRESSORS, r))
    t0 = time.perf_counter()
    run = load_run(os.path.join(ROOT, "data", "fl_thermal"))
    split = args.split_h * 3600.0
    held = slice_run(run, split)
    before = slice_run(run, 0.0, split)
    models = {}
    if not args.no_split:
        print("FL_THERMAL, fit t < %.2f h (tcomp fit defaults), held out t >= %.2f h: RMSE um (ratio to MLR-16)" % (args.split_h, args.split_h))
        print("%4s %8s | %-22s | %-22s | %-22s | %s" % ("ch", "MLR-16", "switched on, observer", "switched on, no observer",
                                                      "filters from 0 h", "sensors"))
    for ch in args.channels.split(","):
        dyn = fit_model([run], "dynamic", target="direct", channel=ch, window=(None, split), **opts)
        models[ch] = dyn
        if not args.no_split:
            mlr = fit_model([run], "mlr", target="direct", channel=ch, window=(None, split))
            m = rmse(mlr, held, ch)
            cells = [rmse(dyn, held, ch), rmse(without_observer(dyn), held, ch), rmse(dyn, held, ch, history=before)]
            print("%4s %8.2f | %s | %s" % (ch, m, " | ".join("%8.2f (%5.2f)%7s" % (c, c / m, "") for c in cells), ",".join(dyn.sensors)))
    cases = []  # (label, model, training runs with spans, test run, resets, scale)
    for ch, dyn in models.items():
        cases.append(("FL_THERMAL %s (model fitted on t < %.2f h)" % (ch, args.split_h), dyn, [(run, (0.0, split))], run, FL_RESETS_H, 1.0))
    if not args.no_twin:
        from host.twin import simulate_run

        train = [simulate_run(p, seed=s) for s, p in enumerate(("v8000_r210_490", "mixed", "random", "v15000_r210_490"))]
        day = simulate_run("day24h", seed=7)
        dyn = fit_model(train, "dynamic", target="slope", **opts)
        scale = float(max(np.nanmax(np.abs(r.errors.position_mm)) for r in train))
        print("\ntwin: slope model fitted on 4 cold-start 5 h runs (v8000_r210_490, mixed, random, v15000_r210_490), sensors %s;"
              " tested on day24h (seed 7); deviation at %.0f mm" % (",".join(dyn.sensors), scale))
        cases.append(("twin day24h", dyn, [(r, (-np.inf, np.inf)) for r in train], day, TWIN_RESETS_H, scale))
    summary = []  # (label, settle_s, [(max30, at30, settle)])
    for label, model, train, test, resets, scale in cases:
        if not args.no_split:
            summary.append((label, model.observer.settle_s, print_restarts(label, model, test, resets, scale)))
        if windows:
            print_windows(label, model, train, test, resets, scale, windows, regressor_sets)
        if histories is not None:
            print_spindle_history(label, model, train, test, resets, scale, histories)
        if args.warm:
            print_warm(label, model, test, resets, scale)
    if args.warm:
        print_rule_sweep(list(models.values()), run)
    if summary:
        print("\nobserver on, dynamic settings %s: resets within %g um at 30 min / largest deviation in the first 30 min (um) / "
              "median settle (min) / SETTLING (min)" % (opts or "tcomp fit defaults", TOL_UM))
        for label, settle_s, figs in summary:
            print("%-50s %d of %d / %6.2f / %6.0f / %6.0f" % (label, sum(f[1] <= TOL_UM for f in figs), len(figs), max(f[0] for f in figs),
                                                      np.median([f[2] for f in figs]) / 60, settle_s / 60))
        fl = [f for label, _, figs in summary if label.startswith("FL_THERMAL") for f in figs]
        print("FL_THERMAL: %d of %d resets within %g um at 30 min" % (sum(f[1] <= TOL_UM for f in fl), len(fl), TOL_UM))
        without = [f for f in fl if len(f) > 3]
        if without:
            print("FL_THERMAL, the models' boards without the controller's record: %d of %d resets within %g um at 30 min, largest "
                  "deviation in the first 30 min %.2f um" % (sum(f[4] <= TOL_UM for f in without), len(without), TOL_UM,
                                                             max(f[3] for f in without)))
    print("\n(%.0f s)" % (time.perf_counter() - t0))


if __name__ == "__main__":
    main()
