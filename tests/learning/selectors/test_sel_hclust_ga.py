"""Hierarchical clustering on the combined distance, the binary GA, and the hclust-ga selector."""
import itertools

import numpy as np
import pytest
from scipy.cluster.hierarchy import is_valid_linkage

from host.learning.empirical.selectors import SelectionError, select
from host.learning.empirical.selectors.ga import binary_ga, decode_uint
from host.learning.empirical.selectors.hclust import agglomerate

SMALL_GA = {"population": 8, "generations": 4}


def _two_groups(n=60, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n)
    a = 1 - np.exp(-3 * t)
    b = np.sin(4 * t)
    X = np.column_stack([a, a * 2 + 5, a + 0.01 * rng.normal(size=n), b, b + 10, b * 0.5])
    return X


def test_correlation_only_groups_by_shape_and_euclid_only_by_level():
    X = _two_groups()
    shape = agglomerate(X, 0.0).partition(2)
    assert shape == [[0, 1, 2], [3, 4, 5]]
    level = agglomerate(X, 1.0)
    # sensors 1 and 4 sit 5-10 K above the rest: by Euclidean distance they form their own group
    assert level.partition(2) == [[0, 2, 3, 5], [1, 4]]


def test_agglomeration_structure():
    X = _two_groups()
    agg = agglomerate(X, 0.4)
    assert len(agg.merges) == X.shape[1] - 1
    for k in range(1, 7):
        part = agg.partition(k)
        assert len(part) == k
        assert sorted(itertools.chain(*part)) == list(range(6))
    assert is_valid_linkage(agg.linkage())
    with pytest.raises(ValueError):
        agg.partition(0)


def test_merged_cluster_distance_uses_mean_series():
    X = _two_groups()
    agg = agglomerate(X, 1.0)
    # recompute the last merge distance from the two clusters' mean series by hand
    a, b, d = agg.merges[-1]
    De = np.sqrt(((X[:, :, None] - X[:, None, :]) ** 2).sum(axis=0))
    off = De[~np.eye(6, dtype=bool)]
    ma, mb = X[:, list(a)].mean(axis=1), X[:, list(b)].mean(axis=1)
    # default (Eq. 5): divided by the largest pair distance; "minmax" is the earlier form
    assert d == pytest.approx(np.linalg.norm(ma - mb) / off.max())
    a, b, d = agglomerate(X, 1.0, normalisation="minmax").merges[-1]
    ma, mb = X[:, list(a)].mean(axis=1), X[:, list(b)].mean(axis=1)
    assert d == pytest.approx((np.linalg.norm(ma - mb) - off.min()) / (off.max() - off.min()))
    with pytest.raises(ValueError, match="normalisation"):
        agglomerate(X, 1.0, normalisation="z")


def test_ga_finds_onemax_and_is_reproducible():
    cost = lambda g: -sum(g)  # noqa: E731
    r1 = binary_ga(cost, 12, population=20, generations=40, mutation=0.05, seed=4)
    r2 = binary_ga(cost, 12, population=20, generations=40, mutation=0.05, seed=4)
    assert r1.best_genome == r2.best_genome and r1.history == r2.history
    assert r1.best_cost == -12
    best = [h["best"] for h in r1.history]
    assert all(b2 <= b1 for b1, b2 in zip(best, best[1:]))  # elitism
    assert r1.evaluations <= r1.calls == 20 * 41
    assert decode_uint((1, 0, 1)) == 5


def test_ga_rejects_bad_settings():
    with pytest.raises(ValueError):
        binary_ga(lambda g: 0.0, 4, population=7)
    with pytest.raises(ValueError):
        binary_ga(lambda g: 0.0, 4, crossover=1.5)


def test_hclust_ga_reproducible_and_seed_matters(arrays3):
    a = select("hclust-ga", arrays3, seed=1)
    b = select("hclust-ga", arrays3, seed=1)
    assert a.sensors == b.sensors and a.reason == b.reason
    others = [select("hclust-ga", arrays3, seed=s, **SMALL_GA).reason["ga"]["genome"] for s in (2, 3, 4)]
    assert len(set(others + [a.reason["ga"]["genome"]])) > 1


