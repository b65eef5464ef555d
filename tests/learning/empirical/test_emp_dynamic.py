"""Dynamic model: lag filters, structure chosen by cross-validation, document, command line, real data."""
import json
import os

import numpy as np
import pytest

from host.cli import main
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import DynamicRegression, _lag_filter_fast, candidate_matrix, features, lag_filter, signals
from host.learning.empirical.fitting import fit_model
from host.learning.documents import ModelFormatError, load_model
from models_export.document import FORMAT
from host.data.runs import Errors
from dynopts import OBSERVER_ONLY

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def test_lag_filter_is_exact_for_held_inputs():
    t = np.arange(0.0, 3600.0, 15.0)
    step = np.ones(t.size)
    # a unit step held from t = 0: y(t) = 1 − exp(−t/τ) at every sample, independently of the step size
    np.testing.assert_allclose(lag_filter(t, step, 600.0), 1 - np.exp(-t / 600.0), rtol=1e-12)
    # the scipy path on a uniform grid and the loop agree; a non-uniform grid takes the loop
    u = np.column_stack([np.sin(t / 300.0), (t > 900).astype(float)])
    np.testing.assert_allclose(_lag_filter_fast(t, u, 450.0), lag_filter(t, u, 450.0), atol=1e-12)
    tn = np.cumsum(np.r_[0.0, np.random.default_rng(0).uniform(5, 25, 200)])
    y = _lag_filter_fast(tn, np.ones(tn.size), 300.0)
    np.testing.assert_allclose(y, 1 - np.exp(-tn / 300.0), rtol=1e-12)
    np.testing.assert_array_equal(lag_filter(t, u, 0.0), u)


def _lagged_run(make_direct, noise=0.02):
    """A spindle run whose ch1 is 3·lag(t1 rise, 1 h) + 2·lag(krpm, 30 min): a static model cannot follow it."""
    run = make_direct(spindle=True, n_sensors=4, channels=("ch1",))
    t, sig = signals(run, ["t1"])
    y = 3 * lag_filter(t, sig["T:t1"], 3600) + 2 * lag_filter(t, sig["spindle_krpm"], 1800)
    y = y + np.random.default_rng(1).normal(0, noise, t.size)
    run.errors = Errors(t.copy(), np.zeros(t.size), y, None, np.array(["ch1"] * t.size, dtype=object))
    return run


