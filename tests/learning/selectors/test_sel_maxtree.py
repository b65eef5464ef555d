"""Maximal-tree fuzzy clustering: hand-checked example, thresholds, λ-cuts, selection criterion."""
import numpy as np
import pytest
from scipy.sparse.csgraph import minimum_spanning_tree

from host.learning.empirical.selectors import SelectionError, maximal_tree, select
from host.learning.empirical.selectors.maxtree import prim_maximum_tree

NAMES = ["T1", "T2", "T3", "T4", "T5"]
# a published-style matrix (values to two decimals) whose tree is worked out by hand below
C5 = np.array([
    [1.00, 0.95, 0.60, 0.55, 0.30],
    [0.95, 1.00, 0.70, 0.50, 0.35],
    [0.60, 0.70, 1.00, 0.85, 0.40],
    [0.55, 0.50, 0.85, 1.00, 0.45],
    [0.30, 0.35, 0.40, 0.45, 1.00],
])
TARGET5 = [0.8, 0.9, 0.6, 0.7, 0.5]


def test_hand_worked_example():
    # Prim from T1: T2 (0.95); then T3 via T2 (0.70 > 0.60, 0.55, 0.35); then T4 via T3
    # (0.85); then T5 via T4 (0.45 > 0.40 > 0.35 > 0.30).
    tree = maximal_tree(C5, NAMES, TARGET5)
    assert tree.edges == [("T1", "T2", 0.95), ("T2", "T3", 0.70), ("T3", "T4", 0.85), ("T4", "T5", 0.45)]
    got = [(p.lambda_low, p.lambda_high, p.clusters, p.representatives) for p in tree.partitions]
    assert got == [
        (0.0, 0.45, [["T1", "T2", "T3", "T4", "T5"]], ["T2"]),
        (0.45, 0.70, [["T1", "T2", "T3", "T4"], ["T5"]], ["T2", "T5"]),
        (0.70, 0.85, [["T1", "T2"], ["T3", "T4"], ["T5"]], ["T2", "T4", "T5"]),
        (0.85, 0.95, [["T1", "T2"], ["T3"], ["T4"], ["T5"]], ["T2", "T3", "T4", "T5"]),
        (0.95, 1.0, [["T1"], ["T2"], ["T3"], ["T4"], ["T5"]], NAMES),
    ]
    doc = tree.to_json()
    assert doc["edges"][0] == ["T1", "T2", 0.95]
    assert [p["lambda_high"] for p in doc["partitions"]] == [0.45, 0.70, 0.85, 0.95, 1.0]


def test_representatives_without_target_are_most_typical_members():
    tree = maximal_tree(C5, NAMES)
    # {T1..T4} at λ in (0.45, 0.70]: mean similarity T1 .70, T2 .7167, T3 .7167, T4 .6333 -> T2 (first of equals)
    assert tree.partitions[1].representatives == ["T2", "T5"]
    assert tree.representative_rule.startswith("max mean similarity")


def _closure(S):
    """Max-min transitive closure by repeated composition: an independent λ-cut reference."""
    R = S.copy()
    while True:
        R2 = np.maximum(R, np.max(np.minimum(R[:, :, None], R[None, :, :]), axis=1))
        if np.array_equal(R2, R):
            return R
        R = R2


def _cut(R, lam, names):
    """The λ-cut classes as Li 2021's Table 3 reads them: together when the closure is above λ (or 1)."""
    p = len(names)
    seen, out = set(), []
    for i in range(p):
        if i in seen:
            continue
        cls = [names[j] for j in range(p) if R[i, j] > lam or R[i, j] >= 1.0]
        seen.update(names.index(c) for c in cls)
        out.append(cls)
    return out


def _random_corr(seed, p=8, n=30):
    rng = np.random.default_rng(seed)
    base = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    X = base @ rng.normal(size=(3, p)) + rng.normal(scale=0.8, size=(n, p))
    return np.round(np.corrcoef(X, rowvar=False), 4)


@pytest.mark.parametrize("seed", range(6))
def test_edge_weights_are_the_partition_thresholds_and_intervals_give_the_cuts(seed):
    C = _random_corr(seed)
    names = ["s%d" % i for i in range(C.shape[0])]
    tree = maximal_tree(C, names)
    S = np.abs(C)
    weights = sorted({w for _, _, w in tree.edges if w < 1.0})
    assert [p.lambda_high for p in tree.partitions[:-1]] == weights
    assert [p.lambda_low for p in tree.partitions[1:]] == weights
    assert tree.partitions[0].lambda_low == 0.0 and tree.partitions[-1].lambda_high == 1.0
    R = _closure(S)
    rng = np.random.default_rng(seed)
    for k, part in enumerate(tree.partitions):
        lo, hi = part.lambda_low, part.lambda_high
        last = k == len(tree.partitions) - 1
        lams = [lo] + list(rng.uniform(lo, hi, 3)) + ([1.0] if last else [])
        for lam in lams:
            if not last and lam >= hi:
                continue
            assert tree.partition_at(lam) == part.clusters
            assert sorted(map(sorted, _cut(R, lam, names))) == sorted(map(sorted, part.clusters))
    # number of clusters grows by the number of edges at each threshold
    sizes = [len(p.clusters) for p in tree.partitions]
    assert sizes == sorted(sizes) and sizes[-1] == len(names)