@pytest.mark.parametrize("intercept", [False, True])
def test_hclust_ga_returns_the_best_combination_of_its_partition(arrays3, intercept):
    sel = select("hclust-ga", arrays3, seed=0, intercept=intercept)
    r = sel.reason
    names = arrays3[0][2]
    clusters = [[names.index(s) for s in c] for c in r["clusters"]]
    assert sorted(sel.sensors) == sorted(r["model"]["sensors"])
    assert all(sum(names.index(s) in c for s in sel.sensors) == 1 for c in clusters)
    assert r["combinations_in_partition"] == np.prod([len(c) for c in clusters])
    Xtr, ytr, _ = arrays3[0]
    # independent re-evaluation: per-combination lstsq, same disturbance (the clean run + the
    # reported disturbed RMSE identify it), every combination no better than the chosen one
    best = None
    for combo in itertools.product(*clusters):
        A = np.column_stack([np.ones(len(ytr)), Xtr[:, combo]]) if intercept else np.column_stack([np.zeros(len(ytr)), Xtr[:, combo]])
        coef = np.linalg.lstsq(A, ytr, rcond=None)[0]  # without intercept the zero column gets the minimum-norm 0
        clean = np.mean([np.sqrt(np.mean((coef[0] + X[:, combo] @ coef[1:] - y) ** 2)) for X, y, _ in arrays3[1:]])
        if sorted(names[j] for j in combo) == sorted(sel.sensors):
            best = clean
            np.testing.assert_allclose(coef[1:], r["model"]["coefficients"], rtol=1e-6)
    assert best == pytest.approx(np.mean(list(r["rmse_clean"].values())))
    assert r["fitness_rmse"] == pytest.approx(np.mean(list(r["rmse_disturbed"].values())))
    assert r["ga"]["model_evaluations"] >= r["combinations_in_partition"]
    assert "fallback" not in r
    assert (r["model"]["intercept"] == 0.0) is (not intercept) and r["intercept"] is intercept


def test_comparison_groups_fix_alpha_and_k(arrays3):
    fixed_a = select("hclust-ga", arrays3, alpha=1, seed=0, **SMALL_GA)
    assert fixed_a.reason["alpha"] == 1.0 and fixed_a.reason["fixed"] == {"alpha": 1.0}
    fixed_k = select("hclust-ga", arrays3, k=3, seed=0, **SMALL_GA)
    assert fixed_k.reason["clusters_k"] == 3 and len(fixed_k.sensors) == 3
    single = select("hclust-ga", arrays3, alpha=0, k=1)
    assert len(single.sensors) == 1 and single.reason["ga"] is None and single.reason["alpha"] == 0.0
    with pytest.raises(SelectionError, match="alpha must be"):
        select("hclust-ga", arrays3, alpha=1.5)
    with pytest.raises(SelectionError, match="k must be"):
        select("hclust-ga", arrays3, k=0)
    with pytest.raises(SelectionError, match="distance_on"):
        select("hclust-ga", arrays3, distance_on="kelvin")


def test_euclidean_distance_on_measured_values_sees_the_level():
    """Two sensor pairs rise identically; one pair sits 6 K warmer. On rises the Euclidean
    distance cannot tell the pairs apart, on measured values it separates them."""
    from host.learning.empirical.targets import RunArrays

    t = np.linspace(0, 1, 30)
    runs = []
    for r in range(3):
        a = (1 + 0.2 * r) * (1 - np.exp(-3 * t))
        rises = np.column_stack([a, a * 1.001, a * 0.999, a * 1.002])
        start = np.array([20.0, 20.1, 26.0, 26.1])
        runs.append(RunArrays(rises, 2 * a + 0.01 * np.sin(7 * t + r), ["W1", "W2", "H1", "H2"], t, "r%d" % r, start))
    on_values = select("hclust-ga", runs, alpha=1, k=2)
    on_rises = select("hclust-ga", runs, alpha=1, k=2, distance_on="rises")
    assert on_values.reason["clusters"] == [["W1", "W2"], ["H1", "H2"]]
    assert on_rises.reason["clusters"] != on_values.reason["clusters"]


