"""Structure averaging of the dynamic model (host/learning/empirical/averaging.py, issue 21)."""
import numpy as np
import pytest

from firmware.table import parse_table
from host.data.runs import Errors, Run, Spindle, Temperatures
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.averaging import average, simplex
from host.learning.empirical.dynamic import DynamicRegression
from host.learning.empirical.fitting import fit_model

from models_export import export_model

from exactlag import exact_lag  # test-side physics, beside these tests
from dynopts import OBSERVER_ONLY


def _two_halves(n=800, blocks=4, seed=5):
    """y = x1 + x2 + noise, x1 and x2 independent: a structure of one of them explains half of y, the average of the
    two (weights 1/2) nearly all of it."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 2))
    y = X[:, 0] + X[:, 1] + 0.05 * rng.normal(size=n)
    groups = np.repeat(np.arange(blocks), n // blocks)
    return X, y, groups


def _one_term_search(X, y, groups, column, **settings):
    """The search restricted to one candidate column (max_terms 1): one structure per ridge value."""
    est = DynamicRegression(min_gain=0.0, max_terms=1, ridge=0.0, **settings)
    return est.fit(X[:, [column]], y, [(("T:a", "T:b")[column], 0.0)], groups)


def _forward_score_by_hand(X, y, groups, weights):
    """Pooled forward-chaining RMSE of sum_m w_m (a_m + b_m x_m), each member an ordinary least-squares line fitted on
    the blocks before the scored one (numpy lstsq, not the model's code)."""
    sq, n = 0.0, 0
    for k in np.unique(groups)[1:]:
        train, held = groups < k, groups == k
        pred = np.zeros(int(held.sum()))
        for m, w in enumerate(weights):
            A = np.column_stack([np.ones(int(train.sum())), X[train, m]])
            (a, b), *_ = np.linalg.lstsq(A, y[train], rcond=None)
            pred += w * (a + b * X[held, m])
        sq += float(((y[held] - pred) ** 2).sum())
        n += int(held.sum())
    return np.sqrt(sq / n)


def test_the_average_is_one_linear_model_whose_prediction_is_the_weighted_members_and_its_weights_are_forward_chosen():
    X, y, groups = _two_halves()
    a = _one_term_search(X, y, groups, 0)
    b = _one_term_search(X, y, groups, 1)
    anchor = a if a.cv_rmse_ <= b.cv_rmse_ else b
    terms = [("T:a", 0.0), ("T:b", 0.0)]
    averaged, record = average(anchor, X, y, terms, groups, [(a, [0]), (b, [1])], count=3)
    assert averaged is not None and record["members"] is not None
    # one linear model over the union of the terms; its prediction is the weighted sum of the members' predictions
    assert averaged.terms_ == [terms[c] for c in [[0, 1], [1, 0]][anchor is b]]
    w = averaged.weights
    assert w.sum() == pytest.approx(1.0) and (w > 0).all()
    members = {0: a, 1: b}
    order = [m["columns"][0] for m in averaged.members]
    by_members = sum(wi * members[c].predict(X[:, [c]]) for wi, c in zip(w, order))
    np.testing.assert_allclose(averaged.predict(X[:, averaged.union]), by_members, rtol=0, atol=1e-9)
    # the weights: the lowest forward-chaining score on the 0.1 grid, the score computed here independently
    grid = [np.array([v, 1 - v]) for v in np.linspace(0, 1, 11)]
    by_hand = [_forward_score_by_hand(X[:, order], y, groups, g) for g in grid]
    assert averaged.cv_rmse_ == pytest.approx(min(by_hand), rel=1e-9)
    np.testing.assert_allclose(w, grid[int(np.argmin(by_hand))], atol=1e-12)
    assert averaged.cv_rmse_ < 0.75 * anchor.cv_rmse_  # one structure leaves x2 (RMS 1), the average (x1 + x2) / 2 (RMS 0.71)
    # refitted on a fold's samples, the same weights combine the members' fold fits
    rows = groups < 2
    b0, coef = averaged.coefficients_on(rows)
    A = np.column_stack([np.ones(int(rows.sum())), X[rows][:, averaged.union]])
    fold = [np.linalg.lstsq(A[:, [0, 1 + i]], y[rows], rcond=None)[0] for i in range(2)]
    assert b0 == pytest.approx(sum(wi * f[0] for wi, f in zip(w, fold)), abs=1e-9)
    np.testing.assert_allclose(coef, [wi * f[1] for wi, f in zip(w, fold)], atol=1e-9)


def test_the_union_obeys_max_sensors_and_a_single_structure_is_kept_with_the_reason():
    X, y, groups = _two_halves()
    a = _one_term_search(X, y, groups, 0, max_sensors=1)
    b = _one_term_search(X, y, groups, 1, max_sensors=1)
    anchor = a if a.cv_rmse_ <= b.cv_rmse_ else b
    averaged, record = average(anchor, X, y, [("T:a", 0.0), ("T:b", 0.0)], groups, [(a, [0]), (b, [1])], count=3)
    assert averaged is None and "1 sensors" in record["why_single"]
    assert [c["within_limits_with_the_best"] for c in record["candidates"]] == [True, False]
    # averaging off: count 1 is the single best structure
    assert average(a, X, y, [("T:a", 0.0), ("T:b", 0.0)], groups, [(a, [0]), (b, [1])], count=1)[0] is None


def test_the_weight_grid_covers_the_simplex():
    grid = simplex(3)
    assert len(grid) == 66 and all(abs(g.sum() - 1) < 1e-12 and (g >= 0).all() for g in grid)
    assert grid[0].tolist() == [1.0, 0.0, 0.0]  # the single best structure is tried first (kept on a tie)


DT = 60.0


def _two_source_machine(hours=32.0):
    """Two heat sources with independent duty (on 2 h of every 4 h at changing power); t1 and t2 read them at once.
    The error is 4 x the 30 min lag of t1's rise plus 2.5 x t2's rise: the lag term explains the larger part, t2 the
    rest, t1 itself little (its steps are not the error's ramps)."""
    t = np.arange(0.0, hours * 3600.0, DT)
    q1, q2 = np.zeros(t.size), np.zeros(t.size)
    for k, (p1, p2) in enumerate(zip((1.0, 3.0, 2.0, 4.0, 1.5, 3.5, 2.5, 3.0), (2.0, 0.5, 3.5, 1.0, 3.0, 2.0, 0.8, 2.5))):
        q1[(t >= 14400 * k) & (t < 14400 * k + 7200)] = p1
        q2[(t >= 14400 * k + 5400) & (t < 14400 * k + 12600)] = p2
    t1 = 22.0 + 2.0 * q1
    t2 = 22.0 + 2.0 * q2
    err = 4.0 * exact_lag(t1 - t1[0], 1800.0, DT) + 2.5 * (t2 - t2[0])
    temps = Temperatures(t, ["t1", "t2"], np.column_stack([t1, t2]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {"t1": {"role": "structure"}, "t2": {"role": "structure"}}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), q1 * 1000), name="two_sources")