@pytest.mark.parametrize("seed", range(4))
def test_prim_tree_is_a_maximum_spanning_tree(seed):
    S = np.abs(_random_corr(seed, p=9))
    edges = prim_maximum_tree(S)
    assert edges[0][0] == 0  # grown from sensor 1
    added = {0}
    for i, j, _ in edges:
        assert i in added and j not in added
        added.add(j)
    ref = minimum_spanning_tree(2.0 - S)  # positive weights; maximising S = minimising 2 - S
    assert sum(w for _, _, w in edges) == pytest.approx(2.0 * (S.shape[0] - 1) - ref.sum())


def test_negative_correlation_absolute_and_signed():
    C = np.array([[1.0, -0.9, 0.2], [-0.9, 1.0, 0.1], [0.2, 0.1, 1.0]])
    assert maximal_tree(C, "abc", absolute=True).partitions[1].clusters == [["a", "b"], ["c"]]
    signed = maximal_tree(C, "abc", absolute=False)
    # with r itself, a and b only join through c at λ <= 0.1
    assert signed.partitions[0].clusters == [["a", "b", "c"]]
    assert signed.partitions[0].lambda_high == pytest.approx(0.1)


def test_weight_one_edges_never_cut():
    C = np.array([[1.0, 1.0, 0.5], [1.0, 1.0, 0.5], [0.5, 0.5, 1.0]])
    parts = maximal_tree(C, ["a", "b", "c"]).partitions
    assert [(p.lambda_low, p.lambda_high) for p in parts] == [(0.0, 0.5), (0.5, 1.0)]
    assert parts[-1].clusters == [["a", "b"], ["c"]]


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda C: C.__setitem__((0, 1), 0.5), "not symmetric"),
        (lambda C: C.__setitem__((2, 2), 0.9), "diagonal"),
        (lambda C: (C.__setitem__((0, 1), 1.2), C.__setitem__((1, 0), 1.2)), "outside"),
        (lambda C: (C.__setitem__((0, 1), np.nan), C.__setitem__((1, 0), np.nan)), "not a finite"),
    ],
)
def test_bad_matrix_is_named(mutate, message):
    C = C5.copy()
    mutate(C)
    with pytest.raises(SelectionError, match=message):
        maximal_tree(C, NAMES)


def test_bad_target_correlations():
    with pytest.raises(SelectionError, match="4 values for 5 sensors"):
        maximal_tree(C5, NAMES, TARGET5[:4])
    with pytest.raises(SelectionError, match="T3"):
        maximal_tree(C5, NAMES, {"T1": 0.1, "T2": 0.1, "T4": 0.1, "T5": 0.2})
    with pytest.raises(SelectionError, match="T5"):
        maximal_tree(C5, NAMES, [0.1, 0.2, 0.3, 0.4, 1.5])


def test_r2_change_criterion_adds_sensors_only_for_a_significant_r2_gain(arrays3):
    from scipy import stats

    sel = select("maxtree", arrays3, criterion="r2-change")
    r = sel.reason
    assert r["criterion_name"] == "r2-change"
    n = r["samples"]
    ok = sorted([row for row in r["partitions"] if "skipped" not in row and row["p_F"] < 0.05], key=lambda row: len(row["representatives"]))
    # independent replay: partial F of the R² change, textbook form
    cur, examined = ok[0], [ok[0]["partition"]]
    for row in ok[1:]:
        examined.append(row["partition"])
        k0, k1 = len(cur["representatives"]), len(row["representatives"])
        F = ((row["r2"] - cur["r2"]) / (k1 - k0)) / ((1 - row["r2"]) / (n - k1 - 1))
        if row["r2"] <= cur["r2"] or stats.f.sf(F, k1 - k0, n - k1 - 1) >= 0.05:
            break
        cur = row
    assert r["chosen_partition"] == cur["partition"]
    assert [st["partition"] for st in r["steps"]] == examined


