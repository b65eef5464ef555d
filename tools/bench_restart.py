"""Figures of a dynamic model's board restarted on a warm machine, observer on vs off (issue 21), host model in floats.

1. FL_THERMAL (data/fl_thermal), every channel: `tcomp fit` defaults (dynamic, direct) on t < SPLIT_H, and MLR-16
   (all sensors, fixed reference) on the same span. Held-out RMSE on t >= SPLIT_H and its ratio to MLR-16's for the
   dynamic model with the board switched on at the split (observer), the same without observer (filters from rest,
   rises over the split: the behaviour before issue 21), and with the filters running since 0 h (`--history`).
2. Restarts: the same models, board reset at several points of FL_THERMAL, and a twin-trained slope model reset at
   several points of the twin's 24 h day; the deviation of the restarted board's offset from the uninterrupted board
   (at the largest training position for a slope model): largest in the first 30 min and overall, at 30 min, and the
   settle time (from when on it stays within 1 um), observer on vs off; and the observer's SETTLING time (settle_s).

Usage: .venv/bin/python tools/bench_restart.py [--channels ch1,ch4] [--no-twin]
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
    if not args.no_twin:
        from host.twin import simulate_run

        train = [simulate_run(p, seed=s) for s, p in enumerate(("v8000_r210_490", "mixed", "random", "v15000_r210_490"))]
        day = simulate_run("day24h", seed=7)
        dyn = fit_model(train, "dynamic", target="slope")
        scale = float(max(np.nanmax(np.abs(r.errors.position_mm)) for r in train))
        print("\ntwin: slope model fitted on 4 cold-start 5 h runs (v8000_r210_490, mixed, random, v15000_r210_490), sensors %s;"
              " tested on day24h (seed 7); deviation at %.0f mm" % (",".join(dyn.sensors), scale))
        print_restarts("twin day24h", dyn, day, TWIN_RESETS_H, scale)
    print("\n(%.0f s)" % (time.perf_counter() - t0))


if __name__ == "__main__":
    main()
