"""The dynamic model's observer (host/learning/empirical/observer.py) and predict(run, history) (issue 21).

The synthetic machine below is written here, independently of the model's filters: a structure sensor
warmed by the spindle through a first-order lag, an ambient sensor, and an error that lags the structure
and the spindle. Its exact solution for a spindle speed held between samples is y ← u + (y − u)·e^(−Δt/τ).
"""
import json

import numpy as np
import pytest

from host.cli import main
from host.data.runs import Errors, Run, Spindle, Temperatures, slice_run, write_run
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.observer import settle_time, start_error_bound

from exactlag import exact_lag  # test-side physics, beside these tests
from dynopts import OBSERVER_ONLY

REF_C = 22.0
DT = 60.0


def _exact_lag(u, tau, y0=0.0):
    return exact_lag(u, tau, DT, y0)


def _machine(hours=20.0):
    """Cycles of 2 h running (1000..4000 rpm) and 2 h stopped from a machine at rest at 22 °C (spindle stopped for
    the first 10 min: at rest means temperatures at the reference and no heat source on)."""
    t = np.arange(0.0, hours * 3600.0, DT)
    rpm = np.zeros(t.size)
    for k, speed in enumerate((1000, 3000, 2000, 4000, 2500)):
        rpm[(t >= 14400 * k + 600) & (t < 14400 * k + 7800)] = speed
    krpm = rpm / 1000.0
    t1 = REF_C + 1.5 * _exact_lag(krpm, 7200.0)  # structure near the spindle
    t2 = REF_C + 0.3 * np.sin(t / 9000.0)  # ambient
    err = 3.0 * _exact_lag(t1 - REF_C, 3600.0) + 2.0 * _exact_lag(krpm, 1800.0)
    temps = Temperatures(t, ["t1", "t2"], np.column_stack([t1, t2]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {"t1": {"role": "structure"}, "t2": {"role": "ambient"}}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), rpm), name="machine")


@pytest.fixture(scope="module")
def machine_and_model():
    run = _machine()
    # the structure chosen by leave-one-cycle-out, as when these checks were written: they test the observer's
    # estimate for a given structure (forward-chaining selection picks another here, on which the warm start at 2.5 h
    # is 4.4 um off against 3.0 um from rest: recorded in docs/empirical.md); the observer estimates every state (no
    # controller's record, no settle bound: defaults since stop 35 that would change the structure under test)
    model = fit_model([run], "dynamic", target="direct", channel="ch1", window=(None, 16 * 3600.0),
                      taus_s=(0, 1800, 3600, 7200), max_terms=4, selection="loo", **OBSERVER_ONLY)
    return run, model


def test_a_cold_start_at_the_reference_is_the_start_from_rest(machine_and_model):
    run, model = machine_and_model
    # the machine is at rest at 22 °C at t = 0: the observer must leave every state at zero there
    states = model.observer.initial_states({"T:t1": 0.0, "T:t2": 0.0, "spindle_krpm": 0.0, "spindle_krpm2": 0.0})
    assert states and all(v == 0.0 for v in states.values())
    plain = fit_model([run], "dynamic", target="direct", channel="ch1", window=(None, 16 * 3600.0),
                      taus_s=(0, 1800, 3600, 7200), max_terms=4, selection="loo", observer=False)
    assert plain.observer is None and plain.terms == model.terms
    np.testing.assert_allclose(model.predict(run), plain.predict(run), atol=1e-9)


def test_a_board_switched_on_warm_starts_near_the_uninterrupted_state(machine_and_model):
    run, model = machine_and_model
    truth = run.errors.error_um
    for hours in (2.5, 6.0, 10.5, 13.0):  # running, stopped, running, stopped: all inside the training span
        k = int(hours * 3600 / DT)
        warm = slice_run(run, hours * 3600.0)
        uninterrupted = model.predict(run)[k:]
        observed = model.predict(warm)
        # the observer's start error is within the bound it records (its largest training residual per state)
        bound = start_error_bound(model, model.observer.states, 0.0)
        assert abs(observed[0] - uninterrupted[0]) <= bound + 1e-9
        # and far below what filters started from rest give: the model without observer restarts at its intercept
        nobs = type(model).from_document({**model.to_document(), "thermal": {**{k_: v for k_, v in model.to_document()["thermal"].items()
                                                                                   if k_ != "observer"}, "reference": "run_start"}})
        rest = nobs.predict(warm)
        assert abs(observed[0] - uninterrupted[0]) < 0.25 * abs(rest[0] - uninterrupted[0]), hours
        # the model itself is right on this machine: the uninterrupted prediction follows the exact solution
        assert np.abs(uninterrupted - truth[k:]).max() < 0.3


