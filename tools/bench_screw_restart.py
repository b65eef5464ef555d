"""Figures of the screw model's board restarted on a warm machine, observer on vs off (issue 21), reduced recurrence
in floats (host/learning/screw/observer.py) from the host's start and from the board's: the exported table's integer
start (firmware/evaluate.py Evaluator.estimate under CPython, on the sensors' readings in whole milli-degC and the
references the board latched at the run's cold start), the form table format 6 carries.

The model: `tcomp fit --model screw` defaults on four bundled twin runs (data/demo: v8000_r210_490, v8000_r0_210,
v15000_r210_490, v8000_r0_700). Resets on runs it did not see, all from the independent twin (host/twin): the bundled
mixed and v6500_r210_490 runs, and a twin 24 h day (protocol day24h, seed --seed). For each reset: the largest
deviation of the restarted board's E_m from the uninterrupted board's over 21 positions of the stroke in the first
30 min and at 30 min, and the settle time (from when on it stays within 1 um), observer on vs off (cold start: the
state in equilibrium with the air, what the board does without a trusted heat.bin); the document's bounds; and
what fitting the observer adds to ScrewModel.fit. The board's column runs the host's float recurrence from the board's
integer start (the recurrence's own integer error is the export certificate's, printed).

Usage: OPENBLAS_NUM_THREADS=1 .venv/bin/python tools/bench_screw_restart.py [--seed 5]
"""
import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.data.runs import load_run
from host.learning.screw import observer as so
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel
from host.twin import simulate_run

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRAIN = ("v8000_r210_490", "v8000_r0_210", "v15000_r210_490", "v8000_r0_700")
DEMO_RESETS_S = (1800, 3600, 5400, 7200, 10800)
DAY_RESETS_H = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0)
TOL_UM = so.SETTLE_TOLERANCE_UM


def settle_s(elapsed, dev):
    """From when on the deviation stays within TOL_UM (inf: not within the run)."""
    bad = np.flatnonzero(dev > TOL_UM)
    if bad.size == 0:
        return 0.0
    return float(elapsed[bad[-1] + 1]) if bad[-1] + 1 < elapsed.size else float("inf")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=5, help="seed of the twin's 24 h day")
    a = ap.parse_args()
    t0 = time.time()
    runs = [load_run(os.path.join(ROOT, "data", "demo", n)) for n in TRAIN]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        m = ScrewModel().fit(runs)
    obs = m.observer_
    print(m.observer_note_)
    if obs is None:
        return 1
    print("fit + observer %.1f s; document: start error bound %.2f um (cold %.2f), settle_s %.0f s (cold %.0f s)"
          % (time.time() - t0, obs.start_error_um, obs.cold_start_error_um, obs.settle_s, obs.cold_settle_s))
    cost = []
    for _ in range(3):  # the observer's share of ScrewModel.fit (fit_observer alone; best of 3)
        t1 = time.perf_counter()
        so.fit_observer(m, runs)
        cost.append(time.perf_counter() - t1)
    print("fit_observer on the %d training runs: %.3f s (best of 3)" % (len(runs), min(cost)))
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    from models_export.export import export_model
    ex = export_model(m.to_document())
    cert = ex.report["screw"]["observer"]
    assert cert["carried"], cert
    table = parse_table(ex.table)
    print("table: format %d, %d bytes, sensors %s; integer start vs host estimate <= %.2g K per segment, %.2g um of offset "
          "(certified); state error bound %.2g K" % (table.version, len(ex.table), ",".join(table.sensors),
                                                     cert["certificate"]["start_error_K"], cert["certificate"]["start_error_um"],
                                                     ex.report["screw"]["state_error_bound_K"]))

    def board_start(run):
        """The board's start at a step time of ``run``: references latched at the run's first sample (its cold start)."""
        tt = run.temperatures
        cols = [tt.column(s) for s in table.sensors]

        def at(t_s):
            ev = Evaluator(table)
            ev.temps[:] = [int(round(float(c[0]) * 1000)) for c in cols]
            if table.ref_mode == 1:
                ev.latch_references()
            ev.temps[:] = [int(round(float(np.interp(t_s, tt.time_s, c)) * 1000)) for c in cols]
            ev.update()
            ev.estimate()
            return np.asarray(ev.T, dtype=float) / (1 << table.ft)
        return at

    print("gains K/K per segment: " + " ".join("%.3f" % g for g in obs.gains))
    print("residual bound K:      " + " ".join("%.2f" % b for b in obs.bound))
    cases = [(load_run(os.path.join(ROOT, "data", "demo", n)), n, DEMO_RESETS_S) for n in ("mixed", "v6500_r210_490")]
    day = simulate_run("day24h", seed=a.seed)
    cases.append((day, "day24h seed %d" % a.seed, tuple(int(h * 3600) for h in DAY_RESETS_H)))
    print()
    print("| run | reset at | observer (host): max 30 min / at 30 min [um], settle | board's integer start: same | "
          "cold start: same |")
    print("|---|---|---|---|---|")
    worst = {"obs": 0.0, "board": 0.0, "cold": 0.0}
    for run, name, resets in cases:
        start = board_start(run)
        for t_r in resets:
            cells = []
            for key, o, s0 in (("obs", obs, None), ("board", None, start), ("cold", None, None)):
                el, dev = so.restart_deviation_um(m, run, t_r, o, start_K=s0)
                first = el <= 1800
                at30 = float(dev[np.searchsorted(el, 1800)]) if el[-1] >= 1800 else float("nan")
                worst[key] = max(worst[key], float(dev[first].max()))
                st = settle_s(el, dev)
                cells.append("%.2f / %.2f, %s" % (dev[first].max(), at30, "%.0f min" % (st / 60) if np.isfinite(st)
                                                  else "> %.0f min (run ends)" % (el[-1] / 60)))
            print("| %s | %.1f h | %s | %s | %s |" % (name, t_r / 3600, cells[0], cells[1], cells[2]))
    print()
    print("largest deviation in the first 30 min over all resets: observer %.2f um (the board's integer start %.2f um), "
          "cold start %.2f um" % (worst["obs"], worst["board"], worst["cold"]))
    print("total %.1f s" % (time.time() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