def test_one_dominant_sensor_is_kept_alone_by_the_r2_change_criterion():
    rng = np.random.default_rng(5)
    n = 60
    base = np.cumsum(rng.normal(size=n))
    X = np.column_stack([base + 0.3 * rng.normal(size=n) for _ in range(4)] + [rng.normal(size=n) for _ in range(3)])
    y = 2.0 * X[:, 0] + 0.5 * rng.normal(size=n)
    names = ["S%d" % (j + 1) for j in range(X.shape[1])]
    forward = select("maxtree", (X, y, names), criterion="r2-change")
    loose = select("maxtree", (X, y, names), criterion="tolerance")
    assert len(forward.sensors) <= len(loose.sensors)
    assert "S1" in forward.sensors
    with pytest.raises(SelectionError, match="criterion must be one of"):
        select("maxtree", (X, y, names), criterion="best")


def test_tolerance_criterion_is_kept_as_an_option(arrays3):
    sel = select("maxtree", arrays3, criterion="tolerance")
    r = sel.reason
    evaluated = [row for row in r["partitions"] if "skipped" not in row and row["p_F"] < 0.05]
    best = max(row["r2"] for row in evaluated)
    cands = [row for row in evaluated if row["r2"] >= best - 0.01]
    assert r["F"] == max(row["F"] for row in cands)
    assert r["p_F"] < 0.05
    # the reported R² is an ordinary least-squares R² of the chosen sensors (independent recomputation)
    X = np.vstack([a[0] for a in arrays3])
    y = np.concatenate([a[1] for a in arrays3])
    idx = [arrays3[0][2].index(s) for s in sel.sensors]
    A = np.column_stack([np.ones(len(y)), X[:, idx]])
    res = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    assert r["r2"] == pytest.approx(1 - res @ res / ((y - y.mean()) @ (y - y.mean())))
    # representatives are the members most correlated with the target
    part = r["tree"]["partitions"][r["chosen_partition"]]
    tc = r["target_correlation"]
    for cluster, rep in zip(part["clusters"], part["representatives"]):
        assert abs(tc[rep]) == max(abs(tc[s]) for s in cluster)
    assert sorted(sel.sensors) == sorted(part["representatives"])


def test_zero_tolerance_is_pure_r2(arrays3):
    sel = select("maxtree", arrays3, criterion="tolerance", r2_tolerance=0.0)
    ok = [row for row in sel.reason["partitions"] if "skipped" not in row and row["p_F"] < 0.05]
    assert sel.reason["r2"] == max(row["r2"] for row in ok)
    capped = select("maxtree", arrays3, criterion="tolerance", r2_tolerance=0.0, max_sensors=2)
    assert len(capped.sensors) <= 2


