"""Lag states the controller supplies (dynamic option ``spindle_states=controller``, issue 21).

The machine below is written here, independently of the model's filters: the spindle is the heat source (2 h running
in every 4 h at changing speeds), sensor t1 sits at it (10 min behind), t2 reads the ambient, and the error is 4 h
behind the source. No instant of t1 and t2 tells the 4 h state at a switch-on; the spindle's past does, and the
controller, which commands the spindle, has it. Exact solution for a speed held between samples: exactlag.py.
"""
import json

import numpy as np
import pytest

from host.cli import main
from host.data.runs import Errors, Run, Spindle, Temperatures, slice_run, write_run
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import DynamicModel
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.observer import CONTROLLER, board_terms
from host.learning.empirical.settle import SettleBound
from host.learning.documents import ModelFormatError
from models_export import export_model
from models_export.certify import ExportError

from exactlag import exact_lag  # test-side physics, beside these tests
from dynopts import OBSERVER_ONLY

REF_C = 22.0
DT = 60.0
SPLIT = 24 * 3600.0
TAUS = (0, 1800, 3600, 14400)
FIT = dict(target="direct", channel="ch1", window=(None, SPLIT), taus_s=TAUS, max_terms=3)


def _machine(hours=32.0):
    t = np.arange(0.0, hours * 3600.0, DT)
    krpm = np.zeros(t.size)
    for k, speed in enumerate((1.0, 3.0, 2.0, 4.0, 1.5, 3.5, 2.5, 3.0)):
        krpm[(t >= 14400 * k) & (t < 14400 * k + 7200)] = speed
    t1 = REF_C + 2.0 * exact_lag(krpm, 600.0, DT)
    t2 = REF_C + 0.4 * np.sin(2 * np.pi * t / 21600.0)
    err = 4.0 * exact_lag(t1 - REF_C, 14400.0, DT)
    temps = Temperatures(t, ["t1", "t2"], np.column_stack([t1, t2]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {"t1": {"role": "structure"}, "t2": {"role": "ambient"}}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), krpm * 1000.0), name="source"), krpm


@pytest.fixture(scope="module")
def fits():
    run, krpm = _machine()
    # the record mechanism alone (record scoring, no settle bound) beside the observer alone: the defaults since stop 35
    # add the settle bound and the worse-start scoring, tested on their own below
    record = dict(spindle_states="controller", controller_scoring="record", settle_max_s=None)
    return run, krpm, fit_model([run], "dynamic", **record, **FIT), fit_model([run], "dynamic", **OBSERVER_ONLY, **FIT)


def _rmse(pred, truth):
    return float(np.sqrt(np.mean((pred - truth) ** 2)))


def test_the_controllers_record_carries_the_state_no_sensor_reveals(fits):
    run, krpm, controlled, observed = fits
    spin = [j for j, (n, tau) in enumerate(controlled.terms) if n in ("spindle_krpm", "spindle_krpm2") and tau > 0]
    assert spin, controlled.terms  # a spindle lag: its state is exactly known at a switch-on
    for s in controlled.observer.states:
        assert (s.get("source") == CONTROLLER) == (s["term"] in spin)
        if s["term"] in spin:  # exact with the record; its gains are the estimate until the record's value comes
            assert s["bound"] == 0.0 and s["bound_without_record"] > 0 and s["gains"]
    cut, before = slice_run(run, SPLIT), slice_run(run, 0.0, SPLIT)
    truth = cut.errors.error_um
    with_record = _rmse(controlled.predict(cut, controller_history=before), truth)
    steady = _rmse(controlled.predict(cut, controller_history=[]), truth)  # a controller that starts with the board
    without_record = _rmse(controlled.predict(cut), truth)  # no controller's values: the observer's gains estimate them
    observer_only = _rmse(observed.predict(cut), truth)
    # the board switched on at the split predicts the future well with the controller's record; the model fitted without
    # the option, or the states at the first speed's steady state, do not; the estimate from the sensors is in between
    assert with_record < 0.5 * observer_only, (with_record, observer_only)
    assert with_record < 0.5 * steady, (with_record, steady)
    assert with_record < without_record < steady, (with_record, without_record, steady)
    # the supplied state is the spindle's exact lag at the split (the test-side solution, started in equilibrium with the
    # record's first input, as observer.controller_states says: the spindle runs from 0 h here)
    k = int(SPLIT / DT)
    _, cols = board_terms(controlled, [cut], controller_history=[before])
    for j in spin:
        name, tau = controlled.terms[j]
        u = krpm if name == "spindle_krpm" else krpm ** 2
        np.testing.assert_allclose(cols[0, j], exact_lag(u, tau, DT, u[0])[k], rtol=1e-9, atol=1e-12)
    # a record that does not end before the run starts is refused, naming both
    with pytest.raises(EmpiricalDataError, match=r"controller's record must end before"):
        controlled.predict(slice_run(run, 20 * 3600.0), controller_history=before)


