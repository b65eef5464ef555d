"""tcomp compare: cases, robustness, findings, plots, and the time split of one run."""
import json
import os

import numpy as np
import pytest

from host.learning.empirical import EmpiricalDataError
from host.cli import main
from host.learning.empirical.compare import METHODS, case_split, cases_runs, findings, run_case, table
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.schedule import cycles, segments
from host.learning.documents import save_model

FAST_GA = {"hclust-ga": {"population": 6, "generations": 3}}


@pytest.fixture
def three_runs(make_slope):
    return [make_slope(name="r%d" % i, seed=i, noise_um=0.05, offset_C=20 + 2 * i) for i in range(3)]


def test_compare_needs_two_runs(make_slope):
    with pytest.raises(EmpiricalDataError, match="at least 2 runs"):
        cases_runs([make_slope()])
    with pytest.raises(EmpiricalDataError, match="out of range"):
        cases_runs([make_slope(), make_slope(seed=1)], train=[5])


def test_every_method_side_by_side(three_runs):
    cases = cases_runs(three_runs, train=[0])
    res = run_case(cases[0], METHODS, selector_params=FAST_GA, options={"stepwise": {"f_enter": 4.0, "f_remove": 2.0},
                                                                        "mr-poly": {"nut": "T1", "base": "T2"}})
    assert [r["method"] for r in res] == list(METHODS)
    ok = [r for r in res if not r.get("error")]
    assert [r["method"] for r in ok] == list(METHODS), [r.get("error") for r in res]
    assert next(r for r in ok if r["method"] == "stepwise")["sensors"] == ["T1", "T2"]
    for r in ok:
        assert set(r["tests"]) == {"r1", "r2"} and set(r["disturbed"]) == {"r1", "r2"}
        assert set(r["sensors"]) <= set(three_runs[0].temperatures.names) and r["n_sensors"] == len(r["sensors"])
        for m in r["tests"].values():
            assert m["min_residual_um"] <= m["max_residual_um"] and m["rmse_um"] >= 0
        assert r["mean_test_rmse_um"] == pytest.approx(np.mean([m["rmse_um"] for m in r["tests"].values()]))
    mlr = next(r for r in ok if r["method"] == "mlr")
    # noise-free slope data generated from T1, T2: MLR predicts other runs to laser-noise level
    assert mlr["mean_test_rmse_um"] < 0.2
    text = table(res)
    assert "r1" in text and "mlr" in text
    notes = findings(res)
    assert any("PCR" in n and "MLR" in n for n in notes) and any("degrades least" in n for n in notes)


def test_robustness_without_disturbance_equals_clean(three_runs):
    case = cases_runs(three_runs)[0]
    res = run_case(case, ["mlr", "pcr"], robustness={"noise_C": 0.0, "offset_C": 0.0, "repeats": 2})
    for r in res:
        for k in r["tests"]:
            assert r["disturbed"][k]["rmse_um"] == pytest.approx(r["tests"][k]["rmse_um"], rel=1e-12)
        assert r["degradation_um"] == pytest.approx(0.0, abs=1e-12)
    res = run_case(case, ["mlr"], robustness={"noise_C": 0.3, "offset_C": 0.5})
    assert res[0]["degradation_um"] > 0


def test_schedule_cycles(make_direct):
    run = make_direct(spindle=True)
    segs = segments(run)
    assert segs[0][2] == 0 and segs[1][2] == 1000
    cyc = cycles(run)
    assert [c["speeds_rpm"] for c in cyc] == [[1000], [2000], [3000], [4000], [1500, 2500]]
    assert [c["constant"] for c in cyc] == [True] * 4 + [False]
    assert cyc[0]["t_start_s"] == 0 and cyc[1]["t_start_s"] == 7800


def test_time_split_case_sees_no_held_out_data(make_direct):
    run = make_direct(spindle=True, noise_um=0.2)
    split = cycles(run)[3]["t_start_s"]
    case = case_split(run, split, "direct", "ch1", test_windows=[("4000 rpm", (split, 29400.0))])
    assert case.window == (None, split)
    assert all(a.time_s.max() < split for a in case.ga_data) and len(case.ga_data) == 3
    res = run_case(case, METHODS, "direct", "ch1", selector_params=FAST_GA)
    ok = {r["method"]: r for r in res if not r.get("error")}
    assert {"mlr", "pcr", "cv-subset"} <= set(ok)
    held = case.tests[0][0]
    assert ok["mlr"]["tests"][held]["rmse_um"] < 1.0  # ch1 is linear in t1, t2 rises plus 0.2 um noise
    assert ok["mlr"]["mean_test_rmse_um"] == ok["mlr"]["tests"][held]["rmse_um"]  # sub-windows are not averaged in
    assert set(ok["cv-subset"]["sensors"]) >= {"t1", "t2"} and ok["cv-subset"]["n_sensors"] <= 5


