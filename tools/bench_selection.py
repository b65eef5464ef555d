"""Benchmark: hclust-ga sensor selection on 23 sensors x 3 runs.

Prints wall time, subset-model evaluations per second (fit on the training run
+ disturbed prediction of the two other runs, batched), and the same work done
as a Python loop of np.linalg.lstsq fits for comparison.

Data (``--source``):
  twin       (default) three digital-twin runs (host/twin) at feeds 8000, 6500 and
             15000 mm/min. The twin has 13 structure sensors; 10 more are derived
             as sensors mounted between two of them: a weighted mean of a pair of
             twin sensors plus 0.02 K white noise. That gives a dense, strongly
             collinear 23-sensor layout like the published ones.
  synthetic  23 sensors mixing three first-order heat sources with per-run
             amplitudes, plus 0.02 K noise; target = 2*s0 - s2. No twin needed.

    .venv/bin/python tools/bench_selection.py [--source twin|synthetic] [--seeds 3]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

PROTOCOLS = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490")
N_SENSORS = 23


def twin_arrays(target, seed=0):
    from host.learning.empirical.targets import training_arrays
    from host.twin import simulate_run

    runs = [simulate_run(protocol=p, seed=seed + i) for i, p in enumerate(PROTOCOLS)]
    base = training_arrays(runs, target=target)
    p0 = len(base[0].names)
    rng = np.random.default_rng(1234)
    extra = N_SENSORS - p0
    pairs = [rng.choice(p0, 2, replace=False) for _ in range(extra)]
    weights = rng.uniform(0.2, 0.8, extra)
    out = []
    for a in base:
        cols = [a.X]
        for (i, j), w in zip(pairs, weights):
            cols.append((w * a.X[:, i] + (1 - w) * a.X[:, j] + rng.normal(scale=0.02, size=a.X.shape[0]))[:, None])
        names = list(a.names) + ["V%d(%s,%s)" % (m + 1, a.names[i], a.names[j]) for m, (i, j) in enumerate(pairs)]
        out.append((np.hstack(cols), a.y, names))
    return out, [r.name for r in runs]


def synthetic_arrays(n=200, seed=0):
    rng = np.random.default_rng(seed)
    W = rng.uniform(0.1, 1.0, size=(3, N_SENSORS))
    t = np.linspace(0.0, 1.0, n)
    out = []
    for _ in range(3):
        amp = rng.uniform(0.5, 1.5, size=3)
        src = np.column_stack([amp[m] * (1 - np.exp(-t * (m + 1) * 2.5)) for m in range(3)]) * 10
        X = src @ W + 0.02 * rng.normal(size=(n, N_SENSORS))
        y = 2.0 * src[:, 0] - src[:, 2] + 0.05 * rng.normal(size=n)
        out.append((X, y, ["S%d" % (j + 1) for j in range(N_SENSORS)]))
    return out, ["synthetic %d" % (i + 1) for i in range(3)]


def batch_vs_loop(arrays, clusters, limit=5000, repeats=5):
    """The evaluation of one partition's combinations: batched (as the GA does it) and as a
    Python loop of np.linalg.lstsq fits, on the same combinations -> (m, batch_s, loop_s)."""
    import itertools

    from host.learning.empirical.selectors.linalg import SubsetFitter, subset_rmse

    (Xtr, ytr, names), tests = arrays[0], arrays[1:]
    idx = [[names.index(s) for s in c] for c in clusters]
    combos = np.array(list(itertools.islice(itertools.product(*idx), limit)), dtype=np.intp)
    rng = np.random.default_rng(0)
    noisy = [(X + rng.uniform(-0.5, 0.5, X.shape), y) for X, y, _ in tests]
    batch = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        b0, b = SubsetFitter(Xtr, ytr).fit(combos)
        for X, y in noisy:
            subset_rmse(b0, b, combos, X, y)
        batch.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for c in combos:
        A = np.column_stack([np.ones(len(ytr)), Xtr[:, c]])
        coef = np.linalg.lstsq(A, ytr, rcond=None)[0]
        for X, y in noisy:
            np.sqrt(np.mean((coef[0] + X[:, c] @ coef[1:] - y) ** 2))
    return len(combos), min(batch), time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("twin", "synthetic"), default="twin")
    ap.add_argument("--seeds", type=int, default=3, help="GA seeds to run (timings per seed)")
    args = ap.parse_args(argv)

    from host.learning.empirical.selectors import select

    t0 = time.perf_counter()
    if args.source == "twin":
        arrays, labels = twin_arrays("slope")
    else:
        arrays, labels = synthetic_arrays()
    t_data = time.perf_counter() - t0
    n = [a[0].shape[0] for a in arrays]
    print("data: %s, %d sensors x %d runs (%s), samples per run %s, target %s; generated in %.2f s"
          % (args.source, arrays[0][0].shape[1], len(arrays), ", ".join(labels), n, "sweep slope k_i - k_0" if args.source == "twin" else "2*s0-s2", t_data))
    print("GA: population 20, crossover 0.8, mutation 0.005, 20 generations; fitness = mean RMSE on runs 2-3 with +-0.5 degC uniform disturbance")
    print("%4s %8s %10s %9s %8s %10s %10s  %s" % ("seed", "wall_s", "model_evals", "evals/s", "genomes", "partitions", "fitness", "sensors"))
    rates = []
    last = None
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        sel = select("hclust-ga", arrays, seed=seed)
        wall = time.perf_counter() - t0
        ga = sel.reason["ga"]
        rate = ga["model_evaluations"] / wall
        rates.append(rate)
        last = sel
        print("%4d %8.3f %10d %9.0f %8d %10d %10.4g  %s" % (seed, wall, ga["model_evaluations"], rate, ga["distinct_genomes"], ga["distinct_partitions"], sel.reason["fitness_rmse"], ",".join(sel.sensors)))
    print("median model evaluations per second (batched, including clustering and GA overhead): %.0f" % np.median(rates))
    m, tb, tl = batch_vs_loop(arrays, last.reason["clusters"])
    print("the last chosen partition's %d combinations (%d sensors each), evaluation only:" % (m, len(last.sensors)))
    print("  batched normal equations: %.4f s = %.0f evals/s" % (tb, m / tb))
    print("  np.linalg.lstsq loop:     %.4f s = %.0f evals/s  (batched is %.1fx faster)" % (tl, m / tl, tl / tb))
    return 0


if __name__ == "__main__":
    sys.exit(main())
