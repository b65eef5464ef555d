"""The identified screw model (host/learning/screw) against the independent twin (host/twin): two implementations
of the same physics agree where they share it, and the screw model beats MLR on random moving states.

The twin's extras the model leaves out (nut heat over the nut length, the sensors' own
lags, the sweeps' heat) can be switched off; the drifting air stays on. Then the
model, written separately, must recover the twin's parameters: a disagreement
between the two implementations (grid, integrator, air forcing, expansion integral)
shows here. The held-out acceptance of the full twin (noise floor with the air term,
well above without) is tests/learning/screw/test_screw_twin.py.
"""
import warnings

import numpy as np
import pytest

from host.learning.empirical.fitting import fit_model
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel
from host.twin import make_params, simulate_run

SHARED_PHYSICS_ONLY = {"nut_length_mm": 0.0, "sweep_trips": 0.0, "sensor_tau_scale": 0.0}
NOISE_BUDGET = 1.25  # issue 11: held-out RMSE <= 1.25 x laser noise


def _fit(runs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return ScrewModel(ambient=True).fit(runs)


def _truth():
    p = make_params()
    return {"q_J_per_mm": p.friction_J_per_mm * p.screw_share, "h_W_m2K": p.h_W_m2K,
            "lambda_W_mK": p.conductivity_W_mK, "alpha_per_K": p.alpha_um_mK * 1e-6}


def _rmse(model, runs):
    return float(np.sqrt(np.mean(np.concatenate([model.predict(r) - r.errors.error_um for r in runs]) ** 2)))


@pytest.mark.parametrize("seed", [4, 9])
def test_model_recovers_the_twin_parameters_on_the_shared_physics(seed):
    # noise-free: measured within 1.2 % (seeds 4, 9); with the extras on, lambda drifts by +4.6..5.8 %
    # (the nut's spread heat looks like extra conduction), which is why they are off here
    run = simulate_run("v8000_r210_490", ["ambient_expansion"], seed=seed, noise_um=0.0, **SHARED_PHYSICS_ONLY)
    m = _fit([run])
    assert {"q_J_per_mm", "h_W_m2K", "lambda_W_mK"} <= set(m.free_)
    assert m.air_sensor_ == "T3"  # the twin's air sensor, found by its role
    for k, v in _truth().items():
        if k in m.free_:
            assert m.values_[k] == pytest.approx(v, rel=0.02), (k, m.values_[k], v)
    # with laser noise: every estimate within 3 reported standard errors (measured |z| <= 1.8)
    noisy = simulate_run("v8000_r210_490", ["ambient_expansion"], seed=seed, noise_um=0.5, **SHARED_PHYSICS_ONLY)
    st = _fit([noisy]).statistics_["parameters"]
    for k, v in _truth().items():
        if k in st:
            assert abs(st[k]["value"] - v) <= 3.0 * st[k]["std"], (k, st[k], v)


def test_screw_model_beats_mlr_on_random_moving_states():
    """Issue 16 item 7, the ball-screw paper's verification (its Table 2): both models fitted on the
    8000 mm/min state, predicting random moving states of the full twin (drifting air, every extra on)."""
    train = [simulate_run("v8000_r210_490", ["ambient_expansion"], seed=1)]
    test = [simulate_run("random", ["ambient_expansion"], seed=s) for s in (101, 102)]
    screw = _rmse(_fit(train), test)
    mlr = _rmse(fit_model(train, "mlr", reference="run_start"), test)
    assert screw <= NOISE_BUDGET * 0.5, screw  # measured 0.54 um for 0.5 um laser noise
    assert mlr >= 3 * screw, (mlr, screw)  # measured 3.5 um
