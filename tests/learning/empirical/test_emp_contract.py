"""The estimator contract, in the manner of scikit-learn's check_estimator, for every estimator in
ESTIMATORS and every model-document kind in host.learning.documents.KIND_CLASSES: keyword-only parameters, fit/predict,
prediction length and order, NaN refused, predict before fit refused, document round trip."""
import copy
import dataclasses
import inspect
import json
import warnings

import numpy as np
import pytest

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.methods import ESTIMATORS as METHOD_NAMES, estimator_class
from host.learning.documents import KIND_CLASSES, load_model
from models_export.document import DOCUMENT_KINDS
from host.learning.screw import synth
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel

ESTIMATORS = {m: estimator_class(m) for m in METHOD_NAMES}  # the registry, its classes imported


def _design(n=60, p=4, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, p))
    y = 1.5 + X @ np.array([2.0, -1.0, 0.5, 0.0][:p]) + 0.05 * rng.normal(size=n)
    return X, y, np.repeat(np.arange(3), n // 3)


# settings that keep each fit quick on 60 samples (the defaults are the papers' and search wider)
SETTINGS = {"stepwise": {"f_enter": 4.0, "f_remove": 2.0}, "ann": {"hidden_sizes": (2,), "max_epochs": 600, "learning_rate": 0.03},
            "dynamic": {"ridge": 0.0}}


def _fit(method, X, y, groups):
    est = ESTIMATORS[method](**SETTINGS.get(method, {}))
    if method == "mr-poly":  # S004's Eq. 12 reads two sensors (nut, base); the design's law is linear in the first three
        return est.fit(X[:, :2], y - 0.5 * X[:, 2], ["T0", "T1"])
    names = ["T%d" % j for j in range(X.shape[1])]
    if method == "dynamic":  # its columns are lag-filtered signals, here with time constant 0 (the inputs themselves)
        return est.fit(X, y, [("T:" + n, 0.0) for n in names], groups)
    return est.fit(X, y, names, groups=groups) if method in ("cv-subset", "ann") else est.fit(X, y, names)


def _columns(method, est, X):
    # the dynamic estimator predicts from the signals of the terms it selected; mr-poly reads nut and base
    return X[:, est.selected_] if method == "dynamic" else (X[:, :2] if method == "mr-poly" else X)


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
def test_estimator_parameters_are_keyword_only(method):
    params = list(inspect.signature(ESTIMATORS[method].__init__).parameters.values())[1:]
    assert params and all(p.kind is p.KEYWORD_ONLY for p in params), params
    with pytest.raises(TypeError):
        ESTIMATORS[method](True)


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
def test_estimator_fit_predict_length_order_and_learned_attributes(method):
    X, y, groups = _design()
    est = ESTIMATORS[method]()
    assert not [k for k in vars(est) if k.endswith("_")]  # nothing learned before fit
    assert _fit(method, X, y, groups) is not None
    est = _fit(method, X, y, groups)
    assert [k for k in vars(est) if k.endswith("_") and not k.startswith("_")]  # what it learned, sklearn-named
    X = _columns(method, est, X)
    pred = est.predict(X)
    assert pred.shape == (len(y),)
    target = y - 0.5 * _design()[0][:, 2] if method == "mr-poly" else y
    assert np.sqrt(np.mean((pred - target) ** 2)) < 0.2  # it learned the linear law, not a constant (y's spread is 2.3)
    perm = np.random.default_rng(1).permutation(len(y))
    np.testing.assert_allclose(est.predict(X[perm]), pred[perm], rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
def test_estimator_refuses_nan_in_fit_and_predict(method):
    X, y, groups = _design()
    Xn = X.copy()
    Xn[5, 1] = np.nan
    with pytest.raises(EmpiricalDataError, match="NaN"):
        _fit(method, Xn, y, groups)
    yn = y.copy()
    yn[3] = np.nan
    with pytest.raises(EmpiricalDataError, match="NaN"):
        _fit(method, X, yn, groups)
    est = _fit(method, X, y, groups)
    Xp = _columns(method, est, X).copy()
    Xp[5, 0] = np.nan
    with pytest.raises(EmpiricalDataError, match="NaN"):
        est.predict(Xp)


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
def test_estimator_predict_before_fit_is_a_clear_error(method):
    with pytest.raises(EmpiricalDataError, match="predict before fit"):
        ESTIMATORS[method](**SETTINGS.get(method, {})).predict(np.zeros((3, 4)))


# --- model documents: one fitted model per kind -------------------------------------------------
def _models():
    import importlib.util
    import os

    spec = importlib.util.spec_from_file_location("emp_conftest", os.path.join(os.path.dirname(__file__), "conftest.py"))
    conf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conf)
    slope, direct = conf.make_slope_run(), conf.make_direct_run()
    screw_run = synth.make_run()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        screw = ScrewModel(ambient=True, segments=10, dt_s=20.0).fit([screw_run])
    cycles = conf.make_direct_run(name="cycles", n_sensors=3, spindle=True)  # the dynamic model cross-validates across cycles
    return {
        "poly_slope": (fit_model([slope], method="mlr", target="slope"), slope),
        "linear_direct": (fit_model([direct], method="mlr", target="direct", channel="ch1"), direct),
        "ann": (fit_model([direct], method="ann", target="direct", channel="ch1", hidden_sizes=(2,), max_epochs=300), direct),
        "dynamic": (fit_model([cycles], method="dynamic", target="direct", channel="ch1", taus_s=(0, 1800)), cycles),
        "screw": (screw, screw_run),
        "mr_poly": (fit_model([slope], method="mr-poly", nut="T1", base="T2", degree=2), slope),
        "ppr": (fit_model([slope], method="ppr", target="slope", n_terms=1, knots=4), slope),
    }


MODELS = {}


def _model(kind):
    if not MODELS:
        MODELS.update(_models())
    return MODELS[kind]


def test_every_kind_is_covered():
    assert set(KIND_CLASSES) == set(DOCUMENT_KINDS) == {"poly_slope", "linear_direct", "ann", "dynamic", "screw", "mr_poly", "ppr"}


@pytest.mark.parametrize("kind", sorted(KIND_CLASSES))
def test_document_round_trip(kind):
    model, run = _model(kind)
    doc = json.loads(json.dumps(model.to_document()))  # through JSON, as a file would
    again = load_model(doc)
    assert type(again) is type(model) and doc["kind"] == kind
    assert json.loads(json.dumps(again.to_document())) == doc
    np.testing.assert_array_equal(again.predict(run), model.predict(run))


@pytest.mark.parametrize("kind", sorted(KIND_CLASSES))
def test_predict_gives_one_value_per_error_row_in_order(kind):
    model, run = _model(kind)
    pred = model.predict(run)
    assert pred.shape == (len(run.errors),)
    rows = np.arange(len(run.errors))[::-1]
    e = run.errors
    reversed_errors = dataclasses.replace(e, **{f.name: getattr(e, f.name)[rows] for f in dataclasses.fields(e)
                                                if getattr(e, f.name) is not None})
    reversed_run = dataclasses.replace(run, errors=reversed_errors)
    np.testing.assert_allclose(model.predict(reversed_run), pred[rows], rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", sorted(KIND_CLASSES))
def test_predict_refuses_nan_temperatures(kind):
    model, run = _model(kind)
    bad = copy.deepcopy(run)
    used = model.sensors[0] if kind != "screw" else model.base_sensor_
    temps = bad.temperatures
    k = int(np.argmin(np.abs(temps.time_s - run.errors.time_s[len(run.errors) // 2])))  # a sample the model reads
    temps.values[k, temps.names.index(used)] = np.nan
    with pytest.raises((EmpiricalDataError, ValueError), match="NaN"):
        model.predict(bad)


def test_screw_predict_before_fit_is_a_clear_error():
    # the empirical kinds have no unfitted state: they are built from their coefficients
    with pytest.raises(ValueError, match="predict before fit"):
        ScrewModel(ambient=True).predict(_model("screw")[1])