def test_the_reported_forward_score_is_the_one_the_structure_was_chosen_by(fits):
    _, _, controlled, _ = fits
    fc = controlled.statistics["forward_chaining"]
    assert controlled.statistics["forward_scored_as"]["continuous_blocks"] == []
    np.testing.assert_allclose(controlled.estimator_.fold_rmse_, fc["rmse_um"], rtol=1e-8)


def test_a_block_scored_by_the_worse_start_is_the_worse_of_the_two_predictions(fits):
    """controller_scoring=worse: each switched-on block of the selection scores the worse of the board with the record
    and the board without it. The selection's block scores (moments of the started columns) must equal that worse of
    two predictions made another way: the refitted model's predict on the block with and without the record."""
    run, _, controlled, _ = fits
    fc = controlled.statistics["forward_chaining"]
    # the record mode reports the board without the record beside it, and chose by the record alone
    assert controlled.statistics["controller_scoring"] == "record"
    assert len(fc["without_record_rmse_um"]) == len(fc["rmse_um"])
    worse = fit_model([run], "dynamic", spindle_states="controller", controller_scoring="worse", settle_max_s=None, **FIT)
    assert worse.statistics["controller_scoring"] == "worse"
    wfc = worse.statistics["forward_chaining"]
    both = np.maximum(wfc["rmse_um"], wfc["without_record_rmse_um"])
    np.testing.assert_allclose(worse.estimator_.fold_rmse_, both, rtol=1e-8)
    # the reported worse-of-starts pooled score is the criterion the worse-scored structure was chosen by, and for the
    # record-scored one the same pooling of its blocks (what compares the two scorings' structures)
    np.testing.assert_allclose(wfc["worse_of_starts_pooled_um"], worse.estimator_.cv_rmse_, rtol=1e-8)
    n = np.array([b["n"] for b in fc["scored"]], dtype=float)
    pooled = np.sqrt(np.sum(n * np.maximum(fc["rmse_um"], fc["without_record_rmse_um"]) ** 2) / n.sum())
    np.testing.assert_allclose(fc["worse_of_starts_pooled_um"], pooled, rtol=1e-9)
    # worse scoring also searches from the structure record scoring picks (the fixture's record fit, found independently
    # here), whose score by this criterion is the record fit's own worse-of-starts pooling; the model is the lower search
    start = worse.statistics["record_structure_start"]
    assert [tuple(t) for t in start["record_structure"]] == controlled.estimator_.terms_
    np.testing.assert_allclose(start["record_structure_score_um"], fc["worse_of_starts_pooled_um"], rtol=1e-8)
    assert start["from_record_structure_score_um"] <= start["record_structure_score_um"] * (1 + 1e-12)
    assert worse.estimator_.cv_rmse_ == min(start["from_empty_score_um"], start["from_record_structure_score_um"])
    assert start["chosen"] == ("from_record_structure" if start["from_record_structure_score_um"] < start["from_empty_score_um"]
                               else "from_empty")
    # with no candidate the controller supplies, the two scorings are one criterion: no second search, the same model
    alone = dict(spindle_states="controller", use_spindle=False, use_feed=False)
    a = fit_model([run], "dynamic", controller_scoring="worse", **alone, **FIT)
    b = fit_model([run], "dynamic", controller_scoring="record", **alone, **FIT)
    assert "record_structure_start" not in a.statistics and a.terms == b.terms and a.estimator_.cv_rmse_ == b.estimator_.cv_rmse_
    # the check can fail: on some block the board without the record is worse than with it
    assert any(w > r * 1.01 for r, w in zip(wfc["rmse_um"], wfc["without_record_rmse_um"])), wfc
    # the option is refused where it means nothing, and with an unknown value, naming what it needs
    for bad in (dict(controller_scoring="worse", spindle_states="observer"), dict(spindle_states="controller", controller_scoring="best")):
        with pytest.raises(EmpiricalDataError, match=r"controller_scoring must be one of record, worse"):
            fit_model([run], "dynamic", **bad, **FIT)
    with pytest.raises(EmpiricalDataError, match=r"controller_scoring=worse \(the default with the observer\) and average_structures > 1 cannot be combined.*give controller_scoring=record and settle_max_s=none"):
        fit_model([run], "dynamic", spindle_states="controller", controller_scoring="worse", average_structures=2, **FIT)