# the cycle blocks (4 h, each a running and a stopped phase) these tests were built on: the mechanics of averaging are
# under test, not the blocks (with the default phase blocks the static search's t2 no longer earns a weight); averaging
# is not combined with the settle bound or the worse-start scoring, the defaults since stop 35: the observer alone
OPTIONS = dict(target="direct", channel="ch1", taus_s=(0, 1800), use_spindle=False, max_terms=1, forward_state="continuous",
               forward_blocks="cycles", **OBSERVER_ONLY)


def test_fit_model_averages_a_dynamic_and_a_static_structure_and_records_it():
    """max_terms 1: the search over every term takes lag(t1, 30 min), the static search t2; the forward-chosen
    average of the two is one model of both terms that predicts the run better than either."""
    run = _two_source_machine()
    single = fit_model([run], "dynamic", **OPTIONS)
    avg = fit_model([run], "dynamic", average_structures=2, **OPTIONS)
    assert "structure_average" not in single.statistics  # the default: the single best structure
    sa = avg.statistics["structure_average"]
    assert len(sa["members"]) == 2 and sorted(avg.terms) == [("T:t1", 1800.0), ("T:t2", 0.0)]
    assert sa["averaged_score_um"] < sa["single_score_um"] == pytest.approx(single.statistics["cv_rmse"])
    assert avg.single_.terms == single.terms
    np.testing.assert_allclose(avg.single_.term_coefficients, single.term_coefficients, rtol=1e-9)
    # the reported forward-chaining score is the averaged model's own, refitted per block (predict, with the filters
    # running since the run start, as this selection scored them): it equals the score the weights were chosen by
    scored = avg.statistics["forward_chaining"]["scored"]
    continuous = np.sqrt(sum(f["n"] * f["continuous_rmse_um"] ** 2 for f in scored) / sum(f["n"] for f in scored))
    assert continuous == pytest.approx(sa["averaged_score_um"], rel=1e-6)
    truth = run.errors.error_um

    def rmse(model):
        return float(np.sqrt(np.mean((model.predict(run) - truth) ** 2)))

    assert rmse(avg) < 0.9 * rmse(single)  # 5.24 against 5.91 µm
    # the board runs it as any dynamic model: one table of kind 4 over the union, its observer fitted for the union
    assert avg.observer is not None and [avg.terms[st["term"]] for st in avg.observer.states] == [("T:t1", 1800.0)]
    table = parse_table(export_model(avg.to_document()).table)
    assert table.kind == "dynamic" and sorted(table.sensors) == ["t1", "t2"]
    with pytest.raises(EmpiricalDataError, match="average_structures must be an integer >= 1"):
        fit_model([run], "dynamic", average_structures=0, **OPTIONS)


