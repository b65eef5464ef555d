"""Targets, geometric polynomial, model documents, evaluation and the fit/predict CLI."""
import json

import numpy as np
import pytest

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.scoring import disturb_run, metrics, score_model
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.geometric import GeometricPolynomial, fit_geometric
from host.learning.empirical.kinds import LinearDirectModel, PolySlopeModel
from host.learning.empirical.targets import direct_targets, sweep_slopes, temperature_features, training_arrays
from host.learning.documents import load_model, save_model
from host.data.runs import load_run, write_run


def test_sweep_slopes_recover_the_thermal_slope(make_slope):
    run = make_slope(coef=(0.004, -0.002), geo=(1.0, 0.01, -2e-5))
    s = sweep_slopes(run)
    assert s.time_s.size == 12 and np.all(np.diff(s.time_s) > 0)
    rises = temperature_features(run, ["T1", "T2"], s.time_s)
    np.testing.assert_allclose(s.target, rises @ [0.004, -0.002], atol=1e-12)
    assert s.target[0] == 0.0


def test_bidirectional_sweeps_have_a_cold_slope_per_direction(make_slope):
    run = make_slope(bidirectional=True)
    s = sweep_slopes(run)
    assert set(s.k0_um_per_mm) == {1, -1}
    assert np.sum(s.target == 0) == 2  # each direction's cold sweep
    X, y, names = training_arrays([run])[0]
    true = X[:, :2] @ [0.004, -0.002]
    back = s.direction == -1
    np.testing.assert_allclose(y[~back], true[~back], atol=1e-12)
    # the backward cold sweep is 60 s later: its targets are relative to that sweep's slope
    np.testing.assert_allclose(y[back], true[back] - true[back][0], atol=1e-12)


def test_direct_targets_and_channel_errors(make_slope, make_direct):
    run = make_direct()
    t, y = direct_targets(run, "ch2")
    assert t.size == 600 and y.size == 600
    with pytest.raises(EmpiricalDataError, match="2 channels"):
        direct_targets(run)
    with pytest.raises(EmpiricalDataError, match="'ch9' is not in errors.csv"):
        direct_targets(run, "ch9")
    with pytest.raises(EmpiricalDataError, match="positions"):
        direct_targets(make_slope())
    with pytest.raises(EmpiricalDataError, match="--direct"):
        sweep_slopes(run, "ch1")


def test_temperature_features_rises_and_bounds(make_direct):
    run = make_direct()
    X = temperature_features(run, ["t1", "t3"], [0.0, 60.0, 90.0])
    assert np.all(X[0] == 0)
    raw = temperature_features(run, ["t1"], [90.0], rise=False)
    assert raw[0, 0] == pytest.approx(np.mean(run.temperatures.values[1:3, 0]))
    with pytest.raises(EmpiricalDataError, match="outside the temperature log"):
        temperature_features(run, ["t1"], [1e9])
    with pytest.raises(EmpiricalDataError, match="not in temperatures.csv"):
        temperature_features(run, ["zz"], [0.0])


def test_training_arrays_window_and_unpacking(make_direct):
    run = make_direct()
    arr = training_arrays([run], "direct", "ch1", window=(3600.0, 7200.0))[0]
    X, y, names = arr
    assert arr.time_s.min() >= 3600 and arr.time_s.max() < 7200 and X.shape == (60, 5) and names == ["t1", "t2", "t3", "t4", "t5"]


def test_geometric_degree_is_chosen():
    rng = np.random.default_rng(1)
    P = np.tile(np.linspace(0, 600, 13), 3)
    e = 2.0 + 0.02 * P - 5e-5 * P**2 + rng.normal(0, 0.05, P.size)
    g = GeometricPolynomial().fit(P, e)
    assert g.degree_ == 2
    np.testing.assert_allclose(g.coef_, [2.0, 0.02, -5e-5], rtol=0.05, atol=0.05)
    assert [s["degree"] for s in g.scores_] == [1, 2, 3, 4, 5]
    assert GeometricPolynomial(criterion="aic").fit(P, e).degree_ == 2
    with pytest.raises(EmpiricalDataError, match="distinct positions"):
        GeometricPolynomial().fit([0, 1, 2], [0, 1, 2])


