"""Forward-chaining validation (issue 21): blocks in time order, folds that never see the scored block, the switched-on
score equal to the model's own predict, the statistics in fit/compare JSON, the lag bound, and run slicing."""
import json

import numpy as np
import pytest

from host.cli import main
from host.data.runs import Errors, Run, Spindle, Temperatures, slice_run, write_run
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import DynamicModel, DynamicRegression, lag_filter, signals
from host.learning.empirical.fitting import SWITCHED_ON_MIN_S, fit_model
from host.learning.empirical.forward import block_run, folds, forward_blocks, observer_block_columns
from host.learning.empirical.observer import fit_observer
from host.learning.empirical.targets import training_arrays

from exactlag import exact_lag  # test-side physics, beside these tests

TAUS = (0.0, 1800.0, 3600.0)


def _lagged_run(make_direct):
    """ch1 = 3·lag(t1 rise, 1 h) + 2·lag(krpm, 30 min) + noise, five spindle cycles of 2 h."""
    run = make_direct(spindle=True, n_sensors=3, channels=("ch1",))
    t, sig = signals(run, ["t1"])
    y = 3 * lag_filter(t, sig["T:t1"], 3600) + 2 * lag_filter(t, sig["spindle_krpm"], 1800)
    y = y + np.random.default_rng(1).normal(0, 0.02, t.size)
    run.errors = Errors(t.copy(), np.zeros(t.size), y, None, np.array(["ch1"] * t.size, dtype=object))
    return run


def test_blocks_are_the_cycles_in_time_order_and_folds_train_on_the_past_only(make_direct):
    run = _lagged_run(make_direct)
    arrays = training_arrays([run], "direct", "ch1")
    assert len(forward_blocks([run], arrays)[1]) == 10  # the default: ten 1 h phases (test_emp_phase_blocks.py)
    labels, blocks = forward_blocks([run], arrays, "cycles")
    t = arrays[0].time_s
    assert [b["block"] for b in blocks] == list(range(5))  # five spindle cycles
    assert all(a["t_end_s"] < b["t_start_s"] for a, b in zip(blocks, blocks[1:]))
    assert np.all(np.diff(labels) >= 0)  # labels ascend with time
    fs = folds(labels)
    assert [k for k, _, _ in fs] == [1, 2, 3, 4]
    for k, train, scored in fs:
        assert train.any() and scored.any() and not (train & scored).any()
        assert t[train].max() < t[scored].min()  # the fit never sees the scored block, nor anything after it
    # N equal time blocks on request; too few blocks are refused, naming the rule
    labels4, _ = forward_blocks([run], arrays, forward_blocks=4)
    assert np.unique(labels4).tolist() == [0, 1, 2, 3]
    with pytest.raises(EmpiricalDataError, match="forward_blocks must be an integer >= 3"):
        forward_blocks([run], arrays, forward_blocks=2)


