"""The export report's per-term figures (report["terms"][i]["max_error_um"]) are in micrometres, like the total.

Every Planner.term() call passes its contribution in output units (0.01 um). A term once passed in accumulator
units (2**fo finer) was reported 2**fo times too small; these tests fail if any kind mixes the units again.

Relations checked on every kind:
- upper: a term is one summand of the certified offset error interval, so its magnitude is at most the certified
  total (the total also holds the output rounding; margin: half an output unit, 0.005 um);
- lower: the certified total is at most the sum of the listed terms plus the integer floor roundings that are not
  listed. Direct kinds (linear_direct, dynamic "direct"), derived: S's error interval is the sum of the coefficient
  quantisations q_i (listed as max|q_i| >= half their width), the dynamic terms' state errors (listed) and k floors
  of one accumulator unit each (k <= limbs per product: nt per sensor, nY per filter); the intercept is a point and
  does not widen it. The output rounding r re-centres it, so |output error| <= half-width / 2**fo + 1/2 + 2**-(fo+1)
  output units, hence total <= sum(terms) + (k / 2 + 1/2) * 2**-fo output units. Positional kinds (poly_slope,
  screw, dynamic "slope") also floor inside S x position, the geometric Horner steps and the screw's segment sums,
  each at one accumulator unit or finer; there the test allows 0.1 output unit (the largest shortfall measured on
  these documents and the demo's MLR export is 0.009 output units).
  A term reported 2**fo too small breaks this: the coefficient terms make up most of a screw model's total, and the
  output rounding term (0.005 um) is in every total.
"""
import json
import random
from fractions import Fraction as F
from pathlib import Path

import pytest

from hil_tests.fixtures.samples import dynamic_doc, linear_direct_doc, poly_slope_doc, restamp, screw_doc
from models_export import export_model

FIXTURE = Path(__file__).resolve().parents[2] / "hil_tests" / "fixtures" / "dynamic_fl_thermal_ch1.json"
HALF_OU_UM = 0.005


def _docs():
    for seed in range(4):
        yield "poly_slope-%d" % seed, poly_slope_doc(random.Random(seed))
        yield "linear_direct-%d" % seed, linear_direct_doc(random.Random(seed))
        yield "screw-%d" % seed, screw_doc(random.Random(seed))
        yield "dynamic-direct-%d" % seed, dynamic_doc(random.Random(seed))
        yield "dynamic-slope-%d" % seed, dynamic_doc(random.Random(seed), target="slope")
    with open(FIXTURE) as fh:
        yield "dynamic_fl_thermal_ch1", json.load(fh)


DOCS = list(_docs())


@pytest.mark.parametrize("name,doc", DOCS, ids=[n for n, _ in DOCS])
def test_terms_bound_and_sum_to_the_certified_total(name, doc):
    ex = export_model(doc)
    rep = ex.report
    total = rep["max_error_um"]
    terms = rep["terms"]
    for t in terms:
        assert 0 <= t["max_error_um"] <= total + HALF_OU_UM, (name, t)
    rounding = [t for t in terms if t["name"].startswith("output rounding")]
    assert len(rounding) == 1 and rounding[0]["max_error_um"] == HALF_OU_UM, (name, rounding)
    f = ex.fields
    if "Lw" not in f:  # direct: no position product (the derived bound, module docstring)
        k = len(doc["sensors"]) * f["nt"] + f.get("nf", 0) * f.get("nY", 0)
        unlisted_um = (k / 2 + 0.5) * 2.0 ** -f["fo"] * 0.01
    else:
        unlisted_um = 0.1 * 0.01  # 0.1 output unit: see the module docstring
    listed = sum(t["max_error_um"] for t in terms)
    assert listed >= total - unlisted_um, (name, listed, total, unlisted_um)


def test_single_sensor_coefficient_term_by_hand():
    """linear_direct, one sensor over 0..40 degC referenced at 20 degC, 1/3 um/K: the coefficient's quantisation
    error is |q / 2**(sh + fo) - b| x 20000 mK, b = 1/3 um/K = 1/30 OU per mK (q, sh, fo: the table's integers)."""
    doc = linear_direct_doc(random.Random(0), n_sensors=1)
    (s,) = doc["sensors"]
    doc["reference_C"] = {s: 20.0}
    doc["envelope"]["temperature_C"] = {s: [0.0, 40.0]}
    doc["thermal"]["coefficients_um_per_K"] = {s: 1.0 / 3.0}
    restamp(doc)
    ex = export_model(doc, envelope={s: (0.0, 40.0)})
    f = ex.fields
    fo, q, sh = f["fo"], f["b"][0], f["shb"][0]
    b_ou_per_mK = F(1.0 / 3.0) * 100 / 1000
    err_ou = abs(F(q, 2 ** (sh + fo)) - b_ou_per_mK) * 20000
    assert err_ou > 0  # 1/3 is not a binary fraction: the case exercises a real quantisation error
    (term,) = [t for t in ex.report["terms"] if t["name"] == "thermal.coefficients_um_per_K.%s" % s]
    assert term["max_error_um"] == pytest.approx(float(err_ou / 100), rel=1e-12)
