"""`tcomp hil` judges (issue 22): the board's answers against the measurement (errors.csv) and against the host
model (`tcomp predict` of the document the table came from), RMSE and largest residual per channel, printed
with channel names and in the JSON's ``judge`` block; ``--duration`` simulates only the run's first seconds.

The figures are recomputed here from the files themselves (errors.csv read with the csv module, the host model's
prediction from `tcomp predict`'s CSV, numpy on the JSON's answers), not with the verb's code; a table whose
thermal coefficients have the wrong sign must be judged far off."""
import csv
import json
import os

import numpy as np
import pytest

from host.cli import main as tcomp

pytestmark = pytest.mark.rig
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUN = os.path.join(ROOT, "data", "demo", "mixed")
SENSORS = "T1,T2,T4"
DURATION_S = 1000  # the sweeps at 0 s and 900 s: 30 rows


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """An MLR fitted on the run (its document and table), and the same document with every thermal
    coefficient's sign flipped (a deliberately wrong table)."""
    from hil_tests.rig.boards import _finish
    d = tmp_path_factory.mktemp("models")
    assert tcomp(["fit", "--model", "mlr", RUN, "--sensors", SENSORS, "--out", str(d / "m.json")]) == 0
    assert tcomp(["export", str(d / "m.json"), "--out", str(d / "m.bin")]) == 0
    doc = json.loads((d / "m.json").read_text())
    coefs = doc["thermal"]["coefficients_um_per_mm_per_K"]
    doc["thermal"]["coefficients_um_per_mm_per_K"] = {k: -v for k, v in coefs.items()}
    (d / "wrong.json").write_text(json.dumps(_finish(doc)))
    assert tcomp(["export", str(d / "wrong.json"), "--out", str(d / "wrong.bin")]) == 0
    assert tcomp(["predict", str(d / "m.json"), RUN, "--out", str(d / "pred.csv")]) == 0
    return d


def _errors_rows(limit_s):
    with open(os.path.join(RUN, "errors.csv"), newline="") as f:
        rows = [r for r in csv.DictReader(f) if float(r["time_s"]) <= limit_s]
    return rows


def _hil(tmp_path, table, model, interpreter, extra=()):
    out = tmp_path / ("%s.json" % os.path.basename(table))
    rc = tcomp(["hil", "--run", RUN, "--table", table, "--model", model, "--duration", str(DURATION_S),
                "--interpreter", interpreter, "--warmup-s", "10", "--json", str(out)]
               + list(extra))
    return rc, json.loads(out.read_text())


def test_hil_judges_against_measurement_and_host_model(tmp_path, models, capsys):
    from hil_tests.rig import interpreters
    interpreters.get().require()
    capsys.readouterr()
    rc, d = _hil(tmp_path, str(models / "m.bin"), str(models / "m.json"), "micropython",
                 ["--fault", "open:T2@100-150", "--print-every", "10"])
    printed = capsys.readouterr().out
    assert rc == 0
    rows = _errors_rows(DURATION_S)
    # --duration: exactly the rows of the first DURATION_S seconds, and no more simulated time than asked
    assert len(d["answers"]) == len(rows) == 30
    assert d["simulated_s"] <= DURATION_S + 10 + 1 and d["duration_s"] == DURATION_S
    board = np.array([a["offset_um"] for a in d["answers"]])
    measured = np.array([float(r["error_um"]) for r in rows])
    assert [a["time_s"] for a in d["answers"]] == [float(r["time_s"]) for r in rows]
    with open(models / "pred.csv", newline="") as f:
        host = np.array([float(r["predicted_um"]) for r in csv.DictReader(f)])[:len(rows)]
    (name, c), = d["judge"]["channels"].items()
    assert name == "X"  # the run's axis: its errors.csv has no channel column
    for key, r in (("against_measurement", measured - board), ("against_host_model", board - host),
                   ("host_model_against_measurement", measured - host)):
        s = c[key]
        tol = 1e-9 if key == "against_measurement" else 6e-5  # predict's CSV has 4 decimals
        assert s["rows"] == 30
        assert s["rmse_um"] == pytest.approx(float(np.sqrt(np.mean(r ** 2))), abs=tol), key
        assert s["max_abs_um"] == pytest.approx(float(np.abs(r).max()), abs=tol), key
        assert (s["max_um"], s["min_um"]) == pytest.approx((float(r.max()), float(r.min())), abs=tol), key
    # the integer table on the board stays near its model (the slew limiter lags a sweep's quick position steps)
    assert c["against_host_model"]["rmse_um"] < 1.0
    # printed: per channel by name, the three comparisons, frames labelled by name (the fault on T2, the axis)
    assert "channel X: 30 rows" in printed
    for what in ("board vs measured", "host model vs measured", "board vs host model"):
        assert what in printed
    assert "faulty T2" in printed and "SENSORS:" not in printed and "$TC," not in printed
    assert " X at 0.000 mm: " in printed


