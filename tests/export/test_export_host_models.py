"""Models fitted by the host code (tcomp fit on a demo run) exported and checked against the host's own evaluation."""
import json
import random
from pathlib import Path

import numpy as np
import pytest

from firmware.evaluate import ACC_AMUL, Evaluator
from firmware.table import parse_table
from host.cli import main
from host.learning.documents import load_model, read_document
from models_export.document import document_hash
from host.data.runs import load_run
from models_export import export_model
from hil_tests.fixtures.reference import Reference

RUN = Path(__file__).resolve().parents[2] / "data" / "demo" / "v8000_r0_700"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    if not RUN.exists():
        pytest.skip("demo run data/demo/v8000_r0_700 not present")
    d = tmp_path_factory.mktemp("fit")
    out = {}
    for method in ("mlr", "screw"):
        path = d / (method + ".json")
        # the screw with E_e (the demo run holds the frame drift it stands for): the table's base-sensor slope is checked too
        extra = ["--option", "ambient=on"] if method == "screw" else []
        assert main(["fit", "--model", method, str(RUN), "--out", str(path)] + extra) == 0
        out[method] = read_document(str(path))
    return out


@pytest.mark.parametrize("reference", ["as fitted", "run_start"])
def test_poly_slope_from_tcomp_fit_matches_host_model(fitted, reference):
    doc = json.loads(json.dumps(fitted["mlr"]))
    assert doc["kind"] == "poly_slope"
    if reference == "run_start":
        doc["thermal"]["reference"] = "run_start"
        doc["provenance"]["sha256"] = document_hash(doc)  # as re-saving the edited model would
    ex = export_model(doc)
    t = parse_table(ex.table)
    model = load_model(doc)
    ev = Evaluator(t, check=True)
    rng = random.Random(1)
    cert = ex.report["max_error_um"]
    for _ in range(300):
        temps = [rng.randint(lo, hi) for lo, hi in zip(t.env_lo, t.env_hi)]
        if t.ref_mode == 1 and rng.random() < 0.1:
            ev.temps[:] = [rng.randint(lo, hi) for lo, hi in zip(t.env_lo, t.env_hi)]
            ev.latch_references()
        for i, v in enumerate(temps):
            ev.temps[i] = v
        ev.update()
        p = rng.randint(t.pos_lo, t.pos_hi)
        # latched references are whole milli-degC in the firmware; fixed ones are the document's reference_C
        refs = np.array(ev.ref) / 1000.0 if t.ref_mode == 1 else np.array([doc["reference_C"][s] for s in t.sensors])
        R = np.array(temps) / 1000.0 - refs
        host = float(model.geometric(p / 1000.0) + model.slope(R[None, :])[0] * p / 1000.0)
        assert abs(ev.offset_at(p) * 0.01 - host) <= cert + 1e-9
    for acc_id, (lo, hi) in ex.accs.items():
        if ev.lo[acc_id] <= ev.hi[acc_id]:
            assert lo <= ev.lo[acc_id] and ev.hi[acc_id] <= hi


def test_screw_from_tcomp_fit_matches_host_reduced_model(fitted):
    from host.learning.screw import heat
    from host.learning.screw.reduced import reduced_error_um

    doc = fitted["screw"]
    red = doc["thermal"]["reduced"]
    ex = export_model(doc)
    t = parse_table(ex.table)
    ev = Evaluator(t, check=True)
    ref = Reference(doc, t)
    run = load_run(str(RUN))
    dt = red["dt_s"]
    n = 400
    times = run.motion.t_start_s[0] + dt * np.arange(n + 1) if run.motion is not None else dt * np.arange(n + 1)
    u_mm = heat.nut_travel_per_segment(run.motion, np.asarray(red["edges_mm"]), red["fixed_end_mm"], times)
    A, B = np.asarray(red["A"]), np.asarray(red["B_K_per_mm"])
    c0, c1 = np.asarray(red["air_K0"]), np.asarray(red["air_K1"])
    assert red["air_sensor"] in t.sensors and t.air == t.sensors.index(red["air_sensor"])
    cert = ex.report["max_error_um"]
    base = red.get("base_sensor")
    ref.settle(list(ev.temps))
    ai = t.air
    air = lambda temps: (temps[ai] - ev.ref[ai]) / 1000.0  # noqa: E731  (in-envelope draws: no clamping)
    a_prev = air(ev.temps)
    x = np.full(len(B), a_prev)
    x_air = x.copy()  # the same recurrence without the nut's heat: what the air alone does to the state
    assert np.allclose(ref.T, x)
    rng = random.Random(2)
    lo_air, hi_air = t.env_lo[ai], t.env_hi[ai]
    a_mC = rng.randint(lo_air, hi_air)
    for k in range(n):
        u_um = [int(round(v * 1000.0)) for v in u_mm[k]]
        temps = [rng.randint(lo, hi) for lo, hi in zip(t.env_lo, t.env_hi)]
        # the air as a random walk with occasional jumps to its envelope's ends (the certificate covers any history)
        a_mC = min(max(a_mC + rng.randint(-300, 300), lo_air), hi_air) if k % 50 else rng.choice([lo_air, hi_air])
        temps[ai] = a_mC
        for i, v in enumerate(temps):
            ev.temps[i] = v
        ev.update()
        # the host recurrence on the same (whole-um) travel the firmware accumulates from position reports
        # and the air it read at the step's start and end
        x = A @ x + B * (np.array(u_um) / 1000.0) + c0 * a_prev + c1 * air(temps)
        x_air = A @ x_air + c0 * a_prev + c1 * air(temps)
        a_prev = air(temps)
        for i, v in enumerate(u_um):
            ev.u[i] = v
        ev.step()
        ref.step(u_um, temps)
        assert np.allclose(ref.T, x, rtol=1e-12, atol=1e-12)
        P = rng.randint(t.pos_lo, t.pos_hi)
        # A run_start (latched) table holds its reference in whole milli-degC, as the firmware latches it.
        base_ref = round(red["base_ref_C"] * 1000.0) / 1000.0 if t.ref_mode == 1 else red["base_ref_C"]
        rise = (temps[t.sensors.index(base)] / 1000.0 - base_ref) if base else None
        host = float(load_model(doc).geometric_um(np.array([P / 1000.0]))[0]
                     + reduced_error_um(red, x, P / 1000.0, base_rise_K=rise))
        assert abs(ref.offset(temps, P) - host) < 1e-9
        assert abs(ev.offset_at(P) * 0.01 - host) <= cert + 1e-9
    # the run heated the screw: the state against the same air history without the heat (comparing with the
    # last air draw alone fails whenever the random walk has just jumped to the envelope's top)
    assert max(x - x_air) > 0.1
    assert ev.hi[ACC_AMUL] > ev.lo[ACC_AMUL]  # the air terms ran
    for acc_id, (lo, hi) in ex.accs.items():  # every observed intermediate inside its certified interval
        if ev.lo[acc_id] <= ev.hi[acc_id]:
            assert lo <= ev.lo[acc_id] and ev.hi[acc_id] <= hi, acc_id
    assert json.dumps(ex.report)  # the report is plain JSON