def test_structure_and_time_constants_are_recovered(make_direct):
    """The search finds the true terms and time constants. Without the settle bound: the truth's 1 h lag of t1 is a state
    its observer estimates from t1's present reading only to within ~2 h of settling, so the default 30 min bound
    refuses it (asserted at the end: what the defaults give instead, and why)."""
    run = _lagged_run(make_direct)
    model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 900, 1800, 3600, 7200), settle_max_s=None)
    terms = dict(zip(model.terms, model.term_coefficients))
    assert terms[("T:t1", 3600.0)] == pytest.approx(3, rel=0.05)
    assert terms[("spindle_krpm", 1800.0)] == pytest.approx(2, rel=0.05)
    st = model.statistics
    # the default blocks: the ten 1 h phases (running, stopped); each is shorter than SWITCHED_ON_MIN_S (90 min), so the
    # selection scores them with the filters running since the run start (scored switched on, 1 h blocks lose the truth)
    assert st["cv_groups"] == 10 and st["rmse"] < 0.05 and st["history"][0]["action"] == "start"
    assert st["forward_scored_as"]["continuous_blocks"] == list(range(1, 10))
    assert model.sensors == ["t1"] and len(model.terms) == 2
    # the 2 h cycle blocks are long enough to be scored as a board switched on at each block: the truth again (a further
    # sensor may join as an input of the observer only: it helps estimate the lag states at the start; its gain stays ~0)
    # (the observer alone: scored by the worse of a start with and without the controller's record, the defaults since
    # stop 35, the truth's start without the record is off by up to 2.4 um on a block, and a structure that starts
    # better either way is chosen; docs/results.md "A second start for worse")
    cycles = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 900, 1800, 3600, 7200), forward_blocks="cycles",
                       **OBSERVER_ONLY)
    assert cycles.statistics["cv_groups"] == 5 and cycles.statistics["forward_scored_as"]["continuous_blocks"] == []
    by_term = dict(zip(cycles.terms, cycles.term_coefficients))
    assert by_term[("T:t1", 3600.0)] == pytest.approx(3, rel=0.05) and by_term[("spindle_krpm", 1800.0)] == pytest.approx(2, rel=0.05)
    assert cycles.sensors[0] == "t1"
    assert all(abs(c) < 0.02 for term, c in by_term.items() if term not in (("T:t1", 3600.0), ("spindle_krpm", 1800.0)))
    continuous = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 900, 1800, 3600, 7200), forward_state="continuous",
                           settle_max_s=None)
    assert continuous.sensors == ["t1"] and len(continuous.terms) == 2
    # a static MLR on all sensors cannot represent the lags
    static = fit_model([run], "mlr", target="direct", channel="ch1")
    assert static.statistics["rmse"] > 5 * st["rmse"]
    # the defaults (settle bound 30 min): the truth's observer settles too slowly, so it is refused and a structure that
    # settles within 30 min is the model, at a cost in fit the statistics show
    assert model.observer.settle_s > 1800
    bounded = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 900, 1800, 3600, 7200))
    assert bounded.statistics["settle_bound"]["settle_max_s"] == 1800 and bounded.observer.settle_s <= 1800
    assert bounded.statistics["settle_bound"]["structures_refused"] > 0 and ("T:t1", 3600.0) not in bounded.terms
    assert bounded.statistics["rmse"] > 5 * st["rmse"]