def test_geometric_from_cold_sweeps_averages_directions(make_slope):
    run = make_slope(bidirectional=True, geo=(1.0, 0.01, -2e-5))
    g = fit_geometric([run])
    # backward sweep carries +1.5 um reversal offset: the average is +0.75
    assert g.coef_[0] == pytest.approx(1.75, abs=1e-6)


@pytest.mark.parametrize("method", ["mlr", "pcr", "stepwise"])
def test_poly_slope_model_fits_predicts_and_round_trips(tmp_path, method, make_slope):
    opts = {"f_enter": 4.0, "f_remove": 2.0} if method == "stepwise" else {}
    train = make_slope(seed=0, noise_um=0.0)
    model = fit_model([train], method, **opts)
    assert isinstance(model, PolySlopeModel)
    test = make_slope(seed=5)
    pred = model.predict(test)
    assert pred.shape == (len(test.errors),) and np.all(np.isfinite(pred))
    doc = save_model(model.to_document(), str(tmp_path / "m.json"))
    again = load_model(str(tmp_path / "m.json"))
    np.testing.assert_allclose(again.predict(test), pred)
    assert doc["kind"] == "poly_slope" and doc["geometric"]["degree"] >= 1
    assert doc["envelope"]["position_mm"] == [0.0, 500.0] and set(doc["envelope"]["temperature_C"]) == set(model.sensors)
    if method == "mlr":
        # exact data: with rises over the test run's own start the slope model reproduces its thermal error
        latched = fit_model([train], method, reference="run_start")
        assert score_model(latched, test)["rmse_um"] < 0.05


def test_linear_direct_model_channels_nan_and_no_intercept(tmp_path, make_direct):
    run = make_direct(intercept=0.0)
    model = fit_model([run], "mlr", target="direct", channel="ch1", fit_intercept=False, sensors=["t1", "t2"])
    assert isinstance(model, LinearDirectModel) and model.intercept == 0.0
    np.testing.assert_allclose(model.coefficients, [-3.0, 1.5], atol=1e-9)
    pred = model.predict(run)
    ch1 = run.errors.channel == "ch1"
    assert np.all(np.isnan(pred[~ch1])) and np.all(np.isfinite(pred[ch1]))
    np.testing.assert_allclose(pred[ch1], run.errors.error_um[ch1], atol=1e-9)
    doc = model.to_document()
    assert doc["geometric"] is None and doc["thermal"]["reference"] == "fixed"
    back = LinearDirectModel.from_document(json.loads(json.dumps(doc)))
    np.testing.assert_allclose(back.predict(run), pred, equal_nan=True)


def test_rise_reference_fixed_vs_run_start(make_direct):
    """A run started 1 K warmer: run_start rises ignore it, the fixed reference_C sees 1 K on every sensor."""
    import copy

    run = make_direct()
    warm = copy.copy(run)
    warm.temperatures = copy.copy(run.temperatures)
    warm.temperatures.values = run.temperatures.values + 1.0
    fixed = fit_model([run], "mlr", target="direct", channel="ch1")
    latched = fit_model([run], "mlr", target="direct", channel="ch1", reference="run_start")
    ch1 = run.errors.channel == "ch1"
    np.testing.assert_allclose(latched.predict(warm)[ch1], latched.predict(run)[ch1], atol=1e-9)
    np.testing.assert_allclose(fixed.predict(warm)[ch1] - fixed.predict(run)[ch1], fixed.coefficients.sum(), atol=1e-9)
    assert fixed.to_document()["thermal"]["reference"] == "fixed" and latched.to_document()["thermal"]["reference"] == "run_start"
    assert fixed.reference_C["t1"] == run.temperatures.values[0, 0]
    # documents without the key are read as the contract's fixed reference
    doc = latched.to_document()
    del doc["thermal"]["reference"]
    assert LinearDirectModel.from_document(doc).reference == "fixed"


