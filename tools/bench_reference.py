"""Error reference (issue 19): parameter bias of the default screw structure, and false discoveries on null data.

1. alpha and q identified by ScrewModel on effect-free twin runs, under each error reference, with the default
   structure before issue 19 (E_e on: ambient=True) and after (ambient="auto", E_e off under both references),
   and the default with the air sensor's lag (air_lag_s = the twin's T3 time constant, 150 s: what its datasheet
   would say; host/learning/screw/screwmodel.py delagged).
   Truth: the twin's q = friction_J_per_mm * screw_share = 0.12 * 0.35 J/mm, alpha = 11.5e-6 /K.
2. The discrepancy workflow (the declaration check, then the catalog search, as `tcomp discrepancy` runs them)
   on effect-free runs of three moving states, declared as made: how many seeds get an effect named or a
   reference suggested (both are false discoveries on these runs).

The "named first / both of a pair / null" figures under each reference are tools/bench_discrepancy.py's
(--references).

    python tools/bench_reference.py [--seeds N] [--jobs J] [--bias-only]
"""
import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.learning.discrepancy import reference, workflow
from host.learning.discrepancy.family import ScrewFamily
from host.learning.screw.screwmodel import ScrewModel
from host.twin import simulate_run

Q_TRUE, ALPHA_TRUE = 0.12 * 0.35, 11.5e-6
FIT = "v8000_r210_490"
AIR_LAG_S = 150.0  # the twin's air sensor T3: host/twin/structure.py sensor_s (sensor_tau_scale 1)
STRUCTURES = (("before: E_e on", {"ambient": True}), ("after: default (E_e off)", {"ambient": "auto"}),
              ("default + air_lag_s=%g" % AIR_LAG_S, {"ambient": "auto", "air_lag_s": AIR_LAG_S}))
STATES = ("v8000_r210_490", "v6500_r210_490", "v8000_r0_700")
REFERENCES = ("start", "T3")


def bias(seeds):
    print("1. parameter bias on effect-free runs (%s, seeds %s, noise 0.5 um; q, h, lambda and alpha free in both structures), "
          "mean [min, max] over seeds:" % (FIT, list(seeds)))
    print("   %-6s %-26s %-28s %-28s" % ("ref", "structure", "alpha bias %", "q bias %"))
    for ref in REFERENCES:
        runs = [simulate_run(FIT, seed=s, error_reference=ref) for s in seeds]
        for label, kw in STRUCTURES:
            a, q = [], []
            for r in runs:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = ScrewModel(free="q,h,lambda,alpha", **kw).fit([r], reduce=False)
                a.append(100 * (m.values_["alpha_per_K"] / ALPHA_TRUE - 1))
                q.append(100 * (m.values_["q_J_per_mm"] / Q_TRUE - 1))
            print("   %-6s %-26s %+7.1f [%+6.1f, %+6.1f]        %+7.1f [%+6.1f, %+6.1f]"
                  % (ref, label, np.mean(a), min(a), max(a), np.mean(q), min(q), max(q)), flush=True)


def false_discoveries(seeds, jobs):
    print("2. false discoveries on null runs (%s; declared as made), per seed:" % ", ".join(STATES))
    for ref in REFERENCES:
        named = suggested = 0
        worst = 0.0
        for s in seeds:
            runs = [simulate_run(p, seed=100 + s, error_reference=ref) for p in STATES]
            check = reference.check_declaration(runs, lambda r: ScrewFamily(error_reference=r), jobs=jobs)
            res = workflow.discover(runs, ScrewFamily(), candidates=[] if check["suggested"] else None, jobs=jobs)
            named += bool(res.effects)
            suggested += check["suggested"] is not None
            worst = max(worst, res.before.rmse())
            print("   %-5s seed %3d: base held-out RMSE %.3f um (%.2f x noise), effects named: %s, suggestion: %s"
                  % (ref, 100 + s, res.before.rmse(), res.before.rmse() / 0.5, ",".join(res.effects) or "none",
                     check["suggested"] or "none"), flush=True)
        print("   %-5s: effects named on %d of %d seeds, a reference suggested on %d of %d; worst base RMSE %.2f x noise"
              % (ref, named, len(seeds), suggested, len(seeds), worst / 0.5))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--bias-only", action="store_true", help="part 1 only")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    bias(range(1, args.seeds + 1))
    if not args.bias_only:
        false_discoveries(range(args.seeds), args.jobs)
    print("(%.0f s)" % (time.perf_counter() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