def test_a_relation_that_changes_in_the_last_block_is_scored_as_unpredictable():
    """y = u in the first blocks and −u in the last: a fold fitted on the past predicts +u there (RMSE 2·rms(u)).
    A leaky split whose training includes the scored block would fit part of the sign change and score lower."""
    rng = np.random.default_rng(3)
    n = 400
    u = np.sin(np.arange(n) / 7.0) + 0.1 * rng.normal(size=n)
    blocks = np.repeat(np.arange(4), n // 4)
    y = np.where(blocks == 3, -u, u)
    est = DynamicRegression(min_gain=0.0, max_terms=1, ridge=0.0, fit_intercept=False).fit(u[:, None], y, [("T:a", 0.0)], blocks)
    assert est.fold_labels_ == [1, 2, 3]
    last = blocks == 3
    assert est.fold_rmse_[-1] == pytest.approx(2 * np.sqrt(np.mean(u[last] ** 2)), rel=1e-9)
    assert est.fold_rmse_[0] == pytest.approx(0.0, abs=1e-9)
    # the assertion discriminates: a fit that had seen the last block would score it lower
    b_leaky = float(u @ y) / float(u @ u)
    assert np.sqrt(np.mean((y[last] - b_leaky * u[last]) ** 2)) < 0.9 * est.fold_rmse_[-1]
    # leave-one-out fits the first group on the later ones, the changed last block among them: it sees the future
    loo = DynamicRegression(min_gain=0.0, max_terms=1, ridge=0.0, fit_intercept=False, selection="loo").fit(u[:, None], y, [("T:a", 0.0)], blocks)
    assert loo.fold_rmse_[0] > 0.2


def test_switched_on_selection_scores_blocks_as_the_models_own_predict_does(make_direct):
    """The selection's switched-on columns are the ones predict computes on the block as its own run: the score the
    structure was chosen by equals the reported forward-chaining score from predict, block by block, with the observer
    (the default: each block's filters start at the estimate of an observer fitted on the blocks before it) and without
    it (filters from rest)."""
    run = _lagged_run(make_direct)
    for observer in (True, False):
        # the 2 h cycles: every block lasts >= SWITCHED_ON_MIN_S, so every block is scored switched on
        # scored with the controller's record where it supplies states (the worse-start scoring, the default with the
        # observer since stop 35, chooses by the worse of two starts: tests/learning/empirical/test_emp_controller.py)
        pinned = {"controller_scoring": "record"} if observer else {}
        model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=TAUS, observer=observer, forward_blocks="cycles",
                          **pinned)
        st = model.statistics
        assert st["selection"] == "forward" and st["forward_state"] == "switched_on"  # the default since issue 21's fwdsel
        assert (model.observer is not None) is observer
        fc = st["forward_chaining"]
        assert [f["block"] for f in fc["scored"]] == model.estimator_.fold_labels_ == [1, 2, 3, 4]
        assert st["forward_scored_as"]["continuous_blocks"] == []
        np.testing.assert_allclose(model.estimator_.fold_rmse_, fc["rmse_um"], rtol=1e-8)
        assert all(f["rmse_um"] != f["continuous_rmse_um"] for f in fc["scored"])
    # the block run starts at the block: its filters and rises start there, unlike the continuous run's
    b = {"block": 2, "run": 0, "t_start_s": 14400.0, "t_end_s": 21540.0}
    cut = block_run([run], b)
    assert cut.temperatures.time_s[0] == 14400.0 and cut.temperatures.time_s[-1] >= 21540.0


def test_a_block_shorter_than_the_settle_window_allows_is_scored_with_continuous_filters(make_direct):
    """With forward_state=switched_on a block under SWITCHED_ON_MIN_S (90 min) is scored with its filters running since
    the run start, the others as a board switched on at their start: block by block, the score the structure was chosen
    by equals the reported forward-chaining score of that kind (predict on the whole run, or on the block as its own
    run). Cycles cut at 9.25 h: four 2 h blocks and a last one of 1.25 h (over a quarter of 2 h, so not merged)."""
    run = _lagged_run(make_direct)
    model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=TAUS, forward_blocks="cycles",
                      window=(None, 9.25 * 3600), controller_scoring="record")  # with the record: as the test above
    st = model.statistics
    assert st["forward_scored_as"]["switched_on_min_s"] == SWITCHED_ON_MIN_S == 5400.0
    assert st["forward_scored_as"]["continuous_blocks"] == [4]
    fc = st["forward_chaining"]
    assert [f["block"] for f in fc["scored"]] == model.estimator_.fold_labels_ == [1, 2, 3, 4]
    assert fc["scored"][-1]["t_end_s"] - fc["scored"][-1]["t_start_s"] < SWITCHED_ON_MIN_S
    assert all(f["t_end_s"] - f["t_start_s"] >= SWITCHED_ON_MIN_S for f in fc["scored"][:-1])
    chosen_by = model.estimator_.fold_rmse_
    np.testing.assert_allclose(chosen_by[:3], fc["rmse_um"][:3], rtol=1e-8)  # switched on
    np.testing.assert_allclose(chosen_by[3], fc["scored"][3]["continuous_rmse_um"], rtol=1e-8)  # continuous
    assert abs(chosen_by[3] - fc["rmse_um"][3]) > 1e-3 * fc["rmse_um"][3]  # the two scores of that block differ


REF_C = 22.0
DT = 60.0


def _exact_lag(u, tau, y0=0.0):
    return exact_lag(u, tau, DT, y0)