def test_sensor_limit_and_settings_are_enforced(make_direct):
    run = _lagged_run(make_direct)
    t = run.errors.time_s
    F, terms = candidate_matrix([run], [t], ["t1", "t2", "t3", "t4"], (0.0, 3600.0), use_spindle=False)
    assert [n for n, _ in terms] == ["T:t1", "T:t1", "T:t2", "T:t2", "T:t3", "T:t3", "T:t4", "T:t4"]
    groups = (t // 7200).astype(int)
    est = DynamicRegression(max_sensors=2, min_gain=0.0, max_terms=8).fit(F, run.errors.error_um, terms, groups)
    assert len({n for n, _ in est.terms_}) <= 2
    for kw, msg in (({"max_sensors": 0}, "max_sensors"), ({"cv_score": "mean"}, "cv_score"), ({"ridge": -1}, "ridge"),
                    ({"min_gain": 1.5}, "min_gain")):
        with pytest.raises(EmpiricalDataError, match=msg):
            DynamicRegression(**kw).fit(F, run.errors.error_um, terms, groups)
    with pytest.raises(EmpiricalDataError, match="at least 2 groups"):
        DynamicRegression(selection="loo").fit(F, run.errors.error_um, terms, np.zeros(t.size))
    with pytest.raises(EmpiricalDataError, match="at least 3 time blocks"):
        DynamicRegression().fit(F, run.errors.error_um, terms, (t > t[-1] / 2).astype(int))
    with pytest.raises(EmpiricalDataError, match="selection must be one of forward, loo"):
        DynamicRegression(selection="kfold").fit(F, run.errors.error_um, terms, groups)


def test_a_ridge_value_that_finds_no_term_does_not_stop_the_others():
    """y = 2u: with ridge 1e6 the term is shrunk to ~0 and lowers the forward-chaining score by less than min_gain (no
    structure for that value); ridge 0 finds it. The grid is tried in the order given, the hopeless value first: the
    search must go on to the next value (a real fit hit this: FL_THERMAL ch2 without its 3rd cycle, ridge 0-0.01 found
    no term, 0.1 did). Only when no value finds a term is it an error, naming the values tried."""
    rng = np.random.default_rng(4)
    u = rng.normal(size=(400, 1))
    y = 2.0 * u[:, 0] + 0.01 * rng.normal(size=400)
    groups = np.repeat(np.arange(4), 100)
    est = DynamicRegression(ridge=[1e6, 0.0]).fit(u, y, [("T:a", 0.0)], groups)
    assert est.ridge_ == 0.0 and est.cv_by_ridge_[1e6] is None and est.cv_by_ridge_[0.0] < 0.05
    assert est.coef_[0] == pytest.approx(2.0, rel=0.01)
    assert est.statistics()["cv_by_ridge"] == {"1000000.0": None, "0.0": pytest.approx(est.cv_by_ridge_[0.0])}
    with pytest.raises(EmpiricalDataError, match=r"no lag-filtered term lowers .* with any ridge value \(1e\+06, 1e\+07\)"):
        DynamicRegression(ridge=[1e6, 1e7]).fit(u, y, [("T:a", 0.0)], groups)


def test_a_search_started_from_a_given_structure_goes_on_from_it():
    """The greedy search is trapped when the best single term is not part of the best pair: y = a + b, and c = a + b +
    noise is the best term alone. From empty, without exchanges, the search keeps c and adds one of a, b. Started from
    (a, b) (with_start), it keeps them: exact. A start that scores worse than the empty structure is not kept, and a
    start term that is not a candidate is refused by name."""
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=600), rng.normal(size=600)
    c = a + b + 0.5 * rng.normal(size=600)
    y = a + b + 0.01 * rng.normal(size=600)
    X = np.column_stack([a, b, c])
    terms = [("T:a", 0.0), ("T:b", 0.0), ("T:c", 0.0)]
    groups = np.repeat(np.arange(4), 150)
    empty = DynamicRegression(max_terms=2, swaps=False, ridge=0.0).fit(X, y, terms, groups)
    assert ("T:c", 0.0) in empty.terms_ and empty.cv_rmse_ > 0.1
    started = DynamicRegression(max_terms=2, swaps=False, ridge=0.0).with_start([("T:a", 0), ("T:b", 0)]).fit(X, y, terms, groups)
    assert sorted(started.terms_) == [("T:a", 0.0), ("T:b", 0.0)] and started.cv_rmse_ < 0.02
    given = [h for h in started.history_ if h["action"] == "start_from"]
    assert given == [{"step": 1, "action": "start_from", "terms": [["T:a", 0.0], ["T:b", 0.0]], "cv_rmse": started.cv_rmse_, "kept": True}]
    # a start worse than no term at all (y against noise) is recorded and dropped; the search runs from empty
    noise = rng.normal(size=(600, 1))
    X2 = np.column_stack([X, noise])
    odd = DynamicRegression(max_terms=2, swaps=False, ridge=0.0).with_start([("T:n", 0.0)])
    odd.fit(X2, a, terms + [("T:n", 0.0)], groups)
    assert [h["kept"] for h in odd.history_ if h["action"] == "start_from"] == [False] and ("T:n", 0.0) not in odd.terms_
    with pytest.raises(EmpiricalDataError, match=r"start structure's term\(s\) \[\('T:z', 0.0\)\] are not among the candidates"):
        DynamicRegression().with_start([("T:z", 0.0)]).fit(X, y, terms, groups)