def test_time_split_without_schedule_reports_hclust_ga(make_direct):
    run = make_direct()
    case = case_split(run, 18000.0, "direct", "ch1")
    res = run_case(case, ["mlr", "hclust-ga"], "direct", "ch1")
    assert res[1]["error"] and "spindle" in res[1]["error"]
    assert not res[0].get("error")


def test_compare_cli_writes_json_and_titled_plots(tmp_path, three_runs, capsys):
    from host.cli import main
    from host.data.runs import write_run

    folders = [write_run(r, str(tmp_path / r.name)) for r in three_runs]
    out = str(tmp_path / "cmp.json")
    rc = main(["compare"] + folders + ["--json", out, "--plots", str(tmp_path / "plots"), "--methods", "mlr,pcr,stepwise,cv-subset", "--repeats", "2"])
    assert rc == 0
    doc = json.load(open(out))
    assert [r["method"] for r in doc["results"]] == ["mlr", "pcr", "stepwise", "cv-subset"]
    pngs = sorted(os.listdir(tmp_path / "plots"))
    assert "case1_pcr_scree.png" in pngs and "case1_residuals.png" in pngs and "case1_mlr_curves.png" in pngs
    for p in doc["plots"]:
        assert open(p, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    assert "findings" in doc and doc["findings"]
    assert main(["compare", folders[0], "--json", out]) == 2
    assert "at least 2 runs" in capsys.readouterr().err
    assert main(["compare"] + folders + ["--json", out, "--methods", "mlr,foo"]) == 2


def test_compare_cli_split_of_one_run(tmp_path, make_direct):
    from host.cli import main
    from host.data.runs import write_run

    run = make_direct(spindle=True, noise_um=0.2)
    folder = write_run(run, str(tmp_path / "d"))
    out = str(tmp_path / "s.json")
    assert main(["compare", folder, "--split-h", "6.1", "--direct", "--channel", "ch2", "--json", out,
                 "--methods", "mlr,stepwise,cv-subset", "--reference", "fixed", "--repeats", "1"]) == 0
    doc = json.load(open(out))
    assert doc["reference"] == "fixed" and doc["target"] == "direct"
    res = {r["method"]: r for r in doc["results"]}
    assert list(res["mlr"]["tests"]) == ["held-out (t >= 6.10 h)"]
    assert res["stepwise"]["sensors"] == ["t1", "t2"]


def test_compare_cli_method_options(tmp_path, three_runs, capsys):
    from host.cli import main
    from host.data.runs import write_run

    folders = [write_run(r, str(tmp_path / r.name)) for r in three_runs]
    out = str(tmp_path / "o.json")
    assert main(["compare"] + folders + ["--json", out, "--methods", "pcr,cv-subset", "--repeats", "1",
                                         "--option", "pcr.n_components=1", "--option", "cv-subset.max_sensors=1"]) == 0
    res = {r["method"]: r for r in json.load(open(out))["results"]}
    assert res["pcr"]["fit"]["n_components"] == 1 and res["cv-subset"]["n_sensors"] == 1
    assert main(["compare"] + folders + ["--json", out, "--option", "pcr.bogus=1"]) == 2
    assert "no setting 'bogus'" in capsys.readouterr().err
    assert main(["compare"] + folders + ["--json", out, "--option", "nothing"]) == 2


def test_split_just_after_a_cycle_start_does_not_make_a_tiny_group(make_direct):
    from host.learning.empirical.fitting import merge_small_groups

    g = merge_small_groups(np.array([0] * 50 + [1] * 40 + [2] * 3))
    assert g.tolist() == [0] * 50 + [1] * 43
    assert merge_small_groups(np.array([0] * 2 + [1] * 40 + [2] * 40)).tolist() == [1] * 42 + [2] * 40
    run = make_direct(spindle=True, noise_um=0.2)
    exact = cycles(run)[3]["t_start_s"]
    a = case_split(run, exact, "direct", "ch1")
    b = case_split(run, exact + 120.0, "direct", "ch1")
    assert len(a.ga_data) == len(b.ga_data) == 3
    from host.learning.empirical.fitting import cv_groups
    from host.learning.empirical.targets import training_arrays

    for case in (a, b):
        arrays = training_arrays([run], "direct", "ch1", window=case.window)
        assert np.unique(cv_groups([run], arrays)).size == 3


def test_accuracy_is_also_reported_on_the_comprehensive_error(three_runs):
    from host.learning.empirical.scoring import score_model
    from host.learning.empirical.fitting import fit_model

    model = fit_model(three_runs[:1], "mlr")
    run = three_runs[1]
    m = score_model(model, run)
    # independent: every non-cold sweep row, whole measured error against geometric + slope * P
    e = run.errors
    cold_t = e.time_s.min()
    rows = np.flatnonzero(e.time_s > cold_t)
    P = e.position_mm[rows]
    R = run.temperatures.at(e.time_s[rows], model.sensors) - np.array([model.reference_C[s] for s in model.sensors])
    pred = np.polynomial.polynomial.polyval(P, model.geometric_coef) + (model.intercept + R @ model.coefficients) * P
    resid = e.error_um[rows] - pred
    c = m["comprehensive"]
    assert c["n"] == m["n"] == rows.size
    assert c["rmse_um"] == pytest.approx(np.sqrt(np.mean(resid**2)))
    rms = np.sqrt(np.mean(e.error_um[rows] ** 2))
    assert c["accuracy_pct"] == pytest.approx(100 * (1 - c["rmse_um"] / rms))
    # the geometric part is large here (1 µm + 0.01 P), so the whole error's RMS exceeds the thermal one
    assert c["rms_measured_um"] > m["rms_measured_um"]


def test_paper_pipelines_select_then_fit_each_model(three_runs):
    cases = cases_runs(three_runs, train=[0])
    res = {r["method"]: r for r in run_case(cases[0], ("maxtree", "maxtree-mlr", "maxtree-pcr", "maxtree-ann", "ann", "ppr"),
                                            options={"maxtree-ann": {"max_epochs": 300}, "ann": {"max_epochs": 300}}, robustness={"repeats": 1})}
    assert not any(r.get("error") for r in res.values()), {m: r.get("error") for m, r in res.items()}
    chosen = res["maxtree"]["sensors"]
    for m in ("maxtree-mlr", "maxtree-pcr", "maxtree-ann"):
        assert res[m]["sensors"] == chosen and res[m]["selection"]["chosen_partition"] == res["maxtree"]["selection"]["chosen_partition"]
    assert res["maxtree-mlr"]["tests"] == res["maxtree"]["tests"]  # the same pipeline under the paper's name
    assert res["maxtree-ann"]["coefficients"] is None and res["maxtree-ann"]["fit"]["hidden_size"] in (3, 4, 5, 6, 7)
    assert res["ann"]["n_sensors"] == len(three_runs[0].temperatures.names)
    for r in res.values():
        assert r["mean_test_rmse_um"] >= 0 and r["mean_test_comprehensive_accuracy_pct"] is not None


def test_compare_pools_training_runs(three_runs):
    # Li 2017's verification fits on two speeds pooled and predicts the third
    cases = cases_runs(three_runs, train=[(0, 1)])
    assert len(cases) == 1 and [r.name for r in cases[0].train] == ["r0", "r1"] and [t[0] for t in cases[0].tests] == ["r2"]
    res = run_case(cases[0], ["mlr"], robustness={"repeats": 1})
    pooled = fit_model(three_runs[:2], "mlr", reference="run_start")
    assert res[0]["coefficients"] == pytest.approx(dict(zip(pooled.sensors, pooled.coefficients.tolist())))
    with pytest.raises(EmpiricalDataError, match="leaves no run to predict"):
        cases_runs(three_runs, train=[(0, 1, 2)])


def test_hclust_ga_row_has_no_intercept_by_default(three_runs):
    # Li 2017 Eq. 16: y = sum b_s dT_s, no constant term
    case = cases_runs(three_runs)[0]
    plain = run_case(case, ["hclust-ga"], selector_params=FAST_GA, robustness={"repeats": 1})[0]
    assert not plain.get("error") and plain["intercept"] == 0.0 and "without intercept" in plain["note"]
    params = {"hclust-ga": dict(FAST_GA["hclust-ga"], intercept=True)}
    withc = run_case(case, ["hclust-ga"], selector_params=params, robustness={"repeats": 1})[0]
    assert withc["intercept"] != 0.0


def test_predict_reports_max_and_min_residual(three_runs, tmp_path):
    from host.data.runs import write_run

    folder = write_run(three_runs[1], str(tmp_path / "r1"), decimals=8)
    model = fit_model([three_runs[0]], "mlr")
    save_model(model.to_document(), str(tmp_path / "m.json"))
    assert main(["predict", str(tmp_path / "m.json"), folder, "--out", str(tmp_path / "p.csv"), "--json", str(tmp_path / "p.json")]) == 0
    with open(tmp_path / "p.json") as fh:
        rep = json.load(fh)
    with open(tmp_path / "p.csv") as fh:
        column = fh.readline().strip().split(",").index("predicted_um")  # measured_um, residual_um follow it
    pred = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)[:, column]
    measured = np.loadtxt(os.path.join(folder, "errors.csv"), delimiter=",", skiprows=1)[:, 2]
    r = measured - pred
    assert rep["max_residual_um"] == pytest.approx(r.max(), abs=2e-4) and rep["min_residual_um"] == pytest.approx(r.min(), abs=2e-4)
    assert rep["rmse_um"] == pytest.approx(np.sqrt(np.mean(r ** 2)), abs=2e-4)