def _source_machine(hours=32.0):
    """A heat source running 2 h in every 4 h at changing power; sensor t1 sits at the source (10 min behind it), t2
    reads the ambient; the error is 4 h behind the source. So the error's state is a 4 h lag of t1, which the model can
    represent exactly but which no instant of t1, t2 tells at a switch-on (each block starts as the source starts, with
    t1 near ambient and the structure still warm from the cycles before)."""
    t = np.arange(0.0, hours * 3600.0, DT)
    q = np.zeros(t.size)
    for k, power in enumerate((1.0, 3.0, 2.0, 4.0, 1.5, 3.5, 2.5, 3.0)):
        q[(t >= 14400 * k) & (t < 14400 * k + 7200)] = power
    t1 = REF_C + 2.0 * _exact_lag(q, 600.0)
    t2 = REF_C + 0.4 * np.sin(2 * np.pi * t / 21600.0)
    err = 4.0 * _exact_lag(t1 - REF_C, 14400.0)
    temps = Temperatures(t, ["t1", "t2"], np.column_stack([t1, t2]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {"t1": {"role": "structure"}, "t2": {"role": "ambient"}}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), q * 1000), name="source")


SPLIT = 24 * 3600.0
# no settle bound (a default since stop 35): it would refuse the true 4 h lag in every selection, continuous too, and
# these tests are about what the switched-on scoring itself does
SOURCE = dict(target="direct", channel="ch1", window=(None, SPLIT), taus_s=(0, 1800, 3600, 14400), use_spindle=False, settle_max_s=None)


def test_switched_on_columns_with_the_observer_are_the_boards_prediction():
    """The selection's switched-on column of a structure (filter from rest + the observer's start decaying) equals what
    a board with that structure computes: DynamicModel.predict on the block cut out as its own run (slice_run), its
    filters started by observer.board_terms from an observer fitted here on the blocks before it, a separate path."""
    run = _source_machine()
    model = fit_model([run], "dynamic", **SOURCE)
    est = model.estimator_
    arrays = training_arrays([run], "direct", "ch1", window=(None, SPLIT))
    labels, blocks = forward_blocks([run], arrays)
    t = arrays[0].time_s
    # the columns of the chosen terms only (the candidates = the model's terms), their starts from their own observer
    started = observer_block_columns([run], arrays, labels, blocks, model.terms, model.reference_C, "direct", "ch1")
    lagged = [j for j, (_, tau) in enumerate(model.terms) if tau > 0]
    assert lagged  # a structure with states, or there is nothing to start
    warm_starts = 0.0
    for b in blocks[1:]:
        k = b["block"]
        b0, coef = est.coefficients_on(labels < k)
        cols = started[k].columns(range(len(model.terms)))
        board = DynamicModel(model.terms, coef, b0, "direct", "ch1", reference_C=model.reference_C)
        board.observer = fit_observer(board, [run], spans=[(t[labels < k].min(), t[labels < k].max())])
        cut = slice_run(run, b["t_start_s"], b["t_end_s"] + DT)
        predicted = board.predict(cut)
        assert predicted.size == cols.shape[0] == int((labels == k).sum())
        np.testing.assert_allclose(b0 + cols @ coef, predicted, rtol=0, atol=1e-9)
        warm_starts = max(warm_starts, float(np.abs(started[k].start(lagged)).max()))
    assert warm_starts > 0.1  # the observer started the states away from rest: the decaying part was exercised


def test_switched_on_scoring_drops_a_lag_the_sensors_cannot_recover_and_predicts_the_next_block_better():
    """On the source machine a continuously scored selection finds the true 4 h lag; scored as a board switched on at
    each block with its observer, the 4 h state is not recoverable from t1 and t2 at the start and the selection takes
    shorter lags instead, which predict the block after the training better on a board switched on there."""
    run = _source_machine()
    continuous = fit_model([run], "dynamic", forward_state="continuous", **SOURCE)
    switched = fit_model([run], "dynamic", **SOURCE)
    assert switched.statistics["forward_state"] == "switched_on"
    assert ("T:t1", 14400.0) in continuous.terms
    np.testing.assert_allclose(continuous.term_coefficients[continuous.terms.index(("T:t1", 14400.0))], 4.0, rtol=0.01)
    assert all(tau < 14400.0 for _, tau in switched.terms)
    cut = slice_run(run, SPLIT)
    truth = cut.errors.error_um

    def rmse(model):
        return float(np.sqrt(np.mean((model.predict(cut) - truth) ** 2)))

    assert rmse(switched) < 0.75 * rmse(continuous)
    # and the reported baseline is on the same blocks: a plain MLR on both sensors, refitted per block
    fc = switched.statistics["forward_chaining"]
    base = fc["baseline_mlr_all"]
    assert base["sensors"] == ["t1", "t2"] and len(base["rmse_um"]) == len(fc["rmse_um"])
    assert fc["beats_baseline"] == (fc["pooled_um"] < base["pooled_um"])