def test_switched_on_the_averaged_score_is_the_boards_forward_chaining_score():
    """Scored as boards switched on at each block (the default), with the union's observer fitted on the blocks before
    it: the score the weights were chosen by equals the reported forward-chaining score, which comes from the model's
    own predict on each block cut out as its own run (a separate path)."""
    run = _two_source_machine()
    options = {k: v for k, v in OPTIONS.items() if k != "forward_state"}
    avg = fit_model([run], "dynamic", average_structures=3, **options)
    sa = avg.statistics["structure_average"]
    assert avg.statistics["forward_state"] == "switched_on" and len(sa["members"]) == 2
    assert avg.statistics["forward_chaining"]["pooled_um"] == pytest.approx(sa["averaged_score_um"], rel=1e-9)
    assert sa["averaged_score_um"] < sa["single_score_um"]


def test_tcomp_fit_takes_the_option_and_prints_the_members(tmp_path, capsys):
    import json

    from host.cli import main
    from host.data.runs import write_run

    folder = write_run(_two_source_machine(), str(tmp_path / "run"))
    args = ["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--option", "taus_s=0/1800", "--option", "max_terms=1",
            "--option", "use_spindle=false", "--option", "forward_state=continuous", "--option", "forward_blocks=cycles",
            "--option", "spindle_states=observer", "--option", "settle_max_s=none", "--out", str(tmp_path / "m.json")]
    assert main(args + ["--option", "average_structures=2"]) == 0
    out = capsys.readouterr().out
    assert "structure average of 2 structures" in out and "weight 0.80: lag(T:t1, tau 1800 s)" in out
    doc = json.loads((tmp_path / "m.json").read_text())
    assert [t["signal"] for t in doc["thermal"]["terms"]] == ["T:t1", "T:t2"]
    assert doc["statistics"]["structure_average"]["members"][1]["weight"] == pytest.approx(0.2)
    assert main(args + ["--option", "average_structures=0"]) == 2


def test_path_members_are_the_greedy_steps_that_ended_in_the_chosen_structure():
    """average_members=path: the structures after each step of the anchor's search, with the scores the search gave
    them; the last step is the chosen structure; averaged, they shrink the terms added last (one model, its terms
    those of the chosen structure)."""
    from host.learning.empirical.averaging import path_structures

    rng = np.random.default_rng(9)
    X = rng.normal(size=(800, 3))
    y = 2 * X[:, 0] + X[:, 1] + 0.3 * X[:, 2] + 0.5 * rng.normal(size=800)
    groups = np.repeat(np.arange(4), 200)
    terms = [("T:a", 0.0), ("T:b", 0.0), ("T:c", 0.0)]
    est = DynamicRegression(min_gain=0.0, ridge=0.0).fit(X, y, terms, groups)
    path = path_structures(est, terms)
    added = [h for h in est.history_ if h["action"] == "add"]
    assert len(path) == len(added) == 3 and est.history_[1]["term"] == ["T:a", 0.0]
    assert sorted(len(m["columns"]) for m in path) == [1, 2, 3]
    assert set(path[0]["columns"]) == set(est.selected_) and path[0]["score_um"] == pytest.approx(est.cv_rmse_)
    assert sorted(m["score_um"] for m in path) == sorted(h["cv_rmse"] for h in added)
    averaged, record = average(est, X, y, terms, groups, [(est, [0, 1, 2])], count=3, members_from="path")
    assert record["candidates"][0]["terms"] == [list(terms[j]) for j in est.selected_]
    # here 0.9 x (a, b, c) + 0.1 x (a, b): the union is the chosen structure's terms, c's coefficient shrunk
    assert averaged is not None and averaged.weights.tolist() == [0.9, 0.1] and set(averaged.union) == set(est.selected_)
    c = averaged.union.index(2)
    assert 0 < averaged.coef_[c] < est.coef_[est.selected_.index(2)]
    with pytest.raises(EmpiricalDataError, match="average_members must be one of ridge, path"):
        average(est, X, y, terms, groups, [(est, [0, 1, 2])], count=3, members_from="steps")
