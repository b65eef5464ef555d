"""The paper comparisons that are not linear in the temperatures: the back-propagation network and PPR."""
import json

import numpy as np
import pytest

from host.cli import main
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.ann import ANN
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.ppr import PPR, natural_spline_basis
from host.learning.empirical.regression import MLR
from host.learning.documents import ModelFormatError, load_model, save_model

FAST = {"max_epochs": 600, "patience": 60, "learning_rate": 0.03}


def _curved(n, seed):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.0, 1.0, (n, 3))
    y = 4.0 * np.tanh(2.0 * X[:, 0]) + X[:, 1] ** 2 + 0.02 * rng.normal(size=n)
    return X, y


def test_ann_learns_a_curve_a_line_cannot_and_is_deterministic():
    X, y = _curved(300, 1)
    Xt, yt = _curved(200, 2)
    a = ANN(hidden_sizes=(3, 5), seed=4, **FAST).fit(X, y)
    b = ANN(hidden_sizes=(3, 5), seed=4, **FAST).fit(X, y)
    np.testing.assert_array_equal(a.W_, b.W_)
    mse = {h: v ** 2 for h, v in a.validation_rmse_.items()}
    assert a.hidden_size_ == min(h for h in mse if mse[h] <= 1.05 * min(mse.values()))  # the default size rule
    assert all(a.epochs_[h] <= FAST["max_epochs"] for h in a.epochs_) and 1 <= a.best_epoch_ <= a.epochs_[a.hidden_size_]
    rmse_ann = np.sqrt(np.mean((a.predict(Xt) - yt) ** 2))
    rmse_mlr = np.sqrt(np.mean((MLR().fit(X, y).predict(Xt) - yt) ** 2))
    assert rmse_ann < 0.5 * rmse_mlr, (rmse_ann, rmse_mlr)
    c = ANN(hidden_sizes=(3, 5), seed=5, **FAST).fit(X, y)
    assert not np.array_equal(a.W_, c.W_)  # the seed is used
    # the forward pass written out independently from the stored network
    net = a.network()
    Z = (Xt - np.array(net["input_offset"])) / np.array(net["input_scale"])
    H = np.tanh(Z @ np.array(net["hidden_weights"]).T + np.array(net["hidden_bias"]))
    by_hand = net["output_offset"] + net["output_scale"] * (H @ np.array(net["output_weights"]) + net["output_bias"])
    np.testing.assert_allclose(a.predict(Xt), by_hand)


def test_ann_validation_on_the_last_group_and_bad_settings():
    X, y = _curved(200, 3)
    groups = np.repeat([0, 1, 2, 3], 50)
    a = ANN(hidden_sizes=(3,), validation="last_group", **FAST).fit(X, y, groups=groups)
    assert a.n_validation_ == 50 and a.validation_.startswith("last group")
    for kw, msg in (({"hidden_sizes": (0,)}, "hidden_sizes"), ({"validation": "none"}, "validation must be"),
                    ({"max_epochs": 0}, "max_epochs"), ({"validation_fraction": 1.0}, "validation_fraction")):
        with pytest.raises(EmpiricalDataError, match=msg):
            ANN(**kw).fit(X, y, groups=groups)
    with pytest.raises(EmpiricalDataError, match="needs at least 2 groups"):
        ANN(validation="last_group").fit(X, y)
    with pytest.raises(EmpiricalDataError, match="training and"):
        ANN().fit(X[:4], y[:4])


def test_natural_spline_is_linear_outside_its_knots():
    knots = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    v = np.array([5.0, 6.0, 7.0, -3.0, -2.0, -1.0])
    B = natural_spline_basis(v, knots)
    beta = np.random.default_rng(0).normal(size=B.shape[1])
    f = B @ beta
    assert f[2] - 2 * f[1] + f[0] == pytest.approx(0.0, abs=1e-9)
    assert f[5] - 2 * f[4] + f[3] == pytest.approx(0.0, abs=1e-9)


