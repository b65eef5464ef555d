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