def test_history_carries_the_states_as_an_uninterrupted_board(machine_and_model, tmp_path):
    run, model = machine_and_model
    split = 13 * 3600.0
    before, after = slice_run(run, 0.0, split), slice_run(run, split)
    k = int(split / DT)
    np.testing.assert_allclose(model.predict(after, history=before), model.predict(run)[k:], atol=1e-9)
    # a history that does not end before the run starts is refused, naming both
    with pytest.raises(EmpiricalDataError, match=r"ends at 46740 s, after .* starts at 43200 s"):
        model.predict(slice_run(run, 12 * 3600.0), history=before)
    # the command line: --history gives the uninterrupted board's predictions; a late history exits 2
    doc = str(tmp_path / "dyn.json")
    with open(doc, "w") as fh:
        json.dump(model.to_document(), fh)
    a, b = write_run(before, str(tmp_path / "before")), write_run(after, str(tmp_path / "after"))
    out = str(tmp_path / "p.csv")
    assert main(["predict", doc, b, "--history", a, "--out", out]) == 0
    pred = np.genfromtxt(out, delimiter=",", names=True, dtype=None, encoding="utf-8")["predicted_um"]
    np.testing.assert_allclose(pred, model.predict(run)[k:], atol=1e-3)
    assert main(["predict", doc, a, "--history", b, "--out", str(tmp_path / "q.csv")]) == 2


def test_the_observer_is_fitted_on_the_training_span_only():
    run = _machine()
    kw = dict(target="direct", channel="ch1", window=(None, 16 * 3600.0), taus_s=(0, 1800, 3600, 7200), max_terms=4)
    a = fit_model([run], "dynamic", **kw)
    late = run.temperatures.time_s > 16 * 3600.0
    run.temperatures.values[late, 0] += 5.0  # what is held out changes; the observer must not
    b = fit_model([run], "dynamic", **kw)
    assert a.observer.to_document() == b.observer.to_document()


def test_settle_time_is_where_the_start_error_bound_meets_the_tolerance(machine_and_model):
    _, model = machine_and_model
    states = model.observer.states
    s = settle_time(model, states, tolerance=0.01)
    # the bound written out from its definition: sum of |b_j| E_j exp(-t / tau_j)
    def bound(t):
        return sum(abs(model.term_coefficients[st["term"]]) * st["bound"] * np.exp(-t / model.terms[st["term"]][1]) for st in states)
    assert bound(s) <= 0.01 < bound(s - 1.0)
    assert model.observer.settle_s == settle_time(model, states, tolerance=1.0)
    assert settle_time(model, states, tolerance=bound(0.0)) == 0.0


def test_history_is_refused_where_no_state_can_be_carried(machine_and_model, tmp_path):
    run, model = machine_and_model
    split = 13 * 3600.0
    a, b = write_run(slice_run(run, 0.0, split), str(tmp_path / "a")), write_run(slice_run(run, split), str(tmp_path / "b"))
    mlr = str(tmp_path / "mlr.json")
    assert main(["fit", "--model", "mlr", "--direct", "--channel", "ch1", a, "--out", mlr]) == 0
    assert main(["predict", mlr, b, "--history", a, "--out", str(tmp_path / "p.csv")]) == 2
    # a dynamic model without an observer reads rises over each run's own start: no state to carry either
    doc = model.to_document()
    doc["thermal"] = {k: v for k, v in doc["thermal"].items() if k != "observer"}
    doc["thermal"]["reference"] = "run_start"
    plain = type(model).from_document(doc)
    with pytest.raises(EmpiricalDataError, match="no observer"):
        plain.predict(slice_run(run, split), history=slice_run(run, 0.0, split))
