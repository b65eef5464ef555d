"""The identified screw model on runs of the independent twin: held-out RMSE with and without the air term,
what each twin extra costs the model, and the screw model against MLR on random moving states.

Usage: .venv/bin/python tools/bench_sim_model.py [--seeds 1,2,3] [--noise 0.5,0.3]
Figures quoted in docs/twin.md ("The identified screw model on twin data").
"""
import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.learning.empirical.fitting import fit_model
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel
from host.twin import LITERATURE_STATES, STILL_AIR, simulate_run

FIT = "v8000_r210_490"
HELD_OUT = ("v6500_r210_490", "v15000_r210_490", "v8000_r0_210", "v8000_r0_700", "mixed", "random")
EXTRAS = {
    "full twin": {},
    "point nut": {"nut_length_mm": 0.0},
    "no sweep heat": {"sweep_trips": 0.0},
    "ideal sensors": {"sensor_tau_scale": 0.0},
    "all three off": {"nut_length_mm": 0.0, "sweep_trips": 0.0, "sensor_tau_scale": 0.0},
    "still air": STILL_AIR,
}


def _fit(runs, **settings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return ScrewModel(**dict({"ambient": True}, **settings)).fit(runs)  # the runs hold ambient_expansion: E_e on


def _rmse(model, runs):
    return float(np.sqrt(np.mean(np.concatenate([model.predict(r) - r.errors.error_um for r in runs]) ** 2)))


def _runs(seed, noise, **over):
    return {p: simulate_run(p, ["ambient_expansion"], seed=seed, noise_um=noise, **over) for p in (FIT,) + HELD_OUT}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--noise", default="0.5,0.3")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    noises = [float(s) for s in args.noise.split(",")]

    print("held-out RMSE / laser noise, fitted on %s, held out: %s" % (FIT, ", ".join(HELD_OUT)))
    print("%4s %6s %14s %10s %14s %10s %8s" % ("seed", "noise", "air pooled", "worst", "no-air pooled", "worst", "fit s"))
    for seed in seeds:
        for noise in noises:
            runs = _runs(seed, noise)
            row = []
            t0 = time.perf_counter()
            for air in ("auto", "off"):
                m = _fit([runs[FIT]], air=air)
                row += [_rmse(m, [runs[p] for p in HELD_OUT]) / noise, max(_rmse(m, [runs[p]]) for p in HELD_OUT) / noise]
            print("%4d %6.2f %14.2f %10.2f %14.2f %10.2f %8.1f" % (seed, noise, *row, (time.perf_counter() - t0) / 2))

    print("\nnoise-free: held-out RMSE (um) of the same fit, twin extras switched off one at a time")
    print("%4s %-15s %8s %8s" % ("seed", "twin", "mean", "worst"))
    for seed in seeds:
        for label, over in EXTRAS.items():
            runs = _runs(seed, 0.0, **over)
            m = _fit([runs[FIT]])
            r = [_rmse(m, [runs[p]]) for p in HELD_OUT]
            print("%4d %-15s %8.2f %8.2f" % (seed, label, np.mean(r), np.max(r)))

    print("\nrandom moving states (3 runs per seed, 0.5 um noise): RMSE um")
    print("%4s %-18s %8s %8s" % ("seed", "trained on", "screw", "mlr"))
    for train_set in ((FIT,), LITERATURE_STATES):
        for seed in seeds:
            train = [simulate_run(p, ["ambient_expansion"], seed=seed) for p in train_set]
            test = [simulate_run("random", ["ambient_expansion"], seed=100 + seed + k) for k in range(3)]
            screw = _rmse(_fit(train), test)
            mlr = _rmse(fit_model(train, "mlr", reference="run_start"), test)
            print("%4d %-18s %8.2f %8.2f" % (seed, FIT if len(train_set) == 1 else "5 literature states", screw, mlr))


if __name__ == "__main__":
    main()