def test_selection_plot_is_written(arrays3, tmp_path):
    sel = select("maxtree", arrays3)
    out = sel.plot(str(tmp_path / "mt.png"))
    with open(out, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_degenerate_intervals():
    one = maximal_tree(np.array([[1.0]]), ["A"])
    assert one.edges == [] and [(p.lambda_low, p.lambda_high, p.clusters) for p in one.partitions] == [(0.0, 1.0, [["A"]])]
    # zero similarity: the edge is cut from λ = 0 on ([0, 0) holds for no λ, so no partition joins them)
    zero = maximal_tree(np.eye(2), ["A", "B"])
    assert [(p.lambda_low, p.lambda_high, p.clusters) for p in zero.partitions] == [(0.0, 1.0, [["A"], ["B"]])]
    # signed similarity below 0 never joins for λ in [0, 1]
    neg = maximal_tree(np.array([[1.0, -0.5], [-0.5, 1.0]]), ["A", "B"], absolute=False)
    assert [(p.lambda_low, p.lambda_high, p.clusters) for p in neg.partitions] == [(0.0, 1.0, [["A"], ["B"]])]


def test_single_sensor_selection_and_plot(tmp_path):
    rng = np.random.default_rng(0)
    X = np.cumsum(rng.normal(size=(30, 1)), axis=0)
    y = 2 * X[:, 0] + 0.1 * rng.normal(size=30)
    sel = select("maxtree", (X, y, ["A"]))
    assert sel.sensors == ["A"]
    assert sel.plot(str(tmp_path / "one.png"))


# Li 2021 Table 6 (R² of the representative sets of Table 5, n = 8 slopes), Tables 7-8 (F, Sig. of sets 5 and 6)
LI2021_TABLE5 = [["T5"], ["T5", "T11"], ["T5", "T7", "T11"], ["T2", "T5", "T7", "T11"], ["T1", "T2", "T5", "T7", "T11"],
                 ["T1", "T2", "T5", "T7", "T9", "T11"], ["T1", "T2", "T5", "T6", "T7", "T9", "T11"]]
LI2021_TABLE6_R2 = [0.963, 0.963, 0.971, 0.989, 0.997, 0.999]


def _published_rows():
    """Rows as choose_partition takes them, F and Sig. recomputed from the published R² (n = 8) by the textbook
    formula F = (R²/k)/((1 − R²)/(n − k − 1)); sets of 7+ variables leave no residual degree of freedom."""
    from scipy import stats

    n, rows = 8, []
    for i, reps in enumerate(LI2021_TABLE5):
        k = len(reps)
        row = {"partition": i, "representatives": reps}
        if k + 1 >= n:
            row["skipped"] = "no residual degree of freedom"
        else:
            r2 = LI2021_TABLE6_R2[i]
            F = (r2 / k) / ((1 - r2) / (n - k - 1))
            row.update(r2=r2, F=F, p_F=float(stats.f.sf(F, k, n - k - 1)), min_tolerance=0.5)
        rows.append(row)
    return rows


def test_paper_rule_on_li2021_tables_6_to_8_picks_the_five_sensors():
    from host.learning.empirical.selectors.maxtree import choose_partition

    rows = _published_rows()
    # the recomputed significance agrees with the printed one: 0.008 for five variables, 0.058 for six
    assert rows[4]["p_F"] == pytest.approx(0.008, abs=0.001)
    assert rows[5]["p_F"] == pytest.approx(0.058, abs=0.002)
    chosen, reason = choose_partition(rows, 8)
    assert chosen["representatives"] == ["T1", "T2", "T5", "T7", "T11"]
    assert reason["criterion_name"] == "paper"
    # the earlier reading (forward F test of the R² change) keeps one sensor on the same numbers
    chosen, _ = choose_partition(_published_rows(), 8, criterion="r2-change")
    assert chosen["representatives"] == ["T5"]


def test_paper_rule_excludes_a_set_whose_variable_fails_spss_tolerance():
    from host.learning.empirical.selectors.maxtree import choose_partition

    rows = _published_rows()
    rows[4]["min_tolerance"], rows[4]["min_tolerance_sensor"] = 5e-5, "T11"  # five-sensor set now collinear
    chosen, _ = choose_partition(rows, 8)
    assert chosen["representatives"] == ["T2", "T5", "T7", "T11"]
    assert "tolerance exceeded" in rows[4]["skipped"] and "T11" in rows[4]["skipped"]


def test_paper_rule_on_data_skips_nearly_collinear_representatives():
    # C = A + 2B + tiny noise: the finest partition {A},{B},{C} has the best R² but C's tolerance is ~1e-7
    rng = np.random.default_rng(3)
    n = 80
    A, B = np.cumsum(rng.normal(size=n)), np.cumsum(rng.normal(size=n))
    Cs = A + 2 * B + 1e-3 * rng.normal(size=n)
    X = np.column_stack([A, B, Cs])
    y = A + 2 * B + 0.05 * rng.normal(size=n)
    names = ["A", "B", "C"]
    sel = select("maxtree", (X, y, names))
    r = sel.reason
    finest = [row for row in r["partitions"] if len(row["representatives"]) == 3][0]
    assert "tolerance exceeded" in finest["skipped"]
    # independent tolerance of C: 1 − R² of C on A and B
    M = np.column_stack([np.ones(n), A, B])
    res = Cs - M @ np.linalg.lstsq(M, Cs, rcond=None)[0]
    assert finest["min_tolerance"] == pytest.approx(res @ res / ((Cs - Cs.mean()) @ (Cs - Cs.mean())), rel=1e-6)
    assert len(sel.sensors) < 3
    # without the tolerance check the rule would take the finest set (largest R²)
    loose = select("maxtree", (X, y, names), min_tolerance=0.0)
    assert loose.sensors == names
    ok = [row for row in loose.reason["partitions"] if "skipped" not in row and row["p_F"] < 0.05]
    assert loose.reason["r2"] == max(row["r2"] for row in ok)


def test_intervals_are_written_as_li2021_table_3():
    # Table 3: [0, 0.94943) all together, [0.94943, 0.96927) T11 apart: at lambda = the edge weight the edge is cut
    C = np.array([[1.0, 0.95, 0.90], [0.95, 1.0, 0.85], [0.90, 0.85, 1.0]])
    tree = maximal_tree(C, ["T1", "T2", "T3"])
    assert tree.to_json()["interval_convention"].startswith("lambda in [lambda_low, lambda_high)")
    assert tree.partition_at(0.90) == [["T1", "T2"], ["T3"]]  # the 0.90 edge is cut at lambda = 0.90
    assert tree.partition_at(0.8999) == [["T1", "T2", "T3"]]
    assert tree.partition_at(1.0) == [["T1"], ["T2"], ["T3"]]
