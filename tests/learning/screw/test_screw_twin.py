"""Identification on runs of the digital twin (host/twin), whose true parameters are known."""
import warnings

import numpy as np
import pytest

from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel

import host.twin as sim

# The twin (host/twin/screw.py, docs/twin.md) has its own finite volumes, absolute temperature and a
# drifting air, so the model is fitted with its air term on (auto) unless a test removes it.
STATES = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490", "v8000_r0_700")  # literature states 1, 2, 3, 5


def _truth():
    p = sim.make_params()
    return {"q_J_per_mm": p.friction_J_per_mm * p.screw_share, "h_W_m2K": p.h_W_m2K,
            "lambda_W_mK": p.conductivity_W_mK, "alpha_per_K": p.alpha_um_mK * 1e-6}


def test_noise_free_twin_run_recovers_parameters():
    # the old twin shares the model's equations: 2 %; the independent twin spreads the nut heat over the nut
    # and discretises its own way (measured: q -1.3 %, h -1.6 %, lambda +4.6 %), so 3 % on q and h, 10 % on
    # lambda (the weakest-identified); alpha comes from meta.json there (not free)
    run = sim.simulate_run("v8000_r210_490", effects=["ambient_expansion"], seed=4, noise_um=0.0)
    m = ScrewModel(ambient=True, air="auto").fit([run])
    tol = {"q_J_per_mm": 0.03, "h_W_m2K": 0.03, "lambda_W_mK": 0.10, "alpha_per_K": 0.02}
    for k, v in _truth().items():
        if k in m.free_:
            assert m.values_[k] == pytest.approx(v, rel=tol.get(k, 0.02)), (k, m.values_[k], v)
    assert {"q_J_per_mm", "h_W_m2K", "lambda_W_mK"} <= set(m.free_)


# The estimates within their reported standard errors: on the physics model and twin share
# (tests/twin/test_sim_model_agreement.py); the twin's extras bias them by more, so the held-out test
# below is the acceptance on the full twin.


def _heldout_ratios(seed, noise_um, air):
    runs = [sim.simulate_run(p, seed=seed + i, noise_um=noise_um) for i, p in enumerate(STATES)]
    out = []
    for k, r in enumerate(runs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentifiabilityWarning)
            m = ScrewModel(ambient=False, air=air, segments=20, dt_s=20.0).fit([x for j, x in enumerate(runs) if j != k])
        out.append(float(np.sqrt(np.mean((r.errors.error_um - m.predict(r)) ** 2))) / noise_um)
    return out


@pytest.mark.parametrize("seed,noise", [(31, 0.4)])  # more seeds and noise levels: tools/bench_screw.py
def test_heldout_reaches_the_laser_noise_and_fails_without_the_air_term(seed, noise):
    # fitted on three of the four states, predicting the fourth: at the noise floor (<= 1.25 x) with the
    # air term, several times above it with the air removed (the model before issue 11)
    with_air = _heldout_ratios(seed, noise, "auto")
    assert max(with_air) <= 1.25, with_air
    without = _heldout_ratios(seed, noise, "off")
    assert min(without) > 1.5 and max(without) > 3.0, without