def test_the_settle_bound_admits_what_the_controller_supplies():
    run, _ = _machine()
    kw = dict(runs=[run], spans=[(0.0, SPLIT)], exclude=None, reference_C={"t1": REF_C, "t2": REF_C}, target="direct",
              channel="ch1", scale=1.0, lag_taus=[1800.0, 3600.0, 14400.0])
    terms, coef = [("spindle_krpm", 14400.0), ("T:t1", 1800.0)], [2.0, 0.5]
    observer_only = SettleBound(1800.0, **kw)
    controlled = SettleBound(1800.0, controller=("spindle_krpm", "spindle_krpm2", "feed_m_min"), **kw)
    # the 4 h spindle state alone: unknown to the sensors, exact from the controller
    assert observer_only.settle_s(terms[:1], coef[:1]) > 1800.0 and controlled.settle_s(terms[:1], coef[:1]) == 0.0
    # beside a temperature state, only that state's start error is left to settle
    assert controlled.settle_s(terms, coef) <= 1800.0 < observer_only.settle_s(terms, coef)
    # and a fit bounded to 30 min keeps the long spindle lag only when the controller supplies it
    bounded = fit_model([run], "dynamic", spindle_states="controller", settle_max_s=1800, controller_scoring="record", **FIT)
    assert bounded.observer.settle_s <= 1800
    assert any(n.startswith("spindle") and tau == 14400.0 for n, tau in bounded.terms), bounded.terms


def test_the_settle_time_without_the_record_is_the_bound_of_the_estimated_start(fits):
    """settle_without_record_s: when B(t) = Σ |b_j|·E_j·exp(−t/τ_j) falls to 1 µm with the supplied states' E_j the
    estimate's (bound_without_record), here on a 1 s grid, not by the fit's bisection; it reaches the document and,
    as settle_nr, the table (format 8), and from_document refuses one below settle_s."""
    _, _, controlled, observed = fits
    obs = controlled.observer
    t = np.arange(0.0, 200000.0, 1.0)
    bound = np.zeros(t.size)
    for st in obs.states:
        e = st["bound_without_record"] if st.get("source") == CONTROLLER else st["bound"]
        bound += abs(controlled.term_coefficients[st["term"]]) * e * np.exp(-t / controlled.terms[st["term"]][1])
    first = t[np.argmax(bound <= obs.tolerance)]
    assert bound[0] > obs.tolerance and abs(obs.settle_without_record_s - first) <= 1.0, (obs.settle_without_record_s, first)
    assert obs.settle_without_record_s > obs.settle_s  # the estimate is worse than the record
    assert observed.observer.settle_without_record_s is None  # nothing supplied: no such time
    doc = controlled.to_document()
    assert doc["thermal"]["observer"]["settle_without_record_s"] == obs.settle_without_record_s
    assert "settle_without_record_s" not in observed.to_document()["thermal"]["observer"]
    from firmware.table import parse_table
    tab = parse_table(export_model(doc).table)
    assert tab.settle_nr == np.ceil(obs.settle_without_record_s) and tab.settle_s == np.ceil(obs.settle_s)
    bad = json.loads(json.dumps(doc))
    bad["thermal"]["observer"]["settle_without_record_s"] = obs.settle_s - 1.0
    with pytest.raises(ModelFormatError, match=r"settle_without_record_s .* must be a finite number >= settle_s"):
        DynamicModel.from_document(bad)


