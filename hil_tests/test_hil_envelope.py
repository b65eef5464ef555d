"""Scenario: the machine runs hotter than during its thermal test (docs/firmware.md, "Operating envelope").

An MLR poly_slope model is fitted on the 8000 mm/min demo run and exported with the default
certified envelope (training range +- 15 K). The firmware on the rig then plays a window of the
15000 mm/min run, where the nut sensor is up to 7 K above the training range (+- 2 K). Inside the
certified envelope the firmware must evaluate the model (status EXTRAPOLATING, never CLAMPED), so
its offsets equal the host model's within the certificate plus the RTD chain. The same window
through the table exported with the training range as its envelope (what the firmware did
before issue 13) clamps and leaves the bound: the comparison can fail.
"""
import os

import numpy as np
import pytest

from hil_tests.conftest import ROOT
from hil_tests.rig.boards import rig_config
from hil_tests.rig.play import play, poly_slope_bound_um
from host.board.link import RATE_LIMITED
from firmware.wire import CLAMPED, EXTRAPOLATING

pytestmark = pytest.mark.rig

SENSORS = ["T1", "T4", "T5"]  # nut, and two structure sensors that also leave the training range at 15000 mm/min
WINDOW_H = (1.0, 2.0)  # hours of the hot run played (the nut is above the training range from 0.64 h on)


def _window(run, h0, h1):
    """The part of ``run`` between ``h0`` and ``h1`` hours, times shifted to start at 0."""
    from host.data.runs import Errors, Run, Temperatures
    t = run.temperatures
    keep = (t.time_s >= h0 * 3600) & (t.time_s <= h1 * 3600)
    e = run.errors
    ke = (e.time_s >= h0 * 3600) & (e.time_s <= h1 * 3600)
    return Run(run.meta, Temperatures(t.time_s[keep] - h0 * 3600, t.names, t.values[keep]),
               Errors(e.time_s[ke] - h0 * 3600, e.position_mm[ke], e.error_um[ke]), None, None)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The model fitted on the cooler run (training envelope = training range +- 2 K, the fit's default)."""
    import json
    from host.cli import main as tcomp
    out = str(tmp_path_factory.mktemp("fit") / "mlr.json")
    assert tcomp(["fit", "--model", "mlr", os.path.join(ROOT, "data", "demo", "v8000_r210_490"),
                  "--sensors", ",".join(SENSORS), "--out", out]) == 0
    with open(out) as fh:
        return json.load(fh)


def _bound(ex, doc, run, pos_mm):
    return ex.report["max_error_um"] + poly_slope_bound_um(doc, run, SENSORS, pos_mm) + 0.05 + 1e-9


def test_hotter_run_inside_the_certified_envelope_matches_the_host_model(make_rig, fitted):
    from host.learning.documents import load_model
    from host.data.runs import load_run
    from models_export.export import export_model
    hot = load_run(os.path.join(ROOT, "data", "demo", "v15000_r210_490"))
    run = _window(hot, *WINDOW_H)
    train = fitted["envelope"]["temperature_C"]
    over = max(float(run.temperatures.column(s).max()) - train[s][1] for s in SENSORS)
    assert over > 3.0, "the window must leave the training range (max %.2f K above it)" % over
    ex = export_model(fitted)  # default envelope: training range +- 15 K
    pred = np.asarray(load_model(fitted).predict(run))
    temps = {s: float(run.temperatures.column(s)[0]) for s in SENSORS}
    rig = make_rig(rig_config(SENSORS), ex.table, temps=temps, noise_uohm=0)
    answers = play(rig, run, SENSORS, motion=False)
    worst = 0.0
    compared = extrapolating = 0
    for a, p in zip(answers, pred):
        st = int(a["status"], 16)
        assert not st & CLAMPED, "t=%.0f s: CLAMPED inside the certified envelope (status %s)" % (a["time_s"], a["status"])
        extrapolating += bool(st & EXTRAPOLATING)
        if st & RATE_LIMITED:
            continue
        compared += 1
        bound = _bound(ex, fitted, run, a["position_mm"])
        err = abs(a["offset_um"] - p)
        worst = max(worst, err)
        assert err <= bound, "t=%.0f s P=%.1f mm: firmware %.2f um, host %.4f um, bound %.4f um (status %s)" % (
            a["time_s"], a["position_mm"], a["offset_um"], p, bound, a["status"])
        assert not a["held"] and not a["fallback"]
    assert compared >= 0.85 * len(answers) and len(answers) >= 20
    assert extrapolating >= 0.5 * len(answers), "%d of %d answers EXTRAPOLATING" % (extrapolating, len(answers))
    print("hot window: %d answers, %d EXTRAPOLATING, 0 CLAMPED, max |firmware - host| %.3f um"
          % (len(answers), extrapolating, worst))


def test_the_training_range_as_envelope_would_clamp_and_miss(fitted):
    """The negative control, on the firmware's evaluator in CPython: with the envelope set to the
    training range the same window clamps and the offsets leave the bound the rig test holds."""
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    from host.learning.documents import load_model
    from host.data.runs import load_run
    from models_export.export import export_model
    run = _window(load_run(os.path.join(ROOT, "data", "demo", "v15000_r210_490")), *WINDOW_H)
    pred = np.asarray(load_model(fitted).predict(run))
    out = {}
    for margin in (0.0, 15.0):
        ex = export_model(fitted, margin_K=margin)
        ev = Evaluator(parse_table(ex.table))
        t = run.temperatures
        worst = 0.0
        clamped = 0
        for k in range(len(run.errors)):
            ts = float(run.errors.time_s[k])
            for j, s in enumerate(SENSORS):
                ev.temps[j] = int(round(float(np.interp(ts, t.time_s, t.column(s))) * 1000))
            ev.update()
            pos = int(round(float(run.errors.position_mm[k]) * 1000))
            v = ev.offset_at(pos) / 100.0
            clamped += bool(ev.flags)
            worst = max(worst, abs(v - pred[k]) - _bound(ex, fitted, run, pos / 1000.0))
        out[margin] = (worst, clamped)
    print("margin K: (worst excess over the bound um, answers clamped) %r" % out)
    assert out[15.0][0] <= 0 and out[15.0][1] == 0
    assert out[0.0][0] > 1.0 and out[0.0][1] > 0.5 * len(run.errors), out