def test_metrics_definition():
    m = metrics([3.0, -4.0, 0.0], [1.0, -4.0, 1.0])
    assert m["rmse_um"] == pytest.approx(np.sqrt(5 / 3))
    assert m["max_residual_um"] == 2.0 and m["min_residual_um"] == -1.0
    assert m["accuracy_pct"] == pytest.approx(100 * (1 - np.sqrt(5 / 3) / np.sqrt(25 / 3)))


def test_disturb_run_keeps_the_start_sample(make_direct):
    run = make_direct()
    d = disturb_run(run, noise_C=0.3, offset_C=0.5, seed=1)
    np.testing.assert_array_equal(d.temperatures.values[0], run.temperatures.values[0])
    diff = d.temperatures.values[1:] - run.temperatures.values[1:]
    assert 0.2 < diff.std() < 0.6
    assert run.temperatures.values is not d.temperatures.values


def test_fit_and_predict_cli(tmp_path, capsys, make_slope):
    from host.cli import main

    folder = write_run(make_slope(), str(tmp_path / "r1"))
    other = write_run(make_slope(seed=3), str(tmp_path / "r2"))
    out = str(tmp_path / "m.json")
    assert main(["fit", "--model", "pcr", folder, other, "--out", out, "--option", "variance_threshold=0.9", "--json", str(tmp_path / "f.json")]) == 0
    doc = json.load(open(out))
    assert doc["method"] == "pcr" and doc["statistics"]["variance_threshold"] == 0.9
    assert main(["predict", out, other, "--out", str(tmp_path / "p.csv")]) == 0
    rows = open(tmp_path / "p.csv").read().splitlines()
    assert rows[0] == "time_s,position_mm,predicted_um,measured_um,residual_um" and len(rows) == len(load_run(other).errors) + 1
    assert main(["fit", "--model", "mlr", folder, "--out", out, "--option", "f_enter=3"]) == 2
    assert "applies to --model stepwise" in capsys.readouterr().err
    assert main(["fit", "--model", "mlr", folder, "--out", out, "--sensors", "T1,T9"]) == 2
    assert "T9" in capsys.readouterr().err


def test_fit_cli_direct_on_multichannel_run(tmp_path, capsys, make_direct):
    from host.cli import main

    run = make_direct()
    run.meta["stroke_mm"] = None
    folder = write_run(run, str(tmp_path / "d"))
    out = str(tmp_path / "d.json")
    assert main(["fit", "--model", "stepwise", "--direct", "--channel", "ch2", folder, "--out", out]) == 0
    doc = json.load(open(out))
    assert doc["kind"] == "linear_direct" and doc["channel"] == "ch2" and sorted(doc["sensors"]) == ["t1", "t2"]
    assert main(["fit", "--model", "mlr", folder, "--out", out]) == 2
    assert "channels" in capsys.readouterr().err


def test_fit_cli_options_reference_and_window(tmp_path, make_direct):
    from host.cli import main

    run = make_direct()
    folder = write_run(run, str(tmp_path / "d"))
    out = str(tmp_path / "m.json")
    assert main(["fit", "--model", "mlr", "--direct", "--channel", "ch1", folder, "--out", out, "--sensors", "t1,t2",
                 "--option", "reference=run_start", "--option", "t_max_s=7200", "--option", "envelope_margin_K=1"]) == 0
    doc = json.load(open(out))
    assert doc["thermal"]["reference"] == "run_start" and doc["training"]["window_s"] == [None, 7200.0]
    assert doc["training"]["n_samples"] == 120 and doc["envelope"]["margin_K"] == 1.0
    assert doc["envelope"]["position_mm"] == [0.0, 0.0]
    lo, hi = doc["envelope"]["temperature_C"]["t1"]
    t1 = run.temperatures.values[:121, 0]
    assert lo == pytest.approx(t1.min() - 1) and hi == pytest.approx(t1[:120].max() + 1, abs=0.2)
    assert main(["fit", "--model", "mlr", folder, "--out", out, "--option", "bogus=1"]) == 2


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=20, deadline=None)
@given(g=st.lists(st.floats(-5, 5), min_size=1, max_size=4), shift=st.floats(-30, 30))
def test_slope_targets_ignore_the_geometric_error_and_sensor_offsets(bidirectional_run, g, shift):
    """Any fixed geometric polynomial cancels out of k_i − k_0; a constant on a sensor cancels out of rises."""
    import copy

    from host.data.runs import Errors

    run = bidirectional_run
    base = training_arrays([run])[0]
    other = copy.copy(run)
    e = run.errors
    coef = np.asarray(g) * np.array([1, 1e-2, 1e-5, 1e-8])[: len(g)]
    other.errors = Errors(e.time_s, e.position_mm, e.error_um + np.polynomial.polynomial.polyval(e.position_mm, coef), e.direction, e.channel)
    other.temperatures = copy.copy(run.temperatures)
    other.temperatures.values = run.temperatures.values + np.array([shift, 0, 0, 0])
    moved = training_arrays([other])[0]
    np.testing.assert_allclose(moved.y, base.y, atol=1e-9)
    np.testing.assert_allclose(moved.X, base.X, atol=1e-9)


