"""Benchmarks of the screw model (host/learning/screw): prints figures, asserts nothing.

    .venv/bin/python tools/bench_screw.py [--runs DIR...]

1. simulation speed in segment-steps per second (modal path: fixed dt and
   convection; grouped path: per-step convection multiplier);
2. identification wall time on three bundled runs fitted together (budget: < 20 s
   on a 2-core machine) and on each alone;
3. reduction error of the firmware recurrence against the full model on every
   bundled run (RMS and max of E over the stroke, µm);
4. held-out RMSE on twin runs of the literature states 1, 2, 3, 5 in a drifting air
   (leave-one-run-out, no hidden effect, three seeds), over the laser noise: the
   model with the air term (budget <= 1.25) and without it.
"""
import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.data.runs import Motion, load_run
from host.learning.screw import heat
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel
from host.learning.screw.reduced import reduction_error

DEMO = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "demo")
THREE = ("v8000_r210_490", "v6500_r210_490", "v8000_r0_700")


def bench_simulation():
    motion = Motion(np.array([0.0]), np.array([4 * 3600.0]), np.array([210.0]), np.array([490.0]), np.array([8000.0]))
    par = heat.ScrewParams()
    print("simulation (8 h at dt = 10 s, 2880 steps):")
    for M in (12, 40, 80, 160):
        geo = heat.ScrewGeometry(800.0, 32.0, 0.0, M)
        t = np.arange(0.0, 8 * 3600.0 + 1, 10.0)
        q = heat.friction_heat_J(heat.nut_travel_per_segment(motion, geo.edges_mm, 0.0, t), par)
        g = np.where(np.arange(t.size - 1) % 2 == 0, 1.0, 1.5)
        for label, kw in (("modal", {}), ("per-step convection", {"convection_mult": g})):
            reps = 0
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < 0.5:
                heat.simulate_segments(geo, par, t, q, **kw)
                reps += 1
            dt = (time.perf_counter() - t0) / reps
            print("  M = %3d  %-20s %7.2f ms/run  %6.2f M segment-steps/s" % (M, label, 1e3 * dt, M * (t.size - 1) / dt / 1e6))


def bench_identification(runs):
    print("identification (ScrewModel defaults: 40 segments, dt 10 s, free q, h, lambda (+alpha)):")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        for r in runs:
            t0 = time.perf_counter()
            m = ScrewModel(ambient=True).fit([r])  # the bundled runs hold the frame drift E_e stands for
            print("  %-18s %6.2f s  (%d evaluations, RMSE %.3f um)" % (r.name, time.perf_counter() - t0, m.statistics_["nfev"], m.statistics_["rmse_um"]))
        t0 = time.perf_counter()
        m = ScrewModel(ambient=True).fit(runs)
        wall = time.perf_counter() - t0
    print("  all %d together    %6.2f s  (%d evaluations, RMSE %.3f um; budget 20 s)" % (len(runs), wall, m.statistics_["nfev"], m.statistics_["rmse_um"]))
    for k, p in m.statistics_["parameters"].items():
        print("    %-14s %11.5g ± %.2g%s" % (k, p["value"], p["std"], " (fixed)" if p.get("fixed") else ""))
    return m


def bench_reduction(model, runs):
    red = model.reduced_
    print("reduced model (%d segments, dt %g s) vs full (%d segments, dt %g s), E over the stroke at every reduced step:"
          % (red["segments"], red["dt_s"], model.geometry_.segments, model.dt_s))
    for spread, label in ((False, "travel from position reports (exact reciprocation)"), (True, "travel from the feed/range state (spread)")):
        print("  %s:" % label)
        allrms = []
        for r in runs:
            e = reduction_error(model, r, spread=spread)
            allrms.append(e["rms_um"])
            print("    %-18s RMS %.3f um  max %.3f um  (full-model max |E_m| %.1f um)" % (r.name, e["rms_um"], e["max_um"], e["full_max_um"]))
        print("    worst RMS %.3f um (limit 0.5 um)" % max(allrms))


def bench_heldout(seeds=(11, 12, 13), noise_um=0.5):
    try:
        from host.twin import simulate_run
    except ImportError:
        print("held-out on twin runs: host.twin not available, skipped")
        return
    states = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490", "v8000_r0_700")
    print("held-out RMSE on twin runs of states 1, 2, 3, 5 (drifting air, no hidden effect, noise %.2f um), "
          "leave-one-run-out, ambient=off:" % noise_um)
    for air in ("auto", "off"):
        ratios = []
        t0 = time.perf_counter()
        for seed in seeds:
            runs = [simulate_run(p, seed=seed + i, noise_um=noise_um) for i, p in enumerate(states)]
            for k, r in enumerate(runs):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentifiabilityWarning)
                    m = ScrewModel(ambient=False, air=air).fit([x for j, x in enumerate(runs) if j != k])
                ratios.append(float(np.sqrt(np.mean((r.errors.error_um - m.predict(r)) ** 2))) / noise_um)
        print("  air %-4s RMSE / noise: median %.2f, max %.2f over %d held-out runs (%.1f s)%s"
              % (air, np.median(ratios), np.max(ratios), len(ratios), time.perf_counter() - t0,
                 "  (budget <= 1.25)" if air == "auto" else "  (the air term removed)"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="*", help="run folders (default: data/demo/)")
    a = ap.parse_args(argv)
    folders = a.runs or [os.path.join(DEMO, n) for n in sorted(os.listdir(DEMO))] if os.path.isdir(DEMO) or a.runs else []
    runs = [load_run(f) for f in folders]
    print("cores visible: %d, load average %s, OPENBLAS_NUM_THREADS=%s" % (
        os.cpu_count(), ", ".join("%.1f" % x for x in os.getloadavg()), os.environ.get("OPENBLAS_NUM_THREADS", "(unset)")))
    bench_simulation()
    if not runs:
        print("no runs (data/demo/ missing): identification and reduction skipped")
        return 0
    by_name = {r.name: r for r in runs}
    three = [by_name[n] for n in THREE if n in by_name] or runs[:3]
    model = bench_identification(three)
    bench_reduction(model, runs)
    bench_heldout()
    return 0


if __name__ == "__main__":
    sys.exit(main())