def test_the_document_keeps_the_source_and_the_table_marks_it(fits, tmp_path):
    run, _, controlled, _ = fits
    doc = controlled.to_document()
    back = DynamicModel.from_document(json.loads(json.dumps(doc)))
    cut, before = slice_run(run, SPLIT), slice_run(run, 0.0, SPLIT)
    np.testing.assert_allclose(back.predict(cut, controller_history=before), controlled.predict(cut, controller_history=before))
    states = doc["thermal"]["observer"]["states"]
    i = next(i for i, s in enumerate(states) if s.get("source") == CONTROLLER)
    for bad in ({"gains": {"T:nosuch": 0.1}}, {"bound": 0.5}, {"source": "operator"}, {"bound_without_record": -1.0}):
        tampered = json.loads(json.dumps(doc))
        tampered["thermal"]["observer"]["states"][i].update(bad)
        with pytest.raises(ModelFormatError, match=r"states\[%d\]" % i):
            DynamicModel.from_document(tampered)
    # the table marks the supplied states (format 7, tauc: their time constants in ms); an edited source is refused
    from firmware.table import parse_table
    t = parse_table(export_model(doc).table)
    assert [t.tauc[j] for j in range(t.nf)] == [round(s_tau * 1000) if any(st.get("source") == CONTROLLER and st["term"] == j
                                                                          for st in states) else 0
                                                for j, (_, s_tau) in enumerate(controlled.terms)]
    assert any(t.tauc)
    tampered = json.loads(json.dumps(doc))
    tampered["thermal"]["observer"]["states"][i]["bound"] = 0.5
    with pytest.raises(ExportError, match="only a lag of the spindle speed, its square or the feed, with bound 0"):
        export_model(tampered, allow_edited=True)
    with pytest.raises(EmpiricalDataError, match="spindle_states must be observer or controller, got 'board'"):
        fit_model([run], "dynamic", spindle_states="board", **FIT)
    with pytest.raises(EmpiricalDataError, match="spindle_states=controller .* needs observer=true"):
        fit_model([run], "dynamic", spindle_states="controller", observer=False, **FIT)


def test_tcomp_predict_reads_the_controllers_record(fits, tmp_path):
    run, _, controlled, observed = fits
    paths = {}
    for name, model in (("controlled", controlled), ("observed", observed)):
        paths[name] = str(tmp_path / ("%s.json" % name))
        with open(paths[name], "w") as fh:
            json.dump(model.to_document(), fh)
    cut, before = slice_run(run, SPLIT), slice_run(run, 0.0, SPLIT)
    a, b = write_run(before, str(tmp_path / "before")), write_run(cut, str(tmp_path / "after"))
    out = str(tmp_path / "p.csv")
    assert main(["predict", paths["controlled"], b, "--controller-history", a, "--out", out]) == 0
    pred = np.genfromtxt(out, delimiter=",", names=True, dtype=None, encoding="utf-8")["predicted_um"]
    np.testing.assert_allclose(pred, controlled.predict(cut, controller_history=before), atol=1e-3)
    # a model with no controller-supplied state would not read the record: refused, exit 2
    assert main(["predict", paths["observed"], b, "--controller-history", a, "--out", str(tmp_path / "q.csv")]) == 2


def test_tcomp_fit_says_which_states_the_controller_supplies_and_export_marks_them(tmp_path, capsys):
    run, _ = _machine(26.0)
    folder = write_run(run, str(tmp_path / "run"))
    out = str(tmp_path / "dyn.json")
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "taus_s=0/1800/3600/14400",
                 "--option", "max_terms=3", "--option", "spindle_states=controller"]) == 0
    printed = capsys.readouterr().out
    assert "lag states the controller supplies from its record at a start (spindle_states=controller): lag(spindle_krpm" in printed
    assert json.loads(open(out).read())["statistics"]["spindle_states"] == "controller"
    assert "tcomp linuxcnc --spindle --signal-record FILE" in printed
    assert "the same without the controller's record (its states at the observer's estimate): RMSE" in printed
    assert main(["export", out, "--out", str(tmp_path / "t.bin"), "--json", str(tmp_path / "t.json")]) == 0
    rep = json.loads((tmp_path / "t.json").read_text())
    supplied = [c for c in rep["dynamic"]["observer"]["states"] if c.get("supplied_by") == "controller"]
    assert supplied and all(c["tau_ms"] > 0 for c in supplied)
    # the settle time without the record: printed by fit, in the report, and said by export's note
    nr = json.loads(open(out).read())["thermal"]["observer"]["settle_without_record_s"]
    assert "settles in %.0f min (the board's SETTLING then)" % (nr / 60) in printed
    assert rep["dynamic"]["observer"]["settle_without_record_s"] == np.ceil(nr)
    assert "keeps SETTLING for %.0f min" % (np.ceil(nr) / 60) in capsys.readouterr().err


