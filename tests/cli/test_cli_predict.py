"""tcomp predict writes measured, predicted and residual per row of the model's channel, max/min/R² per channel,
and says how tcomp compare's figure of the same model on the same run comes out, and why it differs."""
import csv
import json
import os

import numpy as np
import pytest

from host.cli import main
from host.data.runs import load_run, write_run

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRAIN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")
TEST = os.path.join(ROOT, "data", "demo", "v8000_r0_700")
FEW = "T1,T2,T3,T4,T5"


def test_predict_rows_are_the_models_channel_with_measured_and_residual(make_run, tmp_path, capsys):
    run = write_run(make_run(channels=["X1", "X2"]), str(tmp_path / "run"))
    model = str(tmp_path / "m.json")
    assert main(["fit", "--model", "mlr", run, "--channel", "X1", "--out", model]) == 0
    out, js = str(tmp_path / "p.csv"), str(tmp_path / "p.json")
    assert main(["predict", model, run, "--out", out, "--json", js]) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    e = load_run(run).errors
    x1 = np.flatnonzero(e.channel == "X1")
    assert [r["channel"] for r in rows] == ["X1"] * x1.size  # no row of X2, no nan
    measured = np.array([float(r["measured_um"]) for r in rows])
    predicted = np.array([float(r["predicted_um"]) for r in rows])
    residual = np.array([float(r["residual_um"]) for r in rows])
    assert measured == pytest.approx(e.error_um[x1], abs=1e-4)
    assert residual == pytest.approx(measured - predicted, abs=2e-4)
    doc = json.load(open(js))
    c = doc["channels"]["X1"]
    y = e.error_um[x1]
    r = y - predicted
    assert c["max_residual_um"] == pytest.approx(r.max(), abs=2e-4)
    assert c["min_residual_um"] == pytest.approx(r.min(), abs=2e-4)
    assert c["r2"] == pytest.approx(1 - np.sum(r ** 2) / np.sum((y - y.mean()) ** 2), abs=1e-6)
    assert list(doc["channels"]) == ["X1"] and doc["predicted_rows"] == x1.size and doc["rows"] == len(e)


def test_predict_says_what_compare_scores_for_the_same_model(tmp_path, capsys):
    model = str(tmp_path / "m.json")
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", FEW, "--out", model]) == 0
    js = str(tmp_path / "p.json")
    capsys.readouterr()
    assert main(["predict", model, TEST, "--out", str(tmp_path / "p.csv"), "--json", js]) == 0
    printed = capsys.readouterr().out
    view = json.load(open(js))["compare_view"]
    assert view["reference"] == "fixed" and "run_start" in printed
    for reference in ("fixed", "run_start"):
        cj = str(tmp_path / ("c_%s.json" % reference))
        assert main(["compare", TRAIN, TEST, "--methods", "mlr", "--sensors", FEW, "--repeats", "1",
                     "--reference", reference, "--json", cj]) == 0
        doc = json.load(open(cj))
        rmse = doc["results"][0]["tests"]["v8000_r0_700"]["rmse_um"]
        if reference == "fixed":  # the model as fit saved it: predict names compare's figure exactly
            assert view["thermal"]["rmse_um"] == pytest.approx(rmse, rel=1e-12)
            assert "%.3f um" % rmse in printed
        else:  # compare's default scores another reference: its note says so
            assert abs(rmse - view["thermal"]["rmse_um"]) > 1e-3
            assert any("--reference run_start" in n and "tcomp predict" in n for n in doc["findings"])


def test_fit_t_min_t_max_train_on_part_of_a_run(tmp_path, capsys):
    run = load_run(TRAIN)
    t = np.unique(run.errors.time_s)
    lo, hi = float(t[2]), float(t[10])  # sweeps 2..9
    a, b = str(tmp_path / "a.json"), str(tmp_path / "b.json")
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", "T1,T2", "--t-min", repr(lo), "--t-max", repr(hi), "--out", a]) == 0
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", "T1,T2", "--option", "t_min_s=%r" % lo,
                 "--option", "t_max_s=%r" % hi, "--out", b]) == 0
    da, db = json.load(open(a)), json.load(open(b))
    assert da["training"]["window_s"] == [lo, hi] and da["thermal"] == db["thermal"]
    assert da["statistics"]["n_samples"] == 8  # one slope per sweep in [lo, hi)
    capsys.readouterr()
    assert main(["fit", "--model", "mlr", TRAIN, "--t-max", "100", "--option", "t_max_s=50", "--out", a]) == 2
    assert "set the same training window" in capsys.readouterr().err
    assert main(["fit", "--model", "screw", TRAIN, "--t-min", "5", "--t-max", "5", "--out", a]) == 2
    assert "the training window is empty" in capsys.readouterr().err


def test_predict_on_a_training_run_splits_fitted_and_held_out_rows(tmp_path, capsys):
    model = str(tmp_path / "m.json")
    t_max = 10800.0
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", FEW, "--t-max", "%g" % t_max, "--out", model]) == 0
    out, js = str(tmp_path / "p.csv"), str(tmp_path / "p.json")
    capsys.readouterr()
    assert main(["predict", model, TRAIN, "--out", out, "--json", js]) == 0
    assert "held-out rows" in capsys.readouterr().out
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["time_s"]) for r in rows])
    r = np.array([float(r["residual_um"]) for r in rows])
    split = json.load(open(js))["training_split"]
    assert split["held_out"]["rows"] == int(np.sum(t >= t_max)) > 0
    assert split["held_out"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(r[t >= t_max] ** 2)), abs=1e-4)
    assert split["fitted"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(r[t < t_max] ** 2)), abs=1e-4)
    # another run than the training run: no split (every row is held out)
    assert main(["predict", model, TEST, "--out", out, "--json", js]) == 0
    assert json.load(open(js))["training_split"] is None