def test_offset_disturbance_penalises_coefficient_sum(arrays3):
    sel = select("hclust-ga", arrays3, disturbance="offset", disturbance_C=0.5, seed=0, **SMALL_GA)
    r = sel.reason
    # a constant offset d on every input shifts each prediction by d * sum(b)
    X, y, names = arrays3[1]
    idx = [names.index(s) for s in r["model"]["sensors"]]
    pred = r["model"]["intercept"] + (X[:, idx] + 0.5) @ np.asarray(r["model"]["coefficients"])
    assert r["rmse_disturbed"]["run 2"] == pytest.approx(np.sqrt(np.mean((pred - y) ** 2)))


def test_two_runs_fall_back_and_one_run_is_an_error(arrays3):
    sel = select("hclust-ga", arrays3[:2], seed=0, **SMALL_GA)
    assert "fallback" in sel.reason and sel.reason["test_runs"] == ["run 2"]
    with pytest.raises(SelectionError, match="got 1 run"):
        select("hclust-ga", arrays3[:1])
    with pytest.raises(SelectionError, match="train_run"):
        select("hclust-ga", arrays3, train_run=5)
    with pytest.raises(SelectionError, match="population must be even"):
        select("hclust-ga", arrays3, population=7)
    with pytest.raises(SelectionError, match="disturbance"):
        select("hclust-ga", arrays3, disturbance="gaussian")


def test_train_run_choice_and_plot(arrays3, tmp_path):
    sel = select("hclust-ga", arrays3, train_run=2, seed=0, **SMALL_GA)
    assert sel.reason["train_run"] == "run 3" and sel.reason["test_runs"] == ["run 1", "run 2"]
    path = sel.plot(str(tmp_path / "hg.png"))
    with open(path, "rb") as fh:
        assert fh.read(4) == b"\x89PNG"


def test_hclust_ga_picks_the_informative_group():
    """Two groups of four sensors follow two unrelated heat sources; the target follows
    group A only. The robust model must use group A, and predict the other runs well."""
    rng = np.random.default_rng(8)
    t = np.linspace(0, 1, 50)
    runs = []
    for r in range(3):
        sa = (1 + 0.3 * r) * (1 - np.exp(-4 * t)) * 8
        sb = (1.5 - 0.4 * r) * np.sin(3 * t + r) * 5
        X = np.column_stack([sa * w + rng.normal(scale=0.05, size=50) for w in (1.0, 0.9, 1.1, 0.8)]
                            + [sb * w + rng.normal(scale=0.05, size=50) for w in (1.0, 0.7, 1.2, 0.9)])
        y = 3.0 * sa + rng.normal(scale=0.05, size=50)
        runs.append((X, y, ["A1", "A2", "A3", "A4", "B1", "B2", "B3", "B4"]))
    sel = select("hclust-ga", runs, seed=0)
    assert any(s.startswith("A") for s in sel.sensors)
    # clean prediction of the other runs is close to the noise floor of y (0.05) plus
    # what 0.05 K sensor noise costs through coefficients of about 3 um/K
    assert max(sel.reason["rmse_clean"].values()) < 0.5
    assert sel.to_json()["reason"]["ga"]["seed"] == 0


def test_to_json_is_strict():
    import json

    from host.learning.empirical.selectors import Selection

    doc = Selection(["A"], "x", {"F": float("inf"), "r": np.float64(0.5), "k": np.int64(3), "v": np.array([1.0, np.nan])}).to_json()
    assert doc["reason"] == {"F": None, "r": 0.5, "k": 3, "v": [1.0, None]}
    json.dumps(doc, allow_nan=False)


def test_k_all_keeps_every_given_sensor_as_comparison_group_4(arrays3):
    # Li 2017 group 4: the sensors near the heat sources (and the environment) all go into the model
    names = arrays3[0][2]
    given = names[:4]
    sel = select("hclust-ga", arrays3, sensors=given, k="all")
    assert sel.sensors == given and sel.reason["every_sensor"] and sel.reason["ga"] is None
    assert sel.reason["clusters_k"] == 4 and not sel.reason["intercept"]
    # the model on them is Eq. 16 (no intercept) fitted on the training run: check the coefficients by lstsq
    X, y, _ = arrays3[0]
    idx = [names.index(s) for s in sel.reason["model"]["sensors"]]
    b = np.linalg.lstsq(X[:, idx], y, rcond=None)[0]
    np.testing.assert_allclose(sel.reason["model"]["coefficients"], b, rtol=1e-6, atol=1e-9)