def test_a_wrong_table_is_judged_far_off(tmp_path, models, capsys):
    _, good = _hil(tmp_path, str(models / "m.bin"), str(models / "m.json"), "cpython", ["--print-every", "0"])
    _, bad = _hil(tmp_path, str(models / "wrong.bin"), str(models / "m.json"), "cpython", ["--print-every", "0"])
    g, b = good["judge"]["channels"]["X"], bad["judge"]["channels"]["X"]
    measured_span = max(abs(float(r["error_um"])) for r in _errors_rows(DURATION_S))
    assert measured_span > 5.0  # the sweep at 900 s has an error worth compensating
    assert b["against_measurement"]["rmse_um"] > 3 * g["against_measurement"]["rmse_um"]
    assert b["against_host_model"]["max_abs_um"] > measured_span  # twice the thermal part, far beyond the limiter
    assert g["against_host_model"]["max_abs_um"] < 0.5 * b["against_host_model"]["max_abs_um"]


def test_channels_of_a_multi_channel_run_are_judged_by_name(tmp_path, capsys):
    """data/fl_thermal has five errors channels; the dynamic table models ch1 (its document's channel): every
    channel is judged by name against the measurement, only ch1 against the host model."""
    from hil_tests.rig import interpreters
    interpreters.get().require()
    run = os.path.join(ROOT, "data", "fl_thermal")
    doc = os.path.join(ROOT, "hil_tests", "fixtures", "dynamic_fl_thermal_ch1.json")
    assert tcomp(["export", doc, "--out", str(tmp_path / "d.bin")]) == 0
    capsys.readouterr()
    assert tcomp(["hil", "--run", run, "--table", str(tmp_path / "d.bin"), "--model", doc, "--duration", "300",
                  "--print-every", "0", "--json", str(tmp_path / "h.json")]) == 0
    printed = capsys.readouterr().out
    d = json.loads((tmp_path / "h.json").read_text())
    with open(os.path.join(run, "errors.csv"), newline="") as f:
        rows = [r for r in csv.DictReader(f) if float(r["time_s"]) <= 300]
    names = sorted({r["channel"] for r in rows})
    assert names == ["ch1", "ch2", "ch3", "ch4", "ch5"]
    j = d["judge"]
    assert j["output"] == "ch1" and sorted(j["channels"]) == names
    board = np.array([a["offset_um"] for a in d["answers"]])
    for name in names:
        mask = np.array([r["channel"] == name for r in rows])
        r = np.array([float(x["error_um"]) for x in rows])[mask] - board[mask]
        c = j["channels"][name]
        assert c["rows"] == int(mask.sum()) and c["against_measurement"]["rmse_um"] == pytest.approx(
            float(np.sqrt(np.mean(r ** 2))), abs=1e-9)
        assert (c["against_host_model"] is None) == (name != "ch1")
        assert ("channel %s: %d rows" % (name, mask.sum())) in printed
    assert j["channels"]["ch1"]["against_host_model"]["rmse_um"] < 0.2
    assert "channel ch2: %d rows (the board computes ch1)" % j["channels"]["ch2"]["rows"] in printed
    assert [a["channel"] for a in d["answers"]] == [r["channel"] for r in rows]