def test_a_baseline_that_cannot_be_fitted_is_said_not_fatal(make_slope):
    """A slope run of 12 sweeps cut into 4 blocks: the first block has 3 sweeps, fewer than MLR on all 4 sensors needs;
    the dynamic fit stands and its statistics say why the baseline is missing (tcomp compare ran into this)."""
    run = make_slope(name="r0", seed=0, noise_um=0.05)
    model = fit_model([run], "dynamic", target="slope")
    fc = model.statistics["forward_chaining"]
    assert len(fc["rmse_um"]) == 3 and fc["beats_baseline"] is None
    assert "3 samples for 5 parameters" in fc["baseline_mlr_all"]["error"]


def test_forward_chaining_statistics_in_fit_and_compare_json(make_direct, tmp_path, capsys):
    folder = write_run(_lagged_run(make_direct), str(tmp_path / "run"))
    out = str(tmp_path / "dyn.json")
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "taus_s=0/1800/3600"]) == 0
    # the 1 h phases are under 90 min: tcomp fit says they were scored with continuous filters
    printed = capsys.readouterr().out
    assert "blocks 1,2,3,4,5,6,7,8,9 scored with the filters running since the run start: shorter than 90 min" in printed
    fc = json.loads(open(out).read())["statistics"]["forward_chaining"]
    assert fc["blocks"] == 10 and len(fc["rmse_um"]) == 9 and fc["worst_um"] == max(fc["rmse_um"])  # ten 1 h phases
    n = [f["n"] for f in fc["scored"]]
    assert fc["pooled_um"] == pytest.approx(np.sqrt(sum(k * r ** 2 for k, r in zip(n, fc["rmse_um"])) / sum(n)))
    # the block with the largest squared error and its share of the pooled one, recomputed from the per-block figures
    sq = {f["block"]: f["n"] * f["rmse_um"] ** 2 for f in fc["scored"]}
    top = max(sq, key=lambda b: sq[b])
    assert fc["largest_share"] == {"block": top, "share": pytest.approx(sq[top] / sum(sq.values()))}
    assert 1 / 9 < fc["largest_share"]["share"] < 1
    assert "  block %d carries %.0f %% of the pooled squared error" % (top, 100 * sq[top] / sum(sq.values())) in printed
    assert "switched on" in fc["rule"]
    mlr = str(tmp_path / "mlr.json")
    assert main(["fit", "--model", "mlr", "--direct", "--channel", "ch1", folder, "--out", mlr]) == 0
    assert len(json.loads(open(mlr).read())["statistics"]["forward_chaining"]["rmse_um"]) == 9
    cmp = str(tmp_path / "cmp.json")
    assert main(["compare", folder, "--split-h", "8.5", "--direct", "--channel", "ch1", "--methods", "mlr,dynamic", "--repeats", "1",
                 "--option", "dynamic.taus_s=[0,1800,3600]", "--json", cmp]) == 0
    res = {r["method"]: r for r in json.loads(open(cmp).read())["results"]}
    for m in ("mlr", "dynamic"):
        # t < 8.5 h: eight 1 h phases and the last 30 min (a quarter of the longest or more: its own block), 8 scored
        assert len(res[m]["forward_chaining"]["rmse_um"]) == 8, m


