"""Sensor selection by hierarchical clustering with GA-optimised weight and cluster count.

Clustering data: the measured temperatures (``distance_on="values"``, default: the
paper argues that value gaps reflect where a sensor sits, which rises discard) or
the rises (``"rises"``). The robustness model is always fitted on rises, without
intercept (Eq. 16; ``intercept=True`` adds one).

Comparison groups of the paper: ``alpha`` fixed (1: Euclidean only, 0:
correlation only) and/or ``k`` fixed (``k=1``: a single sensor); the GA then
searches only what is left free (both fixed: one evaluation, no GA).

Genome: ``ALPHA_BITS`` bits for the distance weight a in [0, 1] (step 1/255) and
enough bits for the number of clusters k in 1..k_max (k_max = min(max_clusters,
sensors, training samples - 2), mapped linearly and rounded). Cost of a genome =
robustness of the best one-sensor-per-cluster model of its partition: fit the
model (intercept + one coefficient per sensor) on the training run, predict
every other run with a disturbance added to its temperatures, average the RMSEs.
The disturbance realisation is drawn once from the seed and shared by all
candidates, so costs are comparable and the whole search is reproducible.

Every one-per-cluster combination of a partition is fitted in one batch
(:class:`host.learning.empirical.selectors.linalg.SubsetFitter`). When the number of
combinations exceeds ``max_combinations``, the largest clusters are trimmed to
their members most correlated with the target until it fits; the reason records it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import math
import zlib

import numpy as np

from host.learning.empirical.selectors.common import Selection, SelectionError, check_params, data_label, number
from host.learning.empirical.selectors.ga import binary_ga, decode_uint
from host.learning.empirical.selectors.hclust import Moments, agglomerate
from host.learning.empirical.selectors.linalg import SubsetFitter, SubsetScorer

if TYPE_CHECKING:
    from host.learning.empirical.selectors.hclust import Agglomeration

ALPHA_BITS = 8

DEFAULTS = {
    "seed": 0,
    "population": 20,
    "crossover": 0.8,
    "mutation": 0.005,
    "generations": 20,
    "disturbance_C": 0.5,
    "disturbance": "uniform",
    "train_run": 0,
    "max_clusters": 10,
    "max_combinations": 20000,
    "alpha": None,  # fixed distance weight (None: the GA chooses)
    "k": None,  # fixed number of clusters (None: the GA chooses; "all": every candidate sensor, S002's group 4)
    "distance_on": "values",  # values | rises
    "normalisation": "max",  # max (Eq. 5) | minmax
    "intercept": False,  # Eq. 16 has none
    "series": "log",  # log (every temperature sample of the training run) | targets (the sweep times)
}
SERIES = ("log", "targets")
DISTANCE_ON = ("values", "rises")


def combinations(clusters: Sequence[Sequence[int]], score: np.ndarray, max_combinations: int) -> tuple[np.ndarray, list[list[int]] | None]:
    """All one-per-cluster index combinations (m, k), trimming clusters if there are too many.

    ``score`` ranks members for trimming (|r| with the target, larger kept).
    Returns (combos, trimmed_clusters_or_None).
    """
    clusters = [list(c) for c in clusters]
    trimmed = False
    while math.prod(len(c) for c in clusters) > max_combinations:
        big = max(range(len(clusters)), key=lambda i: len(clusters[i]))
        if len(clusters[big]) == 1:
            break
        worst = min(clusters[big], key=lambda j: score[j])
        clusters[big].remove(worst)
        trimmed = True
    grids = np.meshgrid(*[np.asarray(c, dtype=np.intp) for c in clusters], indexing="ij")
    combos = np.stack([g.ravel() for g in grids], axis=1)
    return combos, (clusters if trimmed else None)


class RobustnessProblem:
    """Everything the GA cost needs, with caches of agglomerations and partitions."""

    def __init__(self, train: Any, tests: Any, disturbance_C: float, disturbance: str, seed: int, max_combinations: int, cluster_X: np.ndarray | None = None, normalisation: str = "max", intercept: bool = False) -> None:
        Xtr, ytr, names = train
        self.names = names
        self.X = Xtr if cluster_X is None else cluster_X  # what the distances are computed on
        self.y = ytr
        self.normalisation = normalisation
        p = Xtr.shape[1]
        self.fitter = SubsetFitter(Xtr, ytr, intercept=intercept)
        self.tests = []
        for r, (X, y, _) in enumerate(tests):
            if disturbance == "uniform":
                # one stream per (run, sensor name): the draw does not depend on column order
                noise = np.column_stack(
                    [np.random.default_rng([int(seed), r, zlib.crc32(s.encode())]).uniform(-disturbance_C, disturbance_C, X.shape[0]) for s in names]
                )
            elif disturbance == "offset":
                noise = np.full(X.shape, float(disturbance_C))
            else:
                raise SelectionError("hclust-ga: disturbance must be 'uniform' or 'offset', got %r" % (disturbance,))
            self.tests.append((X, X + noise, y))
        self.scorers = [SubsetScorer(Xd, y) for _, Xd, y in self.tests]
        self.score = np.abs([np.corrcoef(Xtr[:, j], ytr)[0, 1] for j in range(p)])
        self.max_combinations = int(max_combinations)
        self.moments = Moments(self.X)
        self._agg = {}
        self._part = {}
        self.evaluations = 0  # subset models fitted and scored

    def agglomeration(self, alpha: float) -> Agglomeration:
        if alpha not in self._agg:
            self._agg[alpha] = agglomerate(self.X, alpha, self.moments, self.normalisation)
        return self._agg[alpha]

    def score_partition(self, clusters: Sequence[Sequence[int]]) -> dict[str, Any]:
        key = tuple(tuple(c) for c in clusters)
        if key in self._part:
            return self._part[key]
        combos, trimmed = combinations(clusters, self.score, self.max_combinations)
        b0, b = self.fitter.fit(combos)
        per_run = np.stack([sc.rmse(b0, b, combos) for sc in self.scorers])  # (runs, m)
        cost = per_run.mean(axis=0)
        i = int(np.argmin(cost))
        self.evaluations += combos.shape[0]
        res = {
            "cost": float(cost[i]),
            "combo": [int(j) for j in combos[i]],
            "intercept": float(b0[i]),
            "coefficients": [float(c) for c in b[i]],
            "rmse_disturbed": [float(v) for v in per_run[:, i]],
            "combinations": int(combos.shape[0]),
            "trimmed": trimmed,
        }
        self._part[key] = res
        return res


def select_hclust_ga(arrays: Any, context: dict[str, Any] | None = None, **params: Any) -> Selection:
    prm = check_params("hclust-ga", params, DEFAULTS)
    runs = (context or {}).get("runs") or ["run %d" % (i + 1) for i in range(len(arrays))]
    if len(arrays) < 2:
        raise SelectionError(
            "hclust-ga needs runs to test robustness on: it fits on one run and predicts at least one other (published: two); got %d run "
            "(with one long run, cut it into time windows: tcomp select --split 3)" % len(arrays)
        )
    tr = prm["train_run"] = number("hclust-ga", "train_run", prm["train_run"], 0, len(arrays) - 1, integer=True)
    for key in ("population", "generations", "max_clusters", "max_combinations"):
        prm[key] = number("hclust-ga", key, prm[key], 1, integer=True)
    if prm["population"] % 2:
        raise SelectionError("hclust-ga: population must be even (pairs for crossover), got %d" % prm["population"])
    for key in ("crossover", "mutation"):
        prm[key] = number("hclust-ga", key, prm[key], 0.0, 1.0)
    prm["disturbance_C"] = number("hclust-ga", "disturbance_C", prm["disturbance_C"], 0.0)
    prm["seed"] = number("hclust-ga", "seed", prm["seed"], 0, integer=True)
    prm["alpha"] = number("hclust-ga", "alpha", prm["alpha"], 0.0, 1.0, allow_none=True)
    if prm["distance_on"] not in DISTANCE_ON:
        raise SelectionError("hclust-ga: distance_on must be one of %s, got %r" % (", ".join(DISTANCE_ON), prm["distance_on"]))
    if prm["normalisation"] not in ("max", "minmax"):
        raise SelectionError("hclust-ga: normalisation must be max or minmax, got %r" % (prm["normalisation"],))
    if not isinstance(prm["intercept"], bool):
        raise SelectionError("hclust-ga: intercept must be true or false, got %r" % (prm["intercept"],))
    train = arrays[tr]
    tests = [a for i, a in enumerate(arrays) if i != tr]
    test_names = [r for i, r in enumerate(runs) if i != tr]
    Xtr, ytr, names = train
    n, p = Xtr.shape
    k_max = min(prm["max_clusters"], p, n - 2)  # >= 1: check_arrays guarantees n >= 3
    every = prm["k"] == "all"  # S002 comparison group 4: the given sensors (near the heat sources) all kept, one per cluster
    if every:
        if p > n - 2:
            raise SelectionError("hclust-ga: k=all keeps all %d sensors, the training run has %d samples (needs at least %d)" % (p, n, p + 2))
        prm["k"] = p
        if prm["alpha"] is None:
            prm["alpha"] = 1.0  # with one sensor per cluster the distance weight changes nothing
    prm["k"] = number("hclust-ga", "k", prm["k"], 1, min(p, n - 2), integer=True, allow_none=True)
    if prm["series"] not in SERIES:
        raise SelectionError("hclust-ga: series must be one of %s, got %r" % (", ".join(SERIES), prm["series"]))
    # tuples without start temperatures are clustered as given; RunArrays of rises get their start back.
    # Li 2017 computes D_e and D_r on the temperature series: every logged sample of the training run (series="log")
    log = getattr(train, "log", None) if prm["series"] == "log" else None
    base = Xtr if log is None else log[1]
    start = getattr(train, "start", None)
    cluster_X = (base if start is None else base + start) if prm["distance_on"] == "values" else base
    series_on = ("temperature log of the training run: %d samples" % base.shape[0] if log is not None
                 else "target times: %d samples%s" % (n, "" if prm["series"] == "targets" else " (no temperature log with these arrays)"))
    prob = RobustnessProblem(train, tests, float(prm["disturbance_C"]), prm["disturbance"], prm["seed"], prm["max_combinations"],
                             cluster_X=cluster_X, normalisation=prm["normalisation"], intercept=prm["intercept"])
    k_bits = max(1, math.ceil(math.log2(k_max))) if k_max > 1 else 1

    def decode(genome):
        alpha = decode_uint(genome[:ALPHA_BITS]) / (2 ** ALPHA_BITS - 1)
        v = decode_uint(genome[ALPHA_BITS:])
        k = 1 + int(round(v * (k_max - 1) / (2 ** k_bits - 1))) if k_max > 1 else 1
        return (alpha if prm["alpha"] is None else prm["alpha"]), (k if prm["k"] is None else prm["k"])

    def cost(genome):
        alpha, k = decode(genome)
        return prob.score_partition(prob.agglomeration(alpha).partition(k))["cost"]

    if prm["alpha"] is not None and prm["k"] is not None:
        ga = None  # nothing left to search
        alpha, k = prm["alpha"], prm["k"]
    else:
        ga = binary_ga(cost, ALPHA_BITS + k_bits, prm["population"], float(prm["crossover"]), float(prm["mutation"]), prm["generations"], prm["seed"])
        alpha, k = decode(ga.best_genome)
    agg = prob.agglomeration(alpha)
    clusters = agg.partition(k)
    best = prob.score_partition(clusters)
    chosen = sorted(best["combo"])
    sensors = [names[j] for j in chosen]
    order = best["combo"]
    clean = [float(np.sqrt(np.mean((best["intercept"] + X[:, order] @ np.asarray(best["coefficients"]) - y) ** 2))) for X, _, y in prob.tests]
    train_rmse = float(np.sqrt(np.mean((best["intercept"] + Xtr[:, order] @ np.asarray(best["coefficients"]) - ytr) ** 2)))
    reason = {
        "criterion": "minimise mean RMSE on the other runs with a %s %.3g degC disturbance on the temperatures; model fitted on %s"
        % (prm["disturbance"], prm["disturbance_C"], runs[tr]),
        "fitness_rmse": best["cost"],
        "alpha": alpha,
        "clusters_k": k,
        "fixed": {key: prm[key] for key in ("alpha", "k") if prm[key] is not None},
        "every_sensor": every,  # k=all: the candidates kept as given (comparison group 4), alpha irrelevant
        "distance_on": prm["distance_on"] if start is not None or prm["distance_on"] == "rises" else "values as given (no start temperatures)",
        "series": series_on,
        "normalisation": prm["normalisation"],
        "intercept": prm["intercept"],
        "clusters": [[names[j] for j in c] for c in clusters],
        "model": {"sensors": [names[j] for j in order], "intercept": best["intercept"], "coefficients": best["coefficients"]},
        "train_run": runs[tr],
        "test_runs": test_names,
        "rmse_disturbed": dict(zip(test_names, best["rmse_disturbed"])),
        "rmse_clean": dict(zip(test_names, clean)),
        "rmse_train": train_rmse,
        "combinations_in_partition": best["combinations"],
        "trimmed_clusters": None if best["trimmed"] is None else [[names[j] for j in c] for c in best["trimmed"]],
        "ga": None if ga is None else {
            "seed": prm["seed"],
            "population": prm["population"],
            "crossover": float(prm["crossover"]),
            "mutation": float(prm["mutation"]),
            "generations": prm["generations"],
            "alpha_bits": ALPHA_BITS,
            "k_bits": k_bits,
            "k_max": k_max,
            "genome": "".join(str(b) for b in ga.best_genome),
            "distinct_genomes": ga.evaluations,
            "distinct_partitions": len(prob._part),
            "model_evaluations": prob.evaluations,
            "history": ga.history,
        },
        "samples_train": int(n),
    }
    if len(tests) < 2:
        reason["fallback"] = "only %d run(s) besides the training run: fitness is the RMSE on %s alone (the published method averages two)" % (len(tests), ", ".join(test_names))
    label = data_label(context, n)

    def plotter(path):
        _plot(path, agg, clusters, chosen, names, [] if ga is None else ga.history, reason, label)

    return Selection(sensors, "hclust-ga", reason, plotter)


def _plot(path, agg, clusters, chosen, names, history, reason, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.cluster.hierarchy import dendrogram

    cluster_of = {j: ci + 1 for ci, c in enumerate(clusters) for j in c}
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(max(11.0, 0.45 * len(names) + 6), 4.8), gridspec_kw={"width_ratios": [3, 2]})
    if len(names) > 1:
        dendrogram(agg.linkage(), labels=["%s [%d]" % (names[j], cluster_of[j]) for j in range(len(names))], ax=a1, color_threshold=0, leaf_rotation=90)
        for tick in a1.get_xticklabels():
            base = tick.get_text().split(" [")[0]
            if base in {names[j] for j in chosen}:
                tick.set_color("red")
                tick.set_fontweight("bold")
    a1.set_ylabel("merge distance D")
    a1.set_title("clusters for α = %.3f, k = %d (chosen sensors in red, [cluster])" % (reason["alpha"], reason["clusters_k"]), fontsize=9)
    g = [h["generation"] for h in history]
    a2.plot(g, [h["best"] for h in history], "o-", label="best")
    a2.plot(g, [h["mean"] for h in history], "s--", label="population mean")
    a2.set_xlabel("generation")
    a2.set_ylabel("mean disturbed RMSE on the other runs")
    a2.legend(fontsize=8)
    a2.set_title("GA robustness fitness (seed %s)" % reason["ga"]["seed"] if reason["ga"] else "alpha and k fixed: no GA", fontsize=9)
    fig.suptitle("Hierarchical clustering + GA sensor selection: %s; fitness %.4g" % (label, reason["fitness_rmse"]), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