def test_malformed_documents_are_model_format_errors(make_direct):
    from host.learning.documents import ModelFormatError

    doc = fit_model([make_direct()], "mlr", target="direct", channel="ch1").to_document()
    bad = json.loads(json.dumps(doc))
    del bad["thermal"]["coefficients_um_per_K"]["t3"]
    with pytest.raises(ModelFormatError, match="t3"):
        load_model(bad)
    bad = json.loads(json.dumps(doc))
    bad["reference_C"].pop("t1")
    with pytest.raises(ModelFormatError, match="reference_C"):
        load_model(bad)
    bad = json.loads(json.dumps(doc))
    bad["thermal"]["reference"] = "yesterday"
    with pytest.raises(ModelFormatError, match="thermal.reference"):
        load_model(bad)


def test_training_arrays_common_sensors_and_errors(make_slope):
    import copy

    a = make_slope(n_sensors=4)
    b = make_slope(seed=2, n_sensors=4)
    b.temperatures = copy.copy(b.temperatures)
    b.temperatures.names = ["T1", "T2", "T3", "X9"]
    arrs = training_arrays([a, b])
    assert [x.names for x in arrs] == [["T1", "T2", "T3"]] * 2
    with pytest.raises(EmpiricalDataError, match="no run"):
        training_arrays([])
    with pytest.raises(EmpiricalDataError, match="duplicates"):
        training_arrays([a], sensors=["T1", "T1"])
    with pytest.raises(EmpiricalDataError, match="T4.*not in temperatures.csv"):
        training_arrays([a, b], sensors=["T1", "T4"])


def test_geometric_degree_is_exact(make_slope):
    # Li 2021 fits a degree-5 polynomial to the cold sweep, S004 degree 4: the option fixes it
    from host.learning.empirical.geometric import cold_points

    run = make_slope(geo=(1.0, 0.01, -2e-5, 3e-8))
    for n in (4, 5):
        model = fit_model([run], method="mlr", geometric_degree=n)
        doc = model.to_document()
        assert doc["geometric"]["degree"] == n and len(doc["geometric"]["coefficients_um"]) == n + 1
        assert model.statistics["geometric"]["criterion"] == "fixed"
        P, e = cold_points([run])
        ref = np.polynomial.polynomial.polyfit(P, e, n)  # independent least squares on the same cold points
        np.testing.assert_allclose(model.predict(run)[: P.size], np.polynomial.polynomial.polyval(P, ref), atol=1e-6)
    chosen = fit_model([run], method="mlr")
    assert chosen.to_document()["geometric"]["degree"] == 3  # without the option the degree is chosen (here the truth)
    with pytest.raises(EmpiricalDataError, match="geometric_degree must be an integer 1..6"):
        fit_model([run], method="mlr", geometric_degree=7)
    with pytest.raises(EmpiricalDataError, match="geometric_degree=6 needs at least 8 distinct positions"):
        fit_model([_few_positions(make_slope)], method="mlr", geometric_degree=6)


def _few_positions(make_slope):
    from host.data.runs import Errors, Run

    r = make_slope()
    e = r.errors
    keep = e.position_mm <= 300.0  # 7 of the 11 positions
    return Run(r.meta, r.temperatures, Errors(e.time_s[keep], e.position_mm[keep], e.error_um[keep], None, None), name=r.name)
