"""Sensors only the observer reads (option ``observer_sensors``, host/learning/empirical/observer.py; issue 21).

The synthetic machine below is written here, independently of the model's filters (exactlag.py): the spindle heats a
fast sensor t1 (a 10 min path) and, through a slow path (4 h), both the structure whose elongation is the error and a
sensor t2 mounted on it; t3 reads the ambient. The error is 4 × lag(t1, 4 h): a model whose only term is that lag
is exact, but at switch-on its own sensor t1 (fast) says nothing about the 4 h state, while t2's present reading
does (lag(lag(q, 10 min), 4 h) ≈ lag(q, 4 h) = the slow path's). Spindle cycles of unequal length, so that no fixed
phase ties the fast reading to the slow state.
"""
import numpy as np
import pytest

from host.data.runs import Errors, Run, Spindle, Temperatures, slice_run
from host.learning.documents import ModelFormatError
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.dynamic import DynamicModel
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.observer import choose_observer_sensors, fit_observer

from exactlag import exact_lag  # test-side physics, beside these tests

REF_C = 22.0
DT = 60.0
TAU_SLOW = 14400.0


def _machine(hours=30.0):
    t = np.arange(0.0, hours * 3600.0, DT)
    rpm = np.zeros(t.size)
    start = 600.0
    for on_h, off_h, speed in ((3.0, 1.0, 3000), (1.0, 4.0, 4000), (5.0, 2.0, 2000), (2.0, 3.0, 3500), (4.0, 2.0, 1500)):
        rpm[(t >= start) & (t < start + on_h * 3600)] = speed
        start += (on_h + off_h) * 3600
    krpm = rpm / 1000.0
    t1 = REF_C + 1.5 * exact_lag(krpm, 600.0, DT)  # fast: near the spindle
    t2 = REF_C + 1.5 * exact_lag(krpm, TAU_SLOW, DT)  # slow path: on the structure
    t3 = REF_C + 0.4 * np.sin(t / 20000.0)  # ambient
    err = 4.0 * exact_lag(t1 - REF_C, TAU_SLOW, DT)
    temps = Temperatures(t, ["t1", "t2", "t3"], np.column_stack([t1, t2, t3]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {s: {"role": "structure"} for s in ("t1", "t2", "t3")}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), rpm), name="machine")


def _slow_lag_model():
    """The exact structure, 4 × lag(t1, 4 h), with the observer of its own signal only."""
    run = _machine()
    model = DynamicModel([("T:t1", TAU_SLOW)], [4.0], 0.0, "direct", "ch1", reference_C={"t1": REF_C}, dt_s=DT,
                         training={"error_reference": "start"})
    model.observer = fit_observer(model, [run])
    return run, model


def test_the_observer_picks_the_sensor_that_reveals_the_hidden_lag_state_and_settles_sooner():
    run, model = _slow_lag_model()
    own = model.observer
    record = choose_observer_sensors(model, [run], ["t1", "t2", "t3"], {"t1": REF_C, "t2": REF_C, "t3": REF_C}, 5, 5)
    assert record["chosen"][0] == "t2" and "t1" not in record["chosen"]
    assert model.observer_sensors == record["chosen"] and model.sensors == ["t1"] + record["chosen"]
    # its largest training residual (the start error's bound) and the settle time drop by far
    assert model.observer.states[0]["bound"] < 0.1 * own.states[0]["bound"]
    assert model.observer.settle_s < 0.5 * own.settle_s and record["settle_s_without"] == own.settle_s
    # and a board switched on warm (4.5 h: 1.5 h into the 2nd cycle's cool-down) starts nearer the uninterrupted one
    k = int(4.5 * 3600 / DT)
    uninterrupted = model.predict(run)[k]
    with_t2 = model.predict(slice_run(run, 4.5 * 3600.0))[0]
    model_own = DynamicModel(model.terms, model.term_coefficients, 0.0, "direct", "ch1", reference_C={"t1": REF_C}, dt_s=DT,
                             training={"error_reference": "start"})
    model_own.observer = own
    without = model_own.predict(slice_run(run, 4.5 * 3600.0))[0]
    assert abs(with_t2 - uninterrupted) < 0.2 * abs(without - uninterrupted)


