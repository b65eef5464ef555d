"""The workflow's family is host/learning/screw's ScrewModel: one screw model, one effect catalog (issue 19 §3)."""
import os

import numpy as np
import pytest

from host.learning.discrepancy.family import CANDIDATES, ScrewFamily
from host.learning.screw.effects import EFFECTS as SCREW_EFFECTS
from host.learning.screw.screwmodel import ScrewModel
from host.twin import EFFECTS as TWIN_EFFECTS
from host.twin import simulate_run
from host.twin.protocols import Phase, Protocol

SHORT = Protocol("s8000", "8000 mm/min 210-490 for 60 min, 30 min cool-down", (Phase(60, 8000, 210, 490), Phase(30)), 9.0)


@pytest.fixture(scope="module")
def run():
    return simulate_run(SHORT, effects={"reversal_error": 0.0}, seed=5, noise_um=0.0)


def test_one_catalog_the_screw_models_and_the_twins_names():
    fam = ScrewFamily()
    assert set(fam.candidates) == set(CANDIDATES) == set(SCREW_EFFECTS)  # every effect the model has, no other
    assert fam.catalog == {n: SCREW_EFFECTS[n] for n in CANDIDATES}
    assert set(SCREW_EFFECTS) <= set(TWIN_EFFECTS)  # the twin can hide each of them
    # nothing else defines an effect: the second family and its catalog are gone
    here = os.path.dirname(os.path.abspath(__import__("host.learning.discrepancy", fromlist=["x"]).__file__))
    assert not {"catalog.py", "screw_family.py"} & set(os.listdir(here))
    with pytest.raises(ValueError, match="unknown effect"):
        ScrewFamily(candidates=("bogus",))


def test_a_candidate_is_a_screw_model_configuration(run):
    fam = ScrewFamily()
    full = [np.ones(len(run.errors), bool)]
    base = fam.fit([run], full, (), None)
    fit = fam.fit([run], full, ("bearing_heat",), base)
    assert isinstance(fit, ScrewModel) and [e.name for e in fit.effects] == ["bearing_heat"]
    assert not fit.ambient and fit.reduced_ is None  # E_m only; the fold fits skip the reduced form
    np.testing.assert_allclose(fam.predict(fit, run), fit.predict(run))
    # noise-free data without bearing heat: the amplitude stays ~0 and the fit is as good
    assert abs(fit.values_["bearing_heat.W_per_m_min"]) < 0.05
    assert fit.statistics_["rmse_um"] <= base.statistics_["rmse_um"] + 1e-3
    # the final fit is the same configuration with the firmware's form: what the workflow writes
    final = fam.fit_final([run], ("bearing_heat",), fit)
    assert [e.name for e in final.effects] == ["bearing_heat"] and final.reduced_["travel_heat_K_per_mm"]
    assert final.reduced_["reduction_error_um"]


def test_fold_rows_are_the_only_rows_fitted(run):
    fam = ScrewFamily()
    e = run.errors
    first = e.time_s < np.median(e.time_s)
    a = fam.fit([run], [first], (), None)
    b = fam.fit([run], [~first], (), None)
    assert a.statistics_["runs"][0]["rows"] == int(first.sum()) and b.statistics_["runs"][0]["rows"] == int((~first).sum())
    with pytest.raises(ValueError, match="row mask"):
        ScrewModel(segments=12, dt_s=60.0).fit([run], row_masks=[first[:-1]])


def test_applicability_is_workflow_logic(run):
    fam = ScrewFamily()
    assert fam.applicable([run], "speed_dependent_heat").startswith("all runs move at one feed")
    uni = simulate_run(SHORT, seed=5, noise_um=0.0)
    uni.errors.direction = None
    assert "bidirectional" in fam.applicable([uni], "reversal_error")
    assert fam.applicable([run], "bearing_heat") is None
    assert fam.used_sensors(run, ("ambient_expansion",)) >= set(run.sensors_with_role("base")[:1])
