"""tcomp report: ISO 230-3-style drift figures, checked against drift written into the run by the test."""
import json
import os
import re

import numpy as np
import pytest

from host.cli import main
from host.data.runs import write_run

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRAIN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")
CHECK = os.path.join(ROOT, "data", "demo", "v8000_r0_700")


def test_report_figures_are_the_drift_written_into_the_run(make_run, tmp_path, capsys):
    run = make_run()  # errors 0.01 µm/mm · P · (1 + t / 7200 s): each target drifts linearly with time
    t_last = float(run.errors.time_s.max())
    still = make_run()
    still.motion = None
    paths = [write_run(run, str(tmp_path / "moving")), write_run(still, str(tmp_path / "still"))]
    out = str(tmp_path / "rep")
    assert main(["report"] + paths + ["--out", out]) == 0
    doc = json.load(open(os.path.join(out, "report.json")))
    for entry in doc["runs"]:
        (g,) = entry["groups"]
        positions = g["before"]["positions"]
        assert [p["position_mm"] for p in positions] == pytest.approx(np.linspace(0, 700, 8).tolist())
        for p in positions:
            assert p["max_drift_um"] == pytest.approx(0.01 * p["position_mm"] * t_last / 7200.0, abs=1e-9)
            assert p["drift_range_um"] == pytest.approx(0.01 * p["position_mm"] * t_last / 7200.0, abs=1e-9)
        pc = g["before"]["positioning_change"]
        assert (pc["from_mm"], pc["to_mm"]) == (0.0, 700.0)
        assert pc["max_positioning_change_um"] == pytest.approx(0.01 * 700 * t_last / 7200.0)
        assert "after" not in g
    assert [e["etve_applicable"] for e in doc["runs"]] == [False, True]
    # every plot the HTML shows is in the folder, and every PNG is shown
    html = open(os.path.join(out, "report.html")).read()
    shown = set(re.findall(r"src='([^']+)'", html))
    assert shown == {f for f in os.listdir(out) if f.endswith(".png")} and len(shown) == 6


def test_report_after_compensation_is_the_residual_of_predict(tmp_path, capsys):
    model = str(tmp_path / "m.json")
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", "T1,T2,T3,T4,T5", "--out", model]) == 0
    pred_json = str(tmp_path / "p.json")
    assert main(["predict", model, CHECK, "--out", str(tmp_path / "p.csv"), "--json", pred_json]) == 0
    out = str(tmp_path / "rep")
    assert main(["report", CHECK, "--model", model, "--out", out]) == 0
    doc = json.load(open(os.path.join(out, "report.json")))
    entry = doc["runs"][0]
    assert entry["residuals"]["error"]["rmse_um"] == pytest.approx(json.load(open(pred_json))["rmse_um"], rel=1e-12)
    g = entry["groups"][0]
    assert g["after"]["max_drift_um"] < g["before"]["max_drift_um"] / 3  # the model removes most of the drift


def test_report_never_writes_into_a_run(tmp_path, capsys):
    rc = main(["report", CHECK, "--out", os.path.dirname(CHECK)])
    assert rc == 2 and "the folder holds the input" in capsys.readouterr().err


def test_report_groups_channels_and_directions(make_run, tmp_path, capsys):
    run = make_run(bidirectional=True, channels=["X1", "X2"])
    run.errors.error_um = run.errors.error_um * np.where(run.errors.channel == "X1", 1.0, 2.0)  # X2 drifts twice as much
    t_last = float(run.errors.time_s.max())
    out = str(tmp_path / "rep")
    assert main(["report", write_run(run, str(tmp_path / "r")), "--out", out]) == 0
    groups = json.load(open(os.path.join(out, "report.json")))["runs"][0]["groups"]
    assert [g["group"] for g in groups] == ["X1 forward", "X2 reverse"]
    for g, k in zip(groups, (1.0, 2.0)):
        assert g["before"]["positioning_change"]["max_positioning_change_um"] == pytest.approx(k * 0.01 * 700 * t_last / 7200.0)
