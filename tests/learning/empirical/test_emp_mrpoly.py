"""S004's multiple-regression model (Eq. 12) as ``tcomp fit --model mr-poly`` and a ``tcomp compare`` row."""
import json
import subprocess
import sys

import numpy as np
import pytest

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.fitting import fit_model
from host.data.runs import Errors, Run, write_run
from host.learning.documents import load_model

# the truth: s = c + a1 dTn + a2 dTn^2 + a3 dTn^3 + a4 dTn^4 + b1 dTb (um/mm), rises over the run start
TRUTH = {"c": 0.0005, "a": [0.002, 4e-4, -3e-5, 1.5e-6], "b": 0.006}


def eq12_run(make_slope, seed=0, name="s1", nut="T1", base="T2", truth=TRUTH):
    """A slope run whose sweeps follow S004's Eq. 12 exactly on the rises of ``nut`` and ``base``."""
    r = make_slope(name=name, seed=seed, coef=(0.0, 0.0), n_sweeps=16, n_sensors=4)
    e, temps = r.errors, r.temperatures
    d_n = np.interp(e.time_s, temps.time_s, temps.column(nut) - temps.column(nut)[0])
    d_b = np.interp(e.time_s, temps.time_s, temps.column(base) - temps.column(base)[0])
    s = truth["c"] + sum(a * d_n ** (j + 1) for j, a in enumerate(truth["a"])) + truth["b"] * d_b
    meta = json.loads(json.dumps(r.meta))
    meta["sensors"][nut]["role"] = "nut"
    meta["sensors"][base]["role"] = "base"
    return Run(meta, temps, Errors(e.time_s, e.position_mm, e.error_um + s * e.position_mm, e.direction, e.channel), name=name)


def test_mr_poly_recovers_equation_12(make_slope):
    run = eq12_run(make_slope)
    model = fit_model([run], method="mr-poly", reference="run_start")
    assert model.kind == "mr_poly" and model.sensors == ["T1", "T2"] and model.degree == 4
    np.testing.assert_allclose(model.nut_coefficients, TRUTH["a"], rtol=1e-5, atol=1e-10)
    assert model.base_coefficient == pytest.approx(TRUTH["b"], rel=1e-5)
    # the slope target is k_i - k_0 (docs/empirical.md): c belongs to the cold sweep, i.e. the geometric polynomial
    assert model.intercept == pytest.approx(0.0, abs=1e-6)
    assert model.geometric_coef[1] == pytest.approx(0.01 + TRUTH["c"], abs=1e-6)  # make_slope_run's geo slope + c
    pred = model.predict(run)
    assert np.max(np.abs(pred - run.errors.error_um)) < 1e-3


def test_mr_poly_degree_is_exact_and_roles_are_overridable(make_slope):
    run = eq12_run(make_slope, nut="T3", base="T4")  # roles on T3, T4
    m2 = fit_model([run], method="mr-poly", degree=2)
    assert m2.degree == 2 and m2.sensors == ["T3", "T4"]
    other = fit_model([run], method="mr-poly", nut="T2", base="T1")
    assert other.sensors == ["T2", "T1"]
    with pytest.raises(EmpiricalDataError, match="degree must be an integer 1..4"):
        fit_model([run], method="mr-poly", degree=5)
    with pytest.raises(EmpiricalDataError, match="must differ"):
        fit_model([run], method="mr-poly", nut="T1", base="T1")
    plain = make_slope()
    with pytest.raises(EmpiricalDataError, match="no sensor with role 'nut'.*--option nut=SENSOR"):
        fit_model([plain], method="mr-poly")


def test_fit_cli_writes_an_mr_poly_document_that_predicts_by_the_formula(make_slope, tmp_path):
    run = eq12_run(make_slope)
    folder = str(tmp_path / "s1")
    write_run(run, folder, decimals=10)
    out = str(tmp_path / "m1.json")
    p = subprocess.run([sys.executable, "-m", "host", "fit", folder, "--model", "mr-poly", "--option", "degree=4", "--out", out],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "S004 Eq. 12, nut T1, base T2, degree 4" in p.stdout
    with open(out) as fh:
        doc = json.load(fh)
    th = doc["thermal"]
    assert doc["kind"] == "mr_poly" and th["nut_sensor"] == "T1" and th["base_sensor"] == "T2" and th["degree"] == 4
    # the document's numbers evaluated by hand: geometric(P) + (c + sum a_j dTn^j + b dTb) * P, fixed references
    e, temps = run.errors, run.temperatures
    dn = np.interp(e.time_s, temps.time_s, temps.column("T1")) - doc["reference_C"]["T1"]
    db = np.interp(e.time_s, temps.time_s, temps.column("T2")) - doc["reference_C"]["T2"]
    s = th["intercept"] + sum(a * dn ** (j + 1) for j, a in enumerate(th["nut_coefficients"])) + th["base_coefficient"] * db
    geo = sum(g * e.position_mm ** j for j, g in enumerate(doc["geometric"]["coefficients_um"]))
    np.testing.assert_allclose(load_model(out).predict(run), geo + s * e.position_mm, rtol=1e-9, atol=1e-9)


def test_compare_has_an_mr_poly_row(make_slope):
    from host.learning.empirical.compare import cases_runs, run_case

    runs = [eq12_run(make_slope, seed=i, name="s%d" % i) for i in range(3)]
    res = run_case(cases_runs(runs)[0], ["mlr", "mr-poly"], robustness={"repeats": 1})
    row = next(r for r in res if r["method"] == "mr-poly")
    assert not row.get("error") and row["sensors"] == ["T1", "T2"]
    assert row["mean_test_rmse_um"] < 0.05  # Eq. 12 is the truth of these runs
