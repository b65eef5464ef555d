"""Figures of a dynamic model's board restarted on a warm machine, observer on vs off (issue 21), host model in floats.

1. FL_THERMAL (data/fl_thermal), every channel: `tcomp fit` defaults (dynamic, direct) on t < SPLIT_H, and MLR-16
   (all sensors, fixed reference) on the same span. Held-out RMSE on t >= SPLIT_H and its ratio to MLR-16's for the
   dynamic model with the board switched on at the split (observer), the same without observer (filters from rest,
   rises over the split: the behaviour before issue 21), and with the filters running since 0 h (`--history`).
2. Restarts: the same models, board reset at several points of FL_THERMAL, and a twin-trained slope model reset at
   several points of the twin's 24 h day; the deviation of the restarted board's offset from the uninterrupted board
   (at the largest training position for a slope model): largest in the first 30 min and overall, at 30 min, and the
   settle time (from when on it stays within 1 um), observer on vs off; and the observer's SETTLING time (settle_s).
3. Warm restarts (``--warm``, docs/firmware.md "Warm restarts of the lag states"): the same resets as a short cut
   (back within seconds), the lag states restored from lags.bin when the firmware's rule trusts them (every model
   sensor within 0.25 K of its reading at the write, and the observer's estimate moved less than 1 um of offset),
   the observer's start otherwise. The stored state is the last periodic write, AGE_S old: 0 s (a cut right after a
   write, or an X reset, which writes first) and 600 s (a cut just before the next write, the oldest it can be).
   Per reset: warm state (age 0) / warm state (age 600 s) / observer only / neither, each as the largest deviation
   and the settle time; "obs" marks a warm restart that refused the record and started from the observer.
   Then the rule's sweep: a record CUTS_S old (a cut of that length, or a shorter one after an older write) at a
   reset every 2 h of FL_THERMAL, all channels pooled: for each pair of limits (sensor K, observer um), the share of
   records trusted and the mean / largest deviation of the board that applies it, beside restore-always and
   observer-only. The firmware's limits are the row marked "*".

Usage: .venv/bin/python tools/bench_restart.py [--channels ch1,ch4] [--no-twin] [--warm]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.data.runs import load_run, slice_run
from host.learning.empirical.fitting import fit_model

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPLIT_H = 32.13  # start of FL_THERMAL's 5th spindle cycle (docs/results.md)
FL_RESETS_H = (4.0, 12.0, 20.0, 28.0, 36.0, 44.0)
TWIN_RESETS_H = (2.0, 6.0, 10.0, 14.0, 18.0)
TOL_UM = 1.0
WINDOW_S = 1800.0


def without_observer(model):
    """The same terms with filters from rest and rises over the run's start (a document without thermal.observer)."""
    doc = model.to_document()
    doc["thermal"] = {k: v for k, v in doc["thermal"].items() if k != "observer"}
    doc["thermal"]["reference"] = "run_start"
    return type(model).from_document(doc)


def rmse(model, run, ch, **kw):
    rows = np.flatnonzero(run.errors.channel == ch) if run.errors.channel is not None else np.arange(len(run.errors))
    r = run.errors.error_um[rows] - model.predict(run, **kw)[rows]
    return float(np.sqrt(np.mean(r**2)))


def restart_figures(model, run, reset_s, scale):
    """Deviation (um) of a board reset at reset_s from the uninterrupted one, observer on and off."""
    t = run.temperatures.time_s
    times = t[t >= reset_s]
    warm = slice_run(run, reset_s)
    full = model.thermal_at(run, times) * scale
    out = {}
    for name, m in (("on", model), ("off", without_observer(model))):
        dev = np.abs(m.thermal_at(warm, times) * scale - full)
        el = times - times[0]
        over = np.flatnonzero(dev > TOL_UM)
        settle = 0.0 if not over.size else (el[over[-1] + 1] if over[-1] + 1 < el.size else np.inf)
        first = el <= WINDOW_S
        out[name] = (dev[first].max(), float(np.interp(WINDOW_S, el, dev)) if el[-1] >= WINDOW_S else np.nan, dev.max(), settle)
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
    print("\n%s: board reset at hour H vs the uninterrupted board (um of offset); SETTLING time of the observer %.0f min"
          % (label, model.observer.settle_s / 60))
    print("%6s | %-44s | %-44s" % ("H", "observer on: max30 / at30 / max / settle", "observer off: max30 / at30 / max / settle"))
    for h in resets_h:
        f = restart_figures(model, run, h * 3600.0, scale)
        print("%6.1f | %s | %s" % (h, *("%7.2f / %6.2f / %7.2f / %-17s" % (a, b, c, fmt_settle(d)) for a, b, c, d in (f["on"], f["off"]))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channels", default="ch1,ch2,ch3,ch4,ch5")
    ap.add_argument("--no-twin", action="store_true")
    ap.add_argument("--warm", action="store_true", help="also the short cuts with the lag states restored (lags.bin)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    run = load_run(os.path.join(ROOT, "data", "fl_thermal"))
    split = SPLIT_H * 3600.0
    held = slice_run(run, split)
    before = slice_run(run, 0.0, split)
    models = {}
    print("FL_THERMAL, fit t < %.2f h (tcomp fit defaults), held out t >= %.2f h: RMSE um (ratio to MLR-16)" % (SPLIT_H, SPLIT_H))
    print("%4s %8s | %-22s | %-22s | %-22s | %s" % ("ch", "MLR-16", "switched on, observer", "switched on, no observer",
                                                  "filters from 0 h", "sensors"))
    for ch in args.channels.split(","):
        dyn = fit_model([run], "dynamic", target="direct", channel=ch, window=(None, split))
        mlr = fit_model([run], "mlr", target="direct", channel=ch, window=(None, split))
        models[ch] = dyn
        m = rmse(mlr, held, ch)
        cells = [rmse(dyn, held, ch), rmse(without_observer(dyn), held, ch), rmse(dyn, held, ch, history=before)]
        print("%4s %8.2f | %s | %s" % (ch, m, " | ".join("%8.2f (%5.2f)%7s" % (c, c / m, "") for c in cells), ",".join(dyn.sensors)))
    for ch, dyn in models.items():
        print_restarts("FL_THERMAL %s (model fitted on t < %.2f h)" % (ch, SPLIT_H), dyn, run, FL_RESETS_H, 1.0)
        if args.warm:
            print_warm("FL_THERMAL %s" % ch, dyn, run, FL_RESETS_H, 1.0)
    if args.warm:
        print_rule_sweep(list(models.values()), run)
    if not args.no_twin:
        from host.twin import simulate_run

        train = [simulate_run(p, seed=s) for s, p in enumerate(("v8000_r210_490", "mixed", "random", "v15000_r210_490"))]
        day = simulate_run("day24h", seed=7)
        dyn = fit_model(train, "dynamic", target="slope")
        scale = float(max(np.nanmax(np.abs(r.errors.position_mm)) for r in train))
        print("\ntwin: slope model fitted on 4 cold-start 5 h runs (v8000_r210_490, mixed, random, v15000_r210_490), sensors %s;"
              " tested on day24h (seed 7); deviation at %.0f mm" % (",".join(dyn.sensors), scale))
        print_restarts("twin day24h", dyn, day, TWIN_RESETS_H, scale)
        if args.warm:
            print_warm("twin day24h", dyn, day, TWIN_RESETS_H, scale)
    print("\n(%.0f s)" % (time.perf_counter() - t0))


if __name__ == "__main__":
    main()
