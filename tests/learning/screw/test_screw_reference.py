"""The screw model under both error references (issue 19 §1, §4), on data made by the independent twin."""
import warnings

import numpy as np
import pytest

from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel
from host.twin import simulate_run

NOISE_UM = 0.5
FIT, UNSEEN = "v8000_r210_490", ("v6500_r210_490", "v15000_r210_490", "v8000_r0_700")


def _fit(runs, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return ScrewModel(**kw).fit(runs)


@pytest.mark.parametrize("reference", ["start", "T3"])
def test_default_structure_predicts_unseen_states_at_the_noise(reference):
    """Fitted on one moving state of effect-free twin runs, declared as made: every other state within 1.5 x the
    laser noise (the issue measured 5.1 x with errors corrected to T3 and E_m following the air)."""
    model = _fit([simulate_run(FIT, seed=2, noise_um=NOISE_UM, error_reference=reference)])
    assert model.error_reference_ == reference and model.base_sensor_ is None  # E_e off by default under both
    for name in UNSEEN:
        run = simulate_run(name, seed=2, noise_um=NOISE_UM, error_reference=reference)
        rmse = float(np.sqrt(np.mean((model.predict(run) - run.errors.error_um) ** 2)))
        assert rmse <= 1.5 * NOISE_UM, (reference, name, rmse)
    doc = model.to_document()
    assert doc["error_reference"] == reference and doc["thermal"]["reduced"]["error_reference"] == reference
    if reference != "start":
        assert reference in doc["sensors"] and reference in doc["reference_C"]
        assert ScrewModel.from_document(doc).error_reference_ == reference


def test_default_structure_identifies_alpha_and_q_without_counting_the_air_twice():
    """Effect-free raw runs: with E_e on top of an E_m that follows the air (the old default) alpha and q are biased
    by tens of percent; the default (E_e off) is within a few percent of the twin's truth (q = 0.12 * 0.35 J/mm)."""
    run = simulate_run(FIT, seed=2, noise_um=NOISE_UM)
    new = _fit([run])
    old = _fit([run], ambient=True)
    q_true, alpha_true = 0.12 * 0.35, 11.5e-6
    assert abs(new.values_["q_J_per_mm"] / q_true - 1) < 0.05
    assert abs(old.values_["alpha_per_K"] / alpha_true - 1) > 0.2 or abs(old.values_["q_J_per_mm"] / q_true - 1) > 0.2


def test_a_run_of_another_reference_is_not_predicted():
    model = _fit([simulate_run(FIT, seed=2, noise_um=NOISE_UM, error_reference="T3")])
    with pytest.raises(ValueError, match='referred to "start".*fitted on errors referred to "T3"'):
        model.predict(simulate_run(UNSEEN[0], seed=2, noise_um=NOISE_UM))


def test_reduced_form_of_a_sensor_referenced_model_carries_the_reference_term():
    """The firmware evaluates -alpha (T_R - T_R,ref) P on a sensor-referenced table (models_export/exact.py); the host's
    reduced form must too, or its reduction certificate reports the whole reference term as reduction error (4.7 um
    RMS here, and export refused the model). Checked against the twin's laser errors, not only against the full model."""
    from host.learning.screw.reduced import reduced_predict
    from models_export.export import reduction

    run = simulate_run(FIT, seed=2, noise_um=NOISE_UM, error_reference="T3")
    model = _fit([run])
    cert = model.reduced_["reduction_error_um"]
    assert max(e["rows_rms_um"] for e in cert.values()) < 0.2, cert
    assert reduction(model.to_document())["rms_um"] < 0.5
    rmse = float(np.sqrt(np.mean((reduced_predict(model, run) - run.errors.error_um) ** 2)))
    assert rmse <= 1.25 * NOISE_UM, rmse


def _first_order(t, x, tau):
    """The exact response of a first-order sensor (time constant tau) to x linear between samples, from equilibrium."""
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, t.size):
        h = t[k] - t[k - 1]
        e = np.exp(-h / tau)
        slope = (x[k] - x[k - 1]) / h
        # y' = (x - y)/tau with x = x0 + slope*s: y(h) = x(h) - slope*tau + (y0 - x0 + slope*tau) e^{-h/tau}
        y[k] = x[k] - slope * tau + (y[k - 1] - x[k - 1] + slope * tau) * e
    return y


def test_delagged_recovers_the_air_a_first_order_sensor_lags_behind():
    """An air with an HVAC ripple (20 min) on a drift, read by a 150 s sensor and logged every 10 s with 0.01 K noise:
    the de-lagged reading is within a fifth of the lag's own error of the true air."""
    from host.learning.screw.screwmodel import delagged

    t = np.arange(0.0, 18000.0 + 1, 10.0)
    air = 20.0 + 2.0 * t / 18000.0 + 0.5 * np.sin(2 * np.pi * t / 1200.0)
    reading = _first_order(t, air, 150.0) + np.random.default_rng(1).normal(0.0, 0.01, t.size)
    inner = slice(60, -60)  # the moving average holds the log's ends
    lag_err = np.sqrt(np.mean((reading - air)[inner] ** 2))
    fixed_err = np.sqrt(np.mean((delagged(t, reading, 150.0) - air)[inner] ** 2))
    assert lag_err > 0.15 and fixed_err < 0.2 * lag_err, (lag_err, fixed_err)
    assert np.array_equal(delagged(t, reading, 0.0), reading)


def test_air_sensor_lag_removes_most_of_the_alpha_bias_under_a_sensor_reference():
    """Effect-free runs corrected to the air sensor T3 (150 s time constant in the twin): the screw exchanges heat with
    the air, the model was fed T3's lagged reading, and with E_m over T3 that lag is most of what is left of alpha's
    signal: alpha came out 8.5 % low. With air_lag_s = the sensor's time constant it is within 3 %, and the firmware's
    form (fed the raw reading) stays within the reduction limit."""
    from models_export.export import reduction

    run = simulate_run(FIT, seed=2, noise_um=NOISE_UM, error_reference="T3", temp_noise_K=0.0)
    alpha_true = 11.5e-6
    plain = _fit([run], free="q,h,lambda,alpha")
    lagged = _fit([run], free="q,h,lambda,alpha", air_lag_s=150.0)
    assert abs(plain.values_["alpha_per_K"] / alpha_true - 1) > 0.06
    assert abs(lagged.values_["alpha_per_K"] / alpha_true - 1) < 0.03
    doc = lagged.to_document()
    assert doc["thermal"]["air_lag_s"] == 150.0 and ScrewModel.from_document(doc).air_lag_s_ == 150.0
    assert doc["thermal"]["reduced"]["omitted_effects"] == ["air_lag_s"]
    assert reduction(doc)["rms_um"] < 0.5
    with pytest.raises(ValueError, match="air_lag_s must be"):
        _fit([run], air_lag_s=-1.0)
