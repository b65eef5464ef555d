"""Benchmark of the feed-axis twin: wall time per simulated run and screw node-substeps per second.

Usage: .venv/bin/python tools/bench_sim.py [--repeat N]
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.twin import EFFECTS, PROTOCOLS, simulate
from host.twin.screw import ScrewGrid, ScrewIntegrator


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("%-17s %8s %6s %5s %8s %10s %12s %18s" % ("protocol", "hours", "steps", "sub", "nodes", "effects", "best ms",
                                                      "node-substeps/s"))
    for name in PROTOCOLS:
        for effects in (None, list(EFFECTS)):
            best = float("inf")
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                sim = simulate(name, effects, seed=0)
                best = min(best, time.perf_counter() - t0)
            steps = sim.t_s.size - 1
            p = sim.params
            grid = ScrewGrid(p)
            sub = ScrewIntegrator(grid, p.dt_s, p.time_constant_s).substeps(1.0)
            print("%-17s %8.1f %6d %5d %8d %10s %12.1f %18.3g" % (
                name, sim.t_s[-1] / 3600, steps, sub, grid.n_nodes, "all" if effects else "none", best * 1e3,
                steps * sub * grid.n_nodes / best))


if __name__ == "__main__":
    main()