def test_ppr_finds_a_single_index_curve():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 3))
    u = (X[:, 0] + X[:, 1]) / np.sqrt(2)
    y = u**2 + 0.01 * rng.normal(size=400)
    m = PPR(n_terms=1, knots=7).fit(X, y)
    a = m.terms_[0].a * m.x_scale_[0] / m.x_scale_  # back to raw units, up to scale
    a = a / np.linalg.norm(a)
    assert abs(abs(a @ np.array([1, 1, 0]) / np.sqrt(2)) - 1.0) < 0.02
    assert m.rsquared_ > 0.99 and MLR().fit(X, y).rsquared_ < 0.2
    with pytest.raises(EmpiricalDataError, match="n_terms"):
        PPR(n_terms=0).fit(X, y)


def test_ann_model_document_round_trip_and_cli(make_direct, tmp_path):
    from host.data.runs import write_run

    run = make_direct(spindle=True, n_sensors=3, noise_um=0.05)
    model = fit_model([run], "ann", target="direct", channel="ch1", hidden_sizes=(3,), **FAST)
    path = str(tmp_path / "ann.json")
    doc = save_model(model.to_document(), path)
    assert doc["kind"] == "ann" and doc["thermal"]["target"] == "direct" and doc["statistics"]["hidden_size"] == 3
    back = load_model(path)
    np.testing.assert_allclose(back.predict(run), model.predict(run))
    bad = json.loads(open(path).read())
    bad["thermal"]["network"]["hidden_weights"][0] = [1.0]
    with pytest.raises(ModelFormatError, match="hidden_weights"):
        load_model(bad)
    bad = json.loads(open(path).read())
    bad["thermal"]["network"]["activation"] = "relu"
    with pytest.raises(ModelFormatError, match="activation"):
        load_model(bad)
    # the command line: fit, then predict with the saved network
    folder = write_run(run, str(tmp_path / "run"))
    out = str(tmp_path / "cli.json")
    assert main(["fit", "--model", "ann", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "hidden_sizes=3/4",
                 "--option", "max_epochs=300", "--option", "seed=1"]) == 0
    assert main(["predict", out, folder, "--out", str(tmp_path / "pred.csv")]) == 0
    assert main(["fit", "--model", "ann", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "hidden_sizes=x"]) == 2


def test_ann_slope_model_predicts_geometric_plus_thermal(make_slope):
    run = make_slope(n_sweeps=30, noise_um=0.01)
    model = fit_model([run], "ann", target="slope", hidden_sizes=(3,), validation_fraction=0.3, **FAST)
    doc = load_model(model.to_document())
    e = run.errors
    R = doc.rises(run, e.time_s)
    expect = doc.geometric(e.position_mm) + doc.estimator_.predict(R) * e.position_mm
    np.testing.assert_allclose(doc.predict(run), expect)
    assert doc.target == "slope" and doc.to_document()["geometric"]["degree"] >= 1


def _li2021_sized(seed=0):
    """Li 2021's ANN data: 8 slopes, 5 temperature inputs (sensors warming along different curves)."""
    rng = np.random.default_rng(seed)
    t = np.array([0, 20, 60, 120, 210, 240, 340, 390], dtype=float)
    X = np.column_stack([a * (1 - np.exp(-t / tau)) for a, tau in zip(rng.uniform(2, 8, 5), rng.uniform(60, 300, 5))])
    y = 0.01 * X[:, 0] + 0.02 * X[:, 1] - 0.005 * X[:, 3] + 0.002 * rng.normal(size=8)
    return X, y


def test_ann_at_the_papers_sample_size_uses_leave_one_out_and_the_papers_size_rule():
    X, y = _li2021_sized()
    a = ANN(max_epochs=400, patience=60, learning_rate=0.03).fit(X, y)  # 8 samples, 5 inputs: refused before issue 23
    st = a.statistics()
    assert a.validation_.startswith("leave-one-out over 8")
    assert sorted(st["validation_mse_by_size"]) == ["3", "4", "5", "6", "7"] and sorted(st["validation_r2_by_size"]) == ["3", "4", "5", "6", "7"]
    mse = {int(k): v for k, v in st["validation_mse_by_size"].items()}
    # Li 2021: the fewest nodes among the sizes whose MSE is about the lowest (here within 5 %)
    assert a.hidden_size_ == min(h for h in mse if mse[h] <= 1.05 * min(mse.values()))
    best = ANN(max_epochs=400, patience=60, learning_rate=0.03, size_rule="best").fit(X, y)
    assert best.hidden_size_ == min(mse, key=lambda h: (mse[h], h))
    # R2 per size is 1 - SSE_loo / SST
    sst = float(((y - y.mean()) ** 2).sum())
    for h in mse:
        assert st["validation_r2_by_size"][str(h)] == pytest.approx(1 - 8 * mse[h] / sst)
    assert a.n_samples_ == 8 and np.isfinite(a.predict(X)).all()