def test_lags_beyond_a_quarter_of_the_training_span_are_excluded(make_direct):
    run = _lagged_run(make_direct)  # 10 h: lags up to 2.5 h
    model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 3600, 14400, 28800))
    lb = model.statistics["lag_bound"]
    assert lb["max_tau_s"] == pytest.approx(0.25 * (run.errors.time_s.max() - run.errors.time_s.min()))
    assert lb["excluded_taus_s"] == [14400.0, 28800.0]
    assert all(tau <= lb["max_tau_s"] for _, tau in model.terms)
    assert model.training["taus_s"] == [0.0, 3600.0]
    with pytest.raises(EmpiricalDataError, match="exceeds .* the longest the training span"):
        fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(14400,))
    # a larger fraction admits the 4 h lag, and says so
    wide = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 3600, 14400), tau_max_fraction=0.5)
    assert wide.statistics["lag_bound"]["excluded_taus_s"] == [] and 14400.0 in wide.training["taus_s"]


def test_slice_run_is_a_board_switched_on_at_the_cut(make_direct):
    run = _lagged_run(make_direct)
    cut = slice_run(run, 7230.0, 14400.0)
    assert cut.temperatures.time_s[0] == 7260.0 and cut.temperatures.time_s[-1] == 14340.0  # 60 s samples at or after the cut
    assert cut.errors.time_s[0] == 7260.0
    rows = (run.errors.time_s >= 7260.0) & (run.errors.time_s < 14400.0)
    np.testing.assert_array_equal(cut.errors.error_um, run.errors.error_um[rows])  # errors keep the run's reference
    # the spindle speed in force at the cut (2000 rpm from 7800 s; at 7260 s it stands) and every change inside
    assert cut.spindle.time_s[0] == 7260.0 and cut.spindle.rpm[0] == 0.0
    late = slice_run(run, 8000.0)
    assert late.spindle.rpm[0] == 2000.0 and late.spindle.time_s[0] == 8040.0
    with pytest.raises(ValueError, match="at least 2"):
        slice_run(run, 35990.0)


def test_the_static_search_is_compared_on_the_same_score_and_the_lower_one_is_the_model(make_direct):
    """statistics.static_fallback: the search over every term against the same search over the static (tau 0) terms,
    both scored as boards switched on at each block; the model is the lower one (here the dynamic one: the truth has
    lags), and the record says so; static_fallback=false leaves it out."""
    run = _lagged_run(make_direct)
    model = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=TAUS)
    fb = model.statistics["static_fallback"]
    static = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0.0,))
    assert fb["dynamic_score_um"] == pytest.approx(model.statistics["cv_rmse"])
    assert fb["static_score_um"] == pytest.approx(static.statistics["cv_rmse"])  # the same search, tau 0 alone
    assert fb["chosen"] == "dynamic" and fb["dynamic_score_um"] < fb["static_score_um"]
    assert any(tau > 0 for _, tau in model.terms)
    off = fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=TAUS, static_fallback=False)
    assert "static_fallback" not in off.statistics and off.terms == model.terms
    with pytest.raises(EmpiricalDataError, match="static_fallback must be true or false"):
        fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=TAUS, static_fallback="yes")


def test_tcomp_fit_prints_the_baseline_and_warns_when_the_dynamic_model_loses_to_it(make_direct, tmp_path, capsys):
    """ch1 = 0.4 − 3·rise(t1) + 1.5·rise(t2): one term (max_terms=1) cannot follow it, MLR on all sensors can; tcomp
    fit says so on stderr. On a run whose error lags (no MLR can follow it), no warning."""
    folder = write_run(make_direct(spindle=True, n_sensors=3, channels=("ch1",), noise_um=0.01), str(tmp_path / "run"))
    base = ["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--option", "taus_s=0/1800"]
    assert main(base + ["--out", str(tmp_path / "one.json"), "--option", "max_terms=1"]) == 0
    out, err = capsys.readouterr()
    assert "baseline on the same blocks, MLR on all 3 candidate sensors" in out
    assert "warning: the dynamic model predicts the next block worse than MLR on all 3 candidate sensors" in err
    assert json.loads(open(str(tmp_path / "one.json")).read())["statistics"]["forward_chaining"]["beats_baseline"] is False
    lagged = write_run(_lagged_run(make_direct), str(tmp_path / "lagged"))
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", lagged, "--option", "taus_s=0/1800/3600",
                 "--out", str(tmp_path / "two.json")]) == 0
    out, err = capsys.readouterr()
    assert "baseline on the same blocks" in out and "warning" not in err
