"""A dynamic table whose observer reads a sensor no term reads (the option observer_sensors, issue 21).

The export makes such a sensor a filter of tau 0 and coefficient 0 after the terms (models_export/exact.py
``_observer_only_filters``): the board reads it, the observer's gain has an input, the offset does not depend on it.
The board's start must equal the host's (host/learning/empirical/observer.py, via the document as the host loads it)
within the certified start error.
"""
import random

import pytest

from firmware.evaluate import Evaluator
from firmware.table import parse_table
from hil_tests.fixtures.samples import (dynamic_doc, observed_board, observer_host_inputs, observer_input_unit, random_board_inputs,
                                        restamp, with_observer)
from host.learning.empirical.dynamic import DynamicModel
from models_export import export_model
from models_export.certify import ExportError


def _doc(seed, target="direct", signals=("T:T0", "spindle_krpm", "T:T1")):
    """A dynamic document on sensors T0, T1, T2 whose terms read T0 and T1 only, its observer also T2."""
    rng = random.Random(seed)
    doc = dynamic_doc(rng, target, n_sensors=3, signals=list(signals), dt_s=15.0)
    for k, t in enumerate(doc["thermal"]["terms"]):
        t["tau_s"] = (3600.0, 7200.0, 14400.0, 0.0)[k % 4]
    doc = with_observer(doc, random.Random(100 + seed))
    for st in doc["thermal"]["observer"]["states"]:
        st["gains"]["T:T2"] = rng.uniform(0.3, 0.9)  # the slow sensor's present reading carries the lag state
    return restamp(doc)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_board_starts_from_the_observer_only_sensor_like_the_host(seed):
    doc = _doc(seed, "direct" if seed % 2 else "slope")
    ex = export_model(doc)
    t = parse_table(ex.table)
    assert t.sensors == ["T0", "T1", "T2"] and t.obs == 1
    n_terms = len(doc["thermal"]["terms"])
    assert t.nf == n_terms + 1  # T2's filter after the terms
    host = DynamicModel.from_document(doc)
    assert host.observer_sensors == ["T2"]
    terms = host.terms
    cert = {s["filter"]: s["start_error_signal_units"] for s in ex.report["dynamic"]["observer"]["states"]}
    rng = random.Random(seed)
    moved = 0
    for _ in range(25):
        temps, rpm, feed = random_board_inputs(rng, t)
        ev = observed_board(t, temps, rpm, feed)
        u = observer_host_inputs(doc, t, temps, rpm, feed)
        want = host.observer.initial_states(u)
        # T2's share of the estimate: the start without it would differ by this much
        without_t2 = host.observer.initial_states(dict(u, **{"T:T2": 0.0}))
        for j, y in want.items():
            per = observer_input_unit(terms[j][0], t) / 2.0 ** t.fy[j]
            y = min(max(y, t.Ylo[j] * per), t.Yhi[j] * per)
            assert abs(ev.Y[j] * per - y) <= cert[j] * (1 + 1e-9) + 1e-12, (seed, j, ev.Y[j] * per, y, cert[j])
            moved += abs(want[j] - without_t2[j]) > 10 * cert[j]
        # the offset does not depend on T2 after the start (its filter's coefficient is 0)
        p = t.pos_hi
        before = ev.offset_at(p)
        ev.temps[2] = t.train_lo[2] if temps[2] != t.train_lo[2] else t.train_hi[2]
        ev.update()
        assert ev.offset_at(p) == before
    assert moved > 10  # the comparison sees T2's gain


def test_the_table_holds_eight_filters_with_the_observer_only_sensors():
    doc = _doc(5, signals=("T:T0", "T:T1", "T:T0", "T:T1", "spindle_krpm", "T:T0", "T:T1", "spindle_krpm"))
    assert len(doc["thermal"]["terms"]) == 8
    with pytest.raises(ExportError, match=r"thermal.terms \(8\) and the sensors only the observer reads \(T2\) need 9 filters"):
        export_model(doc)


def test_a_gain_on_a_sensor_the_document_does_not_list_is_still_refused():
    doc = _doc(6)
    doc["thermal"]["observer"]["states"][0]["gains"]["T:T9"] = 0.5
    with pytest.raises(ExportError, match="signal 'T:T9' is not read by any term"):
        export_model(restamp(doc))


def test_a_host_document_with_an_observer_only_sensor_starts_on_the_board_like_the_host():
    """The host's own document (tests/learning/empirical/test_emp_observer_sensors.py's machine: 4 x lag(t1, 4 h), its
    observer also reading the slow-path sensor t2) exported; a board started at every 60th sample (hourly) estimates the host's
    state within the certified start error."""
    import os
    import sys

    import numpy as np

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "learning", "empirical"))
    from test_emp_observer_sensors import REF_C, _slow_lag_model

    from host.learning.empirical.observer import choose_observer_sensors

    run, model = _slow_lag_model()
    choose_observer_sensors(model, [run], ["t1", "t2", "t3"], {s: REF_C for s in ("t1", "t2", "t3")}, 2, 5)
    assert model.observer_sensors == ["t2"]
    T = {s: run.temperatures.column(s) for s in ("t1", "t2")}
    model.envelope = {"temperature_C": {s: [float(v.min()) - 2, float(v.max()) + 2] for s, v in T.items()},
                      "position_mm": [0.0, 0.0]}
    doc = model.to_document()
    ex = export_model(doc)
    t = parse_table(ex.table)
    assert t.sensors == ["t1", "t2"] and t.nf == 2
    cert = {s["filter"]: s["start_error_signal_units"] for s in ex.report["dynamic"]["observer"]["states"]}
    for k in range(0, run.temperatures.time_s.size, 60):
        temps = [int(round(T[s][k] * 1000)) for s in t.sensors]
        ev = Evaluator(t, check=True)
        ev.temps[:] = temps
        ev.update()
        ev.observe()
        want = model.observer.initial_states({"T:" + s: v / 1000.0 - REF_C for s, v in zip(t.sensors, temps)})
        got = ev.Y[0] * 1e-3 / 2.0 ** t.fy[0]
        assert abs(got - want[0]) <= cert[0] * (1 + 1e-9) + 1e-12, (k, got, want[0], cert[0])
    assert np.isfinite(cert[0]) and cert[0] < 0.01  # K: the certificate is tight against the state's range
