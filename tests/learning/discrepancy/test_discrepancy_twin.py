"""The workflow on digital-twin data with effects hidden (seeds, magnitudes and noise differ from development).

The candidates are configurations of host/learning/screw's ScrewModel (host/learning/discrepancy/family.py);
the twin (host/twin) has its own physics. To keep make test fast the runs are shortened versions of the
literature states (two hours each: a heating state, a change of state, a cool-down); tools/bench_discrepancy.py
runs the full protocols over many seeds."""
import json
import os

import numpy as np
import pytest

from host.cli import main
from host.learning.discrepancy.family import ScrewFamily
from host.learning.discrepancy.workflow import ALPHA, MIN_GAIN, discover
from host.learning.documents import load_model
from host.data.runs import load_run, write_run
from host.twin import EFFECTS, simulate_run
from hil_tests.fixtures.shortruns import PROTOCOLS, twin_runs

SLOW = os.environ.get("TCOMP_SLOW") == "1"
# The twin (host/twin/screw.py, docs/twin.md) keeps its screw at absolute temperature in a drifting air,
# so the base model's air term is on (its default) everywhere here except where a test removes it.
# speed_dependent_heat, bearing_heat and moving_convection: test_discrepancy_twin_heat.py (the other worker).


@pytest.mark.parametrize("name,scale,noise,seed", [
    ("ambient_expansion", 0.8, 0.4, 424242),
    ("reversal_error", 0.9, 0.55, 424246),
])
def test_hidden_effect_named_first_and_gap_halved(name, scale, noise, seed):
    res = discover(twin_runs({name: scale * EFFECTS[name].default}, seed, noise), ScrewFamily(), jobs=1)
    assert res.effects and res.effects[0] == name, res.as_json()["candidates"]
    assert res.after.rmse() <= 0.5 * res.before.rmse()
    # once the effect is in, the held-out residual is at the laser noise level
    assert res.after.rmse() < 1.3 * noise
    if name == "reversal_error":
        loc = {d["factor"]: d for d in res.rounds[0].localization}
        assert loc["direction"]["share"] > 0.5


def test_two_hidden_effects_both_named():
    res = discover(twin_runs({"ambient_expansion": 1.1, "moving_convection": 0.8}, 515151, 0.5), ScrewFamily(), jobs=1)
    assert set(res.effects) == {"ambient_expansion", "moving_convection"}
    assert res.after.rmse() < 0.65
    acc = {c["name"]: c for c in res.as_json()["candidates"] if c["accepted"]}
    assert set(acc) == set(res.effects)
    assert all(c["p_value"] < ALPHA and c["score"] >= MIN_GAIN for c in acc.values())


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="five rounds of candidate fits: TCOMP_SLOW=1")
def test_all_five_hidden_all_named():
    hidden = {"ambient_expansion": 0.9, "speed_dependent_heat": 0.5, "bearing_heat": 3.5, "moving_convection": 1.1, "reversal_error": 3.0}
    res = discover(twin_runs(hidden, 525252, 0.45), ScrewFamily())
    assert set(res.effects) == set(hidden)
    assert res.after.rmse() < 1.2 * 0.45


@pytest.mark.slow
def test_false_discovery_rate_on_the_null():
    """No effect hidden: the share of seeds where anything is named is at most 1 in 20.

    Reduced form: 1 seed, it may not name an effect; TCOMP_SLOW=1: 40 seeds, <= 2 may
    (tools/bench_discrepancy.py counts the same over more seeds and all effects).
    """
    n = 40 if os.environ.get("TCOMP_SLOW") == "1" else 1
    rng = np.random.default_rng(99)
    named, ratios = [], []
    for k in range(n):
        noise = float(rng.uniform(0.3, 1.0))
        res = discover(twin_runs(None, 818181 + k, noise), ScrewFamily(), jobs=1)
        named.append(res.effects)
        ratios.append(res.before.rmse() / noise)
    falses = sum(bool(e) for e in named)
    assert falses / n <= 0.05, named
    # the base model alone is at the laser noise on data with nothing hidden (issue 11 budget: <= 1.25 x)
    assert max(ratios) <= 1.25, ratios


def _write(runs, root):
    folders = []
    for r in runs:
        folders.append(write_run(r, os.path.join(root, r.name)))
    return folders