def test_document_round_trip_command_line_and_bad_documents(make_direct, tmp_path):
    from host.data.runs import write_run

    run = _lagged_run(make_direct)
    folder = write_run(run, str(tmp_path / "run"))
    out = str(tmp_path / "dyn.json")
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", "--sensors", "t1,t2", folder, "--out", out,
                 "--option", "taus_s=0/1800/3600/7200", "--option", "max_sensors=2"]) == 0
    doc = json.loads(open(out).read())
    # the default fit carries an observer, and then references the inputs to reference_C (issue 21)
    assert doc["kind"] == "dynamic" and doc["thermal"]["reference"] == "fixed" and doc["thermal"]["observer"]["states"]
    assert set(doc["sensors"]) <= {"t1", "t2"} and doc["training"]["candidate_sensors"] == ["t1", "t2"]
    assert main(["predict", out, folder, "--out", str(tmp_path / "p.csv"), "--json", str(tmp_path / "p.json")]) == 0
    # predict from the document reproduces the fit on its training run (a cold start: the observer's start is the rest)
    # (the structure is chosen for boards switched on at each cycle, so it need not be the truth: test_emp_forward.py)
    assert json.loads(open(str(tmp_path / "p.json")).read())["rmse_um"] == pytest.approx(doc["statistics"]["rmse"], rel=1e-3)
    # without an observer: rises over the run's start, filters from rest
    plain = str(tmp_path / "plain.json")
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", "--sensors", "t1,t2", folder, "--out", plain,
                 "--option", "taus_s=0/1800/3600/7200", "--option", "max_sensors=2", "--option", "observer=false"]) == 0
    assert "observer" not in json.loads(open(plain).read())["thermal"]
    model = load_model(plain)
    np.testing.assert_allclose(model.predict(run), model.intercept + features(run, model.terms, run.errors.time_s) @ model.term_coefficients)
    for mutate, msg in ((lambda d: d["thermal"]["terms"][0].update(signal="rpm"), "signal"),
                        (lambda d: d["thermal"]["terms"][0].update(tau_s=-1), "tau_s"),
                        (lambda d: d["thermal"].update(reference="run_start"), "'fixed'"),
                        (lambda d: d["thermal"]["observer"].update(method="kalman"), "static_state_estimate"),
                        (lambda d: d["thermal"]["observer"]["states"].pop(), "one object per lag term"),
                        (lambda d: d["thermal"]["observer"]["states"][0].update(bound=-1), "bound"),
                        (lambda d: d["thermal"]["observer"].update(scale=0), "scale"),
                        (lambda d: d["thermal"]["observer"]["states"][0]["gains"].update(t9=1.0), "gains"),
                        (lambda d: d["thermal"].update(terms=[]), "non-empty")):
        bad = json.loads(open(out).read())
        mutate(bad)
        with pytest.raises(ModelFormatError, match=msg):
            load_model(bad)
    # a run without the spindle log cannot feed a model that uses it: a clear error, exit 2
    run.spindle = None
    nospin = write_run(run, str(tmp_path / "nospin"))
    assert main(["predict", out, nospin, "--out", str(tmp_path / "q.csv")]) == 2
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "taus_s=a"]) == 2


def test_slope_target_multiplies_by_position(make_slope):
    run = make_slope(n_sweeps=30, noise_um=0.01, duration_s=28800.0)
    model = fit_model([run], "dynamic", target="slope", taus_s=(0, 3600), cv_blocks=3)
    doc = model.to_document()
    back = load_model(dict(doc, format=FORMAT))
    e = run.errors
    expect = back.geometric(e.position_mm) + back.thermal_at(run, e.time_s) * e.position_mm
    np.testing.assert_allclose(back.predict(run), expect)
    assert back.target == "slope" and doc["geometric"]["degree"] >= 1


def test_real_fl_thermal_dynamic_beats_static_on_the_held_out_cycles():
    """One fast real-data check: trained on the first three cycles with a small time-constant grid,
    the dynamic model predicts the held-out cycles of ch1 better than MLR on all 16 sensors."""
    from host.learning.empirical.scoring import score_model
    from host.data.runs import load_run

    run = load_run(os.path.join(ROOT, "data", "fl_thermal"))
    split = 86865.0  # start of the 4th spindle cycle (32.1 h)
    # the structure chosen by leave-one-cycle-out (selection=loo): with three training cycles forward chaining scores two blocks,
    # the first fitted on one cycle; the default selection is measured by tools/results_forward.py (docs/results.md);
    # the observer alone, as this check was made (the settle bound and the worse-start scoring: the same file)
    dyn = fit_model([run], "dynamic", target="direct", channel="ch1", window=(None, split), taus_s=(0, 1800, 14400), max_terms=4, ridge=0.0,
                    selection="loo", **OBSERVER_ONLY)
    mlr = fit_model([run], "mlr", target="direct", channel="ch1", window=(None, split), reference="run_start")
    d, m = score_model(dyn, run, (split, None))["rmse_um"], score_model(mlr, run, (split, None))["rmse_um"]
    assert d < 0.8 * m, (d, m)