def test_tcomp_fit_takes_controller_scoring(tmp_path, capsys):
    run, _ = _machine(26.0)
    folder = write_run(run, str(tmp_path / "run"))
    out = str(tmp_path / "dyn.json")
    base = ["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "taus_s=0/1800/3600/14400",
            "--option", "max_terms=3", "--option", "controller_scoring=worse"]
    assert main(base + ["--option", "spindle_states=controller"]) == 0
    stats = json.loads(open(out).read())["statistics"]
    assert stats["controller_scoring"] == "worse"
    rs = stats["record_structure_start"]
    assert ("search from record scoring's structure (%s, worse of starts %.4g) ended at %.4g, from empty %.4g" % (
        ", ".join("lag(%s, tau %g s)" % tuple(t) for t in rs["record_structure"]), rs["record_structure_score_um"],
        rs["from_record_structure_score_um"], rs["from_empty_score_um"])) in capsys.readouterr().out
    # the defaults (since stop 35) are spindle_states=controller and this scoring
    assert main(base[:-2]) == 0 and json.loads(open(out).read())["statistics"]["controller_scoring"] == "worse"
    capsys.readouterr()
    # without spindle_states=controller it means nothing: refused, naming what it needs
    assert main(base + ["--option", "spindle_states=observer"]) == 2
    assert "controller_scoring must be one of record, worse, and needs spindle_states=controller" in capsys.readouterr().err


def test_a_bound_on_the_settle_time_without_the_record_is_kept_by_the_model(fits, tmp_path, capsys):
    """settle_without_record_max_s: only structures whose board *without* the controller's record settles within it
    are admitted (beside settle_max_s, with it). Here the defaults' model takes 3.4 h without the record; bounded to
    1 h, the model's own settle_without_record_s (the final observer's, computed apart from the screen) is within it,
    the screen says how many structures it refused for it alone, and the option is refused where it means nothing."""
    run = fits[0]
    free = fit_model([run], "dynamic", **FIT)
    assert free.observer.settle_without_record_s > 3600.0
    bounded = fit_model([run], "dynamic", settle_without_record_max_s=3600, **FIT)
    assert bounded.observer.settle_without_record_s <= 3600.0 and bounded.observer.settle_s <= 1800.0
    sb = bounded.statistics["settle_bound"]
    assert sb["without_record_max_s"] == 3600.0 and sb["refused_without_record"] > 0
    assert "without_record_max_s" not in free.statistics["settle_bound"]
    folder = write_run(run, str(tmp_path / "run"))
    assert main(["fit", "--model", "dynamic", "--direct", "--channel", "ch1", folder, "--out", str(tmp_path / "m.json"),
                 "--option", "taus_s=0/1800/3600/14400", "--option", "max_terms=3", "--t-max", "%g" % SPLIT,
                 "--option", "settle_without_record_max_s=3600"]) == 0
    assert ("and without the controller's record settle_without_record_s <= 60 min: %d structures refused for that alone"
            % sb["refused_without_record"]) in capsys.readouterr().out
    for bad in (dict(spindle_states="observer"), dict(settle_max_s=None)):
        with pytest.raises(EmpiricalDataError, match=r"settle_without_record_max_s .* needs spindle_states=controller and settle_max_s"):
            fit_model([run], "dynamic", settle_without_record_max_s=3600, **bad, **FIT)
    with pytest.raises(EmpiricalDataError, match=r"settle_without_record_max_s must be a finite number of seconds >= 0.*got -5"):
        fit_model([run], "dynamic", settle_without_record_max_s=-5, **FIT)
