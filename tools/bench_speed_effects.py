"""Reduction error of the speed effects' firmware forms (table format 5, issue 19; docs/screw-model.md).

For speed_dependent_heat and moving_convection: the screw model with the effect, fitted on three runs of the
independent twin with the effect hidden at its default (v6500_r210_490, v15000_r210_490, mixed; seed 7, laser
noise 0.5 um), and its reduced form against the full model on each run (host/learning/screw/reduced.py
reduction_certificate): "before" with the effect's reduced fields removed (what the table carried up to format 4:
the effect left out), "after" with them. RMS / max in um, E_m on 21 positions at every reduced step; the rows'
figures are the whole output at the error rows; the feed/range column feeds the reduced model from the feed state.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python tools/bench_speed_effects.py
"""
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.learning.screw.effects import make_effect
from host.learning.screw.reduced import reduction_certificate
from host.learning.screw.screwmodel import ScrewModel
from host.twin import EFFECTS as TWIN_EFFECTS
from host.twin import simulate_run

RUNS = ("v6500_r210_490", "v15000_r210_490", "mixed")
SPEED_FIELDS = ("heat_scale0", "heat_scale_per_mm", "convection_per_mm")


def main():
    print("| effect | run | before: RMS / max [um] | after: RMS / max [um] | after, error rows: RMS / max | after, feed/range RMS |")
    print("|---|---|---|---|---|---|")
    for name in ("speed_dependent_heat", "moving_convection"):
        t0 = time.perf_counter()
        runs = [simulate_run(p, effects={name: TWIN_EFFECTS[name].default}, seed=7, noise_um=0.5) for p in RUNS]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = ScrewModel(segments=20, dt_s=20.0, ambient=False, effects=[make_effect(name)]).fit(runs)
        red = model.reduced_
        after = red["reduction_error_um"]
        kept = {k: red.pop(k) for k in SPEED_FIELDS if k in red}
        before = reduction_certificate(model, runs)
        red.update(kept)
        k = {n: round(v, 4) for n, v in model.values_.items() if "." in n}
        for r in runs:
            a, b = after[r.path or r.name], before[r.path or r.name]
            print("| %s %s | %s | %.3f / %.3f | %.3f / %.3f | %.3f / %.3f | %.3f |" % (
                name, k, r.name, b["rms_um"], b["max_um"], a["rms_um"], a["max_um"], a["rows_rms_um"], a["rows_max_um"],
                a["feed_range"]["rms_um"]), flush=True)
        print("(%s: omitted %s, %.0f s)" % (name, red.get("omitted_effects") or "none", time.perf_counter() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
