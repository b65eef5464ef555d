"""The workflow names the heat effects hidden in the independent twin (the other half of test_discrepancy_twin.py,
in its own file so that make test's two workers share the candidate fits)."""
import pytest

from hil_tests.fixtures.shortruns import twin_runs
from host.learning.discrepancy.family import ScrewFamily
from host.learning.discrepancy.workflow import discover
from host.twin import EFFECTS


@pytest.mark.parametrize("name,scale,noise,seed", [
    ("speed_dependent_heat", 1.3, 0.7, 424243),
    ("bearing_heat", 0.7, 0.6, 424244),
    ("moving_convection", 1.2, 0.45, 424245),
])
def test_hidden_heat_effect_named_first_and_gap_halved(name, scale, noise, seed):
    res = discover(twin_runs({name: scale * EFFECTS[name].default}, seed, noise), ScrewFamily(), jobs=1)
    assert res.effects and res.effects[0] == name, res.as_json()["candidates"]
    assert res.after.rmse() <= 0.5 * res.before.rmse()
    # once the effect is in, the held-out residual is at the laser noise level
    assert res.after.rmse() < 1.3 * noise