def test_cli_end_to_end(tmp_path):
    folders = _write(twin_runs({"bearing_heat": 4.0}, 717171, 0.5), str(tmp_path / "runs"))
    out, rep = tmp_path / "out.json", tmp_path / "report"
    # the 60 s budget on four runs is measured by tools/bench_discrepancy.py, not asserted here (a shared machine)
    assert main(["discrepancy", *folders, "--json", str(out), "--report", str(rep)]) == 0
    js = json.loads(out.read_text())
    assert js["effects"][0] == "bearing_heat"
    assert isinstance(js["rmse_before_um"], float) and js["rmse_after_um"] <= 0.5 * js["rmse_before_um"]
    assert [r["run"] for r in js["per_run"]] == [os.path.basename(f) for f in folders]
    assert {c["name"] for c in js["candidates"]} == set(ScrewFamily().catalog)
    for c in js["candidates"]:
        assert set(c) >= {"name", "score", "p_value", "accepted"}
    assert js["localization"] and all("factor" in d and "share" in d for d in js["localization"])
    for f in ("report.md", "residual_map.png", "error_curves.png", "model.json"):
        assert (rep / f).stat().st_size > 0
    ev = js["evidence"][0]
    assert ev["effect"] == "bearing_heat" and ev["rmse_after_um"] < ev["rmse_before_um"] and ev["where"]
    assert "**bearing_heat** (round 1)" in (rep / "report.md").read_text()
    model = load_model(str(rep / "model.json"))
    assert model.to_document()["kind"] == "screw"
    run = load_run(folders[0])
    rmse = float(np.sqrt(np.mean((model.predict(run) - run.errors.error_um) ** 2)))
    assert rmse < 1.0  # the saved model carries the bearing heat
    # issue 19's case: the model the workflow validated exports with the bearing heat in the table, and the
    # board equals the host model within the certificate (was: board 20.0 um, host 40.9 um at 1800 s, 500 mm)
    from hil_tests.fixtures.boardplay import board_offsets
    from models_export import export_model
    doc = json.loads((rep / "model.json").read_text())
    red = doc["thermal"]["reduced"]
    assert [e["name"] for e in doc["thermal"]["effects"]] == ["bearing_heat"] and "omitted_effects" not in red
    assert red["travel_heat_K_per_mm"][0] > 0
    assert main(["export", str(rep / "model.json"), "--out", str(tmp_path / "t.bin"), "--json", str(tmp_path / "c.json")]) == 0
    cert = json.loads((tmp_path / "c.json").read_text())
    ex = export_model(doc)
    board = board_offsets(ex.table, run)
    host = model.predict(run)
    fr = red["reduction_error_um"][run.path or run.name]["feed_range"]["rows_max_um"]
    bound = cert["max_error_um"] + fr + 0.0005 * red["alpha_um_per_mm_per_K"] * np.abs(run.errors.position_mm) + 0.01
    assert np.all(np.abs(board - host) <= bound), float(np.max(np.abs(board - host) - bound))
    late = np.flatnonzero(run.errors.time_s >= 1800)
    assert np.max(np.abs(host[late])) > 10.0  # the bearing heat is in both, tens of um


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="a robustness scenario of the workflow (a discrepancy run each): TCOMP_SLOW=1")
def test_missing_sweep_and_sensor_dropout_still_work(tmp_path):
    runs = twin_runs({"ambient_expansion": 1.0}, 727272, 0.5)
    # a missing sweep: drop every row of the 5th sweep of the first run
    e = runs[0].errors
    t5 = np.unique(e.time_s)[4]
    keep = e.time_s != t5
    for k in ("time_s", "position_mm", "error_um"):
        setattr(e, k, getattr(e, k)[keep])
    # a sensor dropout: the base sensor's column is gone from the second run
    t = runs[1].temperatures
    base = runs[1].sensors_with_role("base")[0]
    j = t.names.index(base)
    t.values = np.delete(t.values, j, axis=1)
    t.names = [n for n in t.names if n != base]
    runs[1].meta = dict(runs[1].meta, sensors={k: v for k, v in runs[1].meta["sensors"].items() if k != base})
    res = discover(runs, ScrewFamily(), jobs=1)
    amb = [c for c in res.rounds[0].candidates if c.name == "ambient_expansion"][0]
    assert amb.skipped and "role 'base'" in amb.skipped
    assert np.isfinite(res.before.rmse())


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="a robustness scenario of the workflow (a discrepancy run each): TCOMP_SLOW=1")
def test_single_run_time_split():
    run = simulate_run(PROTOCOLS[2], effects={"reversal_error": 4.0}, seed=737373, noise_um=0.5)
    res = discover([run], ScrewFamily(), jobs=1)
    assert res.effects[:1] == ["reversal_error"]
    assert np.all(np.isfinite(res.before.residuals[0]))