def test_compare_runs_the_dynamic_model_with_its_settings(make_direct, tmp_path):
    from host.data.runs import write_run

    folder = write_run(_lagged_run(make_direct), str(tmp_path / "run"))
    out = str(tmp_path / "cmp.json")
    base = ["compare", folder, "--split-h", "7", "--direct", "--channel", "ch1", "--methods", "mlr,dynamic", "--repeats", "1", "--json", out]
    assert main(base + ["--option", "dynamic.taus_s=[0,1800,3600]", "--option", "dynamic.max_sensors=1"]) == 0
    res = {r["method"]: r for r in json.loads(open(out).read())["results"]}
    assert res["dynamic"]["n_sensors"] == 1 and res["dynamic"]["mean_test_rmse_um"] < res["mlr"]["mean_test_rmse_um"]
    assert main(base + ["--option", "dynamic.bogus=1"]) == 2


ISSUE16 = {"selection": "loo", "ridge": (0.0, 1e-3, 1e-2), "tau_max_fraction": 1.0,  # the dynamic model's choice before issue 21
           **OBSERVER_ONLY}


@pytest.mark.slow
def test_goal_leave_one_cycle_out_at_most_0p8_of_mlr16():
    """Issue 16's goal on the real FL_THERMAL test: under leave-one-cycle-out over all six spindle cycles
    (every choice made inside each fold), the dynamic model chosen as before issue 21 (selection=loo, ridge grid
    0/0.001/0.01, no lag bound) has a pooled held-out RMSE at most 0.8 x that of MLR on all 16 sensors. CI checks
    ch4, the closest channel (0.75); TCOMP_SLOW=1 all five. Issue 21's defaults give 0.37 0.47 0.76 0.86 0.95 here
    (and 0.80 on ch4 with selection=loo alone): docs/results.md, issue 21 section."""
    from host.learning.empirical.compare import leave_one_cycle_out
    from host.data.runs import load_run

    run = load_run(os.path.join(ROOT, "data", "fl_thermal"))
    channels = ["ch1", "ch2", "ch3", "ch4", "ch5"] if os.environ.get("TCOMP_SLOW") == "1" else ["ch4"]
    ratios = {}
    for ch in channels:
        out = leave_one_cycle_out(run, channel=ch, methods=("mlr", "dynamic"), options={"dynamic": ISSUE16})
        assert len(out["cycles"]) == 6 and len(out["methods"]["dynamic"]["folds"]) == 6
        # each fold's lag terms are reported (a dynamic model's; none for MLR), and they are that fold's own choice
        terms = out["methods"]["dynamic"]["terms"]
        assert out["methods"]["mlr"]["terms"] == [None] * 6 and len(terms) == 6
        assert all(t and {s[2:] for s, _, _ in t if s.startswith("T:")} <= set(sens)
                   for t, sens in zip(terms, out["methods"]["dynamic"]["sensors"])), terms
        assert len({tuple(map(tuple, t)) for t in terms}) > 1, terms  # refitted per fold, not one model six times
        # and each fold's own forward-chaining score (the criterion its structure was chosen by), none for MLR
        chained = out["methods"]["dynamic"]["forward_chaining"]
        assert out["methods"]["mlr"]["forward_chaining"] == [None] * 6
        assert all(fc["pooled_um"] > 0 and "scored" not in fc for fc in chained), chained
        ratios[ch] = out["ratio_to_mlr"]["dynamic"]
    assert all(r <= 0.8 for r in ratios.values()), ratios