def test_lockstep_folds_equal_networks_trained_one_by_one():
    # the batched leave-one-out trainer against the one-network trainer, fold by fold
    X, y = _li2021_sized(1)
    a = ANN(hidden_sizes=(4,), max_epochs=150, patience=1000, learning_rate=0.03)
    a._check()
    n = len(y)
    keep = ~np.eye(n, dtype=bool)
    Xf, yf = np.stack([X[k] for k in keep]), np.stack([y[k] for k in keep])
    mu, sd = Xf.mean(axis=1), Xf.std(axis=1)
    ym, ys = yf.mean(axis=1), yf.std(axis=1)
    Zf, tf = (Xf - mu[:, None, :]) / sd[:, None, :], (yf - ym[:, None]) / ys[:, None]
    mse, epoch = a._train_folds(Zf, tf, (X - mu) / sd, y, ym, ys, 4)
    errs = []
    for k in range(n):
        (W, b, v, c), _, _, _ = a._train(Zf[k], tf[k], Zf[k], tf[k], 4, epochs=epoch)
        zo = (X[k] - mu[k]) / sd[k]
        errs.append(ym[k] + ys[k] * (np.tanh(W @ zo + b) @ v + c) - y[k])
    assert mse == pytest.approx(np.mean(np.square(errs)), rel=1e-9)


def test_ppr_model_document_predict_and_export_refusal(make_direct, tmp_path, capsys):
    """tcomp fit --model ppr writes a ``ppr`` document; predict reads it back to the fitted model's values; export
    refuses it naming why (a ridge function is no table kind); a document whose ridges are malformed is refused
    naming the field."""
    from host.data.runs import load_runs, write_run

    run = make_direct(n_sensors=3)
    folder = write_run(run, str(tmp_path / "run"))
    out = str(tmp_path / "ppr.json")
    assert main(["fit", "--model", "ppr", "--direct", "--channel", "ch1", folder, "--out", out, "--option", "n_terms=2",
                 "--option", "knots=4"]) == 0
    doc = json.loads(open(out).read())
    assert doc["kind"] == "ppr" and doc["thermal"]["target"] == "direct" and len(doc["thermal"]["ridges"]["terms"]) == 2
    # the same fit in memory on the written run (PPR is deterministic) predicts what the saved document predicts
    written = load_runs([folder])[0]
    expected = fit_model([written], "ppr", target="direct", channel="ch1", n_terms=2, knots=4).predict(written)
    ch1 = written.errors.channel == "ch1"  # the model's channel; the other rows are not predicted (NaN)
    assert np.isfinite(expected[ch1]).all() and np.isnan(expected[~ch1]).all()
    np.testing.assert_allclose(load_model(out).predict(written), expected, rtol=0, atol=1e-9)
    pred = str(tmp_path / "pred.csv")
    assert main(["predict", out, folder, "--out", pred]) == 0
    rows = np.genfromtxt(pred, delimiter=",", names=True, dtype=None, encoding="utf-8")
    np.testing.assert_allclose(rows["predicted_um"], expected[ch1], rtol=0, atol=5.1e-5)  # the channel's rows, printed to 0.1 nm
    capsys.readouterr()
    assert main(["export", out, "--out", str(tmp_path / "t.bin")]) == 2
    err = capsys.readouterr().err
    assert "a ppr model cannot be exported" in err and "ridge functions" in err
    assert not (tmp_path / "t.bin").exists()
    for field, value in (("knots", [1.0, 1.0, 2.0, 3.0]), ("coefficients", [0.5]), ("direction", [1.0])):
        bad = json.loads(open(out).read())
        bad["thermal"]["ridges"]["terms"][1][field] = value
        with pytest.raises(ModelFormatError, match=r"terms\[1\]\.%s" % field):
            load_model(bad)
