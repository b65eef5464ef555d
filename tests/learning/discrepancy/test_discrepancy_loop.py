import numpy as np
import pytest

from host.learning.discrepancy import workflow
from host.learning.discrepancy.workflow import discover, make_folds


def test_hidden_ambient_named_first_and_gap_halved(make, toy_family):
    runs = [make(100 + i, "r%d" % i, ambient_um_per_K=4.0) for i in range(3)]
    res = discover(runs, toy_family, jobs=1)
    assert res.effects[:1] == ["ambient"]
    assert res.after.rmse() < 0.5 * res.before.rmse()
    js = res.as_json()
    assert js["effects"] == res.effects
    assert {c["name"] for c in js["candidates"]} == set(toy_family.candidates)
    acc = [c for c in js["candidates"] if c["accepted"]]
    assert [c["name"] for c in acc] == res.effects
    assert all(c["p_value"] < workflow.ALPHA for c in acc)
    assert len(js["per_run"]) == 3 and all(r["rmse_after_um"] < r["rmse_before_um"] for r in js["per_run"])


def test_two_hidden_effects_both_named(make, toy_family):
    runs = [make(200 + i, "r%d" % i, ambient_um_per_K=3.0, reversal_um=4.0) for i in range(3)]
    res = discover(runs, toy_family, jobs=1)
    assert set(res.effects) == {"ambient", "reversal"}
    assert len(res.rounds) == 3  # two accepted rounds and one that finds nothing more


def test_nothing_hidden_nothing_named(make, toy_family):
    falses = 0
    for seed in range(8):
        runs = [make(1000 * seed + i, "r%d" % i) for i in range(3)]
        falses += bool(discover(runs, toy_family, jobs=1).effects)
    assert falses == 0


def test_reversal_skipped_without_bidirectional_sweeps(make, toy_family):
    runs = [make(300 + i, "r%d" % i, bidirectional=False) for i in range(2)]
    res = discover(runs, toy_family, jobs=1)
    rev = [c for c in res.rounds[0].candidates if c.name == "reversal"][0]
    assert rev.skipped and "bidirectional" in rev.skipped
    assert res.as_json()["candidates"]


def test_single_run_uses_time_split(make, toy_family):
    run = make(400, "solo", ambient_um_per_K=4.0, n_sweeps=40)
    folds = make_folds([run])
    assert len(folds) == 2
    a, b = folds[0].test[0], folds[1].test[0]
    assert not np.any(a & b) and np.all(a | b)
    assert run.errors.time_s[a].max() < run.errors.time_s[b].min()
    res = discover([run], toy_family, jobs=1)
    assert res.effects[:1] == ["ambient"]
    assert np.all(np.isfinite(res.before.residuals[0]))


def test_parallel_equals_serial(make, toy_family):
    runs = [make(500 + i, "r%d" % i, reversal_um=3.0) for i in range(2)]
    a = discover(runs, toy_family, jobs=1).as_json()
    b = discover(runs, toy_family, jobs=2).as_json()
    assert a["effects"] == b["effects"]
    assert a["rmse_after_um"] == pytest.approx(b["rmse_after_um"], rel=1e-12)


def test_max_effects_stops_and_keeps_the_tested_figures(make, toy_family):
    runs = [make(600 + i, "r%d" % i, ambient_um_per_K=3.0, reversal_um=4.0) for i in range(3)]
    res = discover(runs, toy_family, jobs=1, max_effects=1)
    assert len(res.effects) == 1
    js = res.as_json()
    assert all(c["rmse_um"] is not None for c in js["candidates"])
    assert sum(c["accepted"] for c in js["candidates"]) == 1