def test_clear_errors(tmp_path, capsys):
    run = simulate_run("v8000_r210_490", seed=1)
    folder = write_run(run, str(tmp_path / "r"))
    os.remove(os.path.join(folder, "motion.csv"))
    assert main(["discrepancy", folder, "--json", str(tmp_path / "o.json"), "--report", str(tmp_path / "rep")]) == 2
    assert "none of the runs has a motion.csv" in capsys.readouterr().err
    assert main(["discrepancy", str(tmp_path / "nope"), "--json", str(tmp_path / "o.json"), "--report", str(tmp_path / "rep")]) == 2
    assert "not a folder" in capsys.readouterr().err
    folder2 = write_run(run, str(tmp_path / "r2"))
    assert main(["discrepancy", folder2, "--candidates", "bogus", "--json", str(tmp_path / "o.json"), "--report", str(tmp_path / "rep")]) == 2
    assert "unknown effect" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="a robustness scenario of the workflow (a discrepancy run each): TCOMP_SLOW=1")
def test_json_alone_and_the_residual_diagnostic(tmp_path):
    # --report is optional: the JSON alone carries every field, the model fields are null
    folders = _write(twin_runs(None, 747474, 0.5), str(tmp_path / "runs"))
    out = tmp_path / "out.json"
    assert main(["discrepancy", *folders, "--json", str(out)]) == 0
    js = json.loads(out.read_text())
    assert js["effects"] == [] and js["model"] is None and js["model_error"] is None
    assert js["unexplained"] == []  # the base model is right: no signal passes the threshold on the null
    names = {d["signal"] for d in js["unexplained_all"]}
    assert {"d(T_air)/dt", "feed", "position x time"} <= names
    air = load_run(folders[0]).sensors_with_role("ambient")[0]
    assert "rise(%s)" % air not in names  # with the air term the air sensor is a model input, not a candidate
    assert not (tmp_path / "report").exists()


def test_residual_diagnostic_names_a_signal_the_model_lacks():
    # the model with the air term off misses the screw's lag behind the air: the diagnostic must say so
    from host.learning.discrepancy.report import residual_diagnostic
    from host.learning.discrepancy.unexplained import summary

    runs = twin_runs(None, 757575, 0.4)
    fam = ScrewFamily(air=False)
    res = discover(runs, fam, candidates=[], jobs=1)
    diag = residual_diagnostic(res, fam)
    hits = summary(diag)
    assert hits, diag[:3]
    # without the air term the whole air-driven expansion is missing: an air sensor's rise (x P) leads
    air = {"rise(%s)" % n for n in runs[0].sensors_with_role("ambient")} | {"d(T_air)/dt"}
    assert hits[0]["signal"] in air, diag[:3]
    assert hits[0]["rmse_share"] >= 0.05


@pytest.mark.slow
@pytest.mark.skipif(not SLOW, reason="a robustness scenario of the workflow (a discrepancy run each): TCOMP_SLOW=1")
def test_cli_reports_what_is_left_when_no_catalog_effect_passes(tmp_path):
    # the air term off and only a candidate that does not fit (sweeps go one way): the screw's lag behind the drifting air is left in the residual, and
    # the JSON's `unexplained` and the text report must name it with its evidence (issue 11, point 5)
    folders = _write(twin_runs(None, 757575, 0.4), str(tmp_path / "runs"))
    out, rep = tmp_path / "out.json", tmp_path / "report"
    assert main(["discrepancy", *folders, "--json", str(out), "--report", str(rep), "--air", "off", "--candidates", "reversal_error"]) == 0
    js = json.loads(out.read_text())
    assert js["effects"] == [] and js["unexplained"], js["unexplained_all"][:3]
    for d in js["unexplained"]:
        assert set(d) == {"signal", "partial_r", "rmse_share"}
        assert abs(d["partial_r"]) >= 0.25 and 0 < d["rmse_share"] < 1
    air = {"rise(%s)" % n for n in load_run(folders[0]).sensors_with_role("ambient")} | {"d(T_air)/dt"}
    assert js["unexplained"][0]["signal"] in air
    text = (rep / "report.md").read_text()
    assert "held-out RMSE follows %s: partial r" % js["unexplained"][0]["signal"] in text
