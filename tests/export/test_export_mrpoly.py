"""S004's Eq. 12 (kind mr_poly) on the board: exported as a dynamic table whose tau-0 filters read the nut rise,
its powers (integer, one floored factor at a time) and the base rise; certified, and the firmware equals the
host's model within the certificate, bit-identically on MicroPython."""
import json
import random

import numpy as np
import pytest

from firmware.evaluate import Evaluator
from firmware.table import parse_table
from hil_tests.fixtures.samples import mr_poly_doc
from host.learning.empirical.fitting import fit_model
from host.learning.documents import load_model
from host.data.runs import load_run
from models_export import export_model
from models_export.certify import ExportError
from models_export.exact import mr_poly_as_dynamic


def _host_um(doc, temps_mc, ref_mc, pos_um):
    """The document's own formula in doubles (no tcomp code): geometric(P) + s*P or s, s from the rises."""
    th = doc["thermal"]
    dn = (temps_mc[0] - ref_mc[0]) / 1000.0
    db = (temps_mc[1] - ref_mc[1]) / 1000.0
    s = th["intercept"] + sum(a * dn ** (j + 1) for j, a in enumerate(th["nut_coefficients"])) + th["base_coefficient"] * db
    if th["target"] == "direct":
        return s
    P = pos_um / 1000.0
    return sum(g * P ** j for j, g in enumerate(doc["geometric"]["coefficients_um"])) + s * P


def _check_against_host(doc, n=400, seed=0):
    ex = export_model(doc)
    t = parse_table(ex.table)
    assert t.kind == "dynamic" and ex.report["document_kind"] == "mr_poly"
    assert all(a == 0 for a in t.A)  # every filter passes its input through (tau 0)
    ev = Evaluator(t, check=True)
    rng = random.Random(seed)
    worst = 0.0
    for k in range(n):
        temps = [rng.randint(lo, hi) for lo, hi in zip(t.env_lo, t.env_hi)]
        for i, v in enumerate(temps):
            ev.temps[i] = v
        ev.update()
        if k == 0 and t.ref_mode == 1:
            ev.latch_references()
        ev.step()
        pos = rng.randint(t.pos_lo, t.pos_hi)
        got = ev.offset_at(pos) / 100.0
        worst = max(worst, abs(got - _host_um(doc, temps, ev.ref, pos)))
    # every intermediate stayed inside the certified accumulator intervals, the power factors' included
    from firmware.evaluate import ACC_PMUL

    if len(doc["thermal"]["nut_coefficients"]) > 1:
        assert ACC_PMUL in ex.accs and ev.lo[ACC_PMUL] <= ev.hi[ACC_PMUL]
    for acc, (lo, hi) in ex.accs.items():
        if acc >= 0 and ev.lo[acc] <= ev.hi[acc]:  # seen at least once
            assert lo <= ev.lo[acc] and ev.hi[acc] <= hi, acc
    return ex, worst


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("target", ["slope", "direct"])
def test_board_equals_the_document_within_the_certificate(seed, target):
    doc = mr_poly_doc(random.Random(seed), target, degree=4 if seed < 2 else None)
    ex, worst = _check_against_host(doc, seed=seed)
    assert worst <= ex.report["max_error_um"] + 1e-9
    assert ex.report["max_error_um"] < ex.report["limit_um"]


def test_twin_m1_exports_and_the_board_follows_the_host_model(tmp_path):
    # M1 of S004 on the twin's state 1, as tcomp fit writes it; the host's predict() is the reference
    run = load_run("data/demo/v8000_r210_490")
    model = fit_model([run], method="mr-poly")
    doc = json.loads(json.dumps(model.to_document()))
    ex = export_model(doc)
    t = parse_table(ex.table)
    ev = Evaluator(t, check=True)
    e = run.errors
    host = load_model(doc).predict(run)
    worst = 0.0
    for i in range(0, len(e), 7):
        for j, s in enumerate(t.sensors):
            ev.temps[j] = int(round(float(run.temperatures.at(np.array([e.time_s[i]]), [s])[0, 0]) * 1000))
        ev.update()
        board = ev.offset_at(int(round(e.position_mm[i] * 1000))) / 100.0
        worst = max(worst, abs(board - host[i]))
    # the board reads millidegrees (rounding <= 0.5 mK per sensor) and micrometre positions: the certificate plus
    # that input rounding through the model's local sensitivity
    assert worst < ex.report["max_error_um"] + 0.02, worst


def test_export_refuses_a_broken_mr_poly_document():
    doc = mr_poly_doc(random.Random(1))
    doc["sensors"] = doc["sensors"][::-1]
    with pytest.raises(ExportError, match="sensors must be \\[thermal.nut_sensor, thermal.base_sensor\\]"):
        export_model(doc)
    doc = mr_poly_doc(random.Random(1))
    doc["thermal"]["nut_coefficients"] = [0.1] * 5
    with pytest.raises(ExportError, match="1..4 numbers"):
        export_model(doc)


@pytest.mark.parametrize("names", [[None, None], [1, 2]])
def test_mr_poly_whose_sensors_are_no_names_is_refused_naming_the_field(names):
    """sensors equal to [nut_sensor, base_sensor] but not strings: mr_poly_as_dynamic (which Model calls before it checks
    sensors) built "T:" + None and raised a TypeError; a direct call is the only way there (tcomp export's document
    check refuses first)."""
    doc = mr_poly_doc(random.Random(1))
    doc["sensors"] = list(names)
    doc["thermal"]["nut_sensor"], doc["thermal"]["base_sensor"] = names
    with pytest.raises(ExportError, match=r"mr_poly: thermal\.nut_sensor must be a sensor's name, found %r" % (names[0],)):
        mr_poly_as_dynamic(doc)
    with pytest.raises(ExportError, match=r"thermal\.nut_sensor"):
        export_model(doc)
    doc["sensors"][0] = doc["thermal"]["nut_sensor"] = "T_nut"
    with pytest.raises(ExportError, match=r"mr_poly: thermal\.base_sensor must be a sensor's name, found %r" % (names[1],)):
        mr_poly_as_dynamic(doc)


def test_micropython_bit_identical_and_allocation_free(tmp_path, mp, runner):
    cases = []
    for seed in range(3):
        tb = export_model(mr_poly_doc(random.Random(seed), "slope" if seed != 1 else "direct", degree=4)).table
        t = parse_table(tb)
        rng = random.Random(seed)
        ops = []
        for k in range(60):
            ops.append(["t", [rng.randint(t.env_lo[i] - 3000, t.env_hi[i] + 3000) for i in range(t.n_sensors)]])
            ops.append(["s"])
            if k == 3 and t.ref_mode == 1:
                ops.append(["l"])
            ops.append(["e", rng.randint(t.pos_lo - 1000, t.pos_hi + 1000)])
        cases.append((tb, ops))
    path = tmp_path / "cases.jsonl"
    path.write_text("".join(json.dumps({"table": tb.hex(), "ops": ops}) + "\n" for tb, ops in cases))
    out = mp.run(mp.runner, [path], heapsize="2M", timeout=600)
    got = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert len(got) == len(cases)
    for (tb, ops), board in zip(cases, got):
        cp, _ = runner.run_case(tb, ops, check=True)
        assert board == cp
        assert len({r[0] for r in cp}) > 30  # the vectors exercise many distinct offsets