def test_the_budget_of_sensors_holds():
    run, model = _slow_lag_model()
    # a model of 1 sensor under max_sensors 2: one observer-only sensor at most, whatever observer_sensors allows
    record = choose_observer_sensors(model, [run], ["t1", "t2", "t3"], {"t1": REF_C, "t2": REF_C, "t3": REF_C}, 5, 2)
    assert record["chosen"] == ["t2"] and len(model.sensors) == 2
    # and through fit_model: the model's sensors (terms' and observer's) within max_sensors
    fitted = fit_model([run], "dynamic", target="direct", channel="ch1", window=(None, 20 * 3600.0),
                       taus_s=(0, 3600, TAU_SLOW), max_sensors=2, max_terms=3, observer_sensors=5)
    assert len(fitted.sensors) <= 2
    assert fitted.statistics["observer_sensors"]["chosen"] == fitted.observer_sensors
    assert set(fitted.observer_sensors).isdisjoint(fitted.term_sensors)


@pytest.mark.parametrize("value", [-1, 1.5, True, "2", None])
def test_bad_observer_sensors_values_are_refused_by_name(value):
    run = _machine(8.0)
    with pytest.raises(EmpiricalDataError, match="observer_sensors must be a whole number >= 0"):
        fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 3600), observer_sensors=value)


def test_observer_sensors_without_an_observer_is_refused():
    run = _machine(8.0)
    with pytest.raises(EmpiricalDataError, match="observer_sensors .* needs observer=true"):
        fit_model([run], "dynamic", target="direct", channel="ch1", taus_s=(0, 3600), observer=False, observer_sensors=2)


def test_the_document_lists_observer_only_sensors_and_round_trips():
    run, model = _slow_lag_model()
    choose_observer_sensors(model, [run], ["t1", "t2", "t3"], {"t1": REF_C, "t2": REF_C, "t3": REF_C}, 1, 5)
    doc = model.to_document()
    # the document's sensors: the terms', then those only the observer reads (no term's signal names them)
    assert doc["sensors"] == ["t1", "t2"] and "t2" in doc["reference_C"]
    assert "T:t2" in doc["thermal"]["observer"]["states"][0]["gains"]
    back = DynamicModel.from_document(doc)
    assert back.observer_sensors == ["t2"] and back.term_sensors == ["t1"]
    warm = slice_run(run, 6.0 * 3600.0)
    np.testing.assert_allclose(back.predict(warm), model.predict(warm), rtol=0, atol=1e-12)
    # a gain on a sensor the document's sensors do not list is refused by name
    with pytest.raises(ModelFormatError, match=r"gains must map the model.s signals \(T:t1\) to finite numbers, found .*T:t2"):
        DynamicModel.from_document({**doc, "sensors": ["t1"]})
    # an observer-only sensor needs its reference temperature
    with pytest.raises(ModelFormatError, match="reference_C of sensor t2"):
        DynamicModel.from_document({**doc, "reference_C": {"t1": REF_C}})


def test_tcomp_fit_takes_the_option_and_prints_the_choice(tmp_path, capsys):
    import json

    from host.cli import main
    from host.data.runs import write_run

    path = str(tmp_path / "machine")
    write_run(_machine(), path)
    out = str(tmp_path / "m.json")
    assert main(["fit", path, "--model", "dynamic", "--direct", "--channel", "ch1", "--option", "taus_s=0/3600/14400",
                 "--option", "forward_blocks=4", "--option", "observer_sensors=2", "--out", out]) == 0
    assert "observer-only sensors (up to 2, the model's sensors within 5)" in capsys.readouterr().out
    with open(out) as fh:
        doc = json.load(fh)
    rec = doc["statistics"]["observer_sensors"]
    assert rec["allowed"] == 2 and doc["sensors"][len(doc["sensors"]) - len(rec["chosen"]):] == rec["chosen"]
    assert main(["fit", path, "--model", "dynamic", "--direct", "--channel", "ch1", "--option", "observer_sensors=-1",
                 "--out", str(tmp_path / "bad.json")]) != 0
    assert "observer_sensors" in capsys.readouterr().err
