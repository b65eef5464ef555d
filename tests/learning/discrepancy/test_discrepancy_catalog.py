import numpy as np
import pytest

from host.learning.discrepancy.catalog import CATALOG, FEED_REF_MM_MIN
import host.twin
from host.learning.discrepancy.screw_family import Drive
from host.learning.discrepancy.screw_family import ScrewFamily as Family
from host.twin import EFFECTS, simulate_run

# the twin's screw follows a drifting air only since the independent twin (see test_discrepancy_twin.py)
TWIN_AIR = hasattr(host.twin, "STILL_AIR")


def ScrewFamily(**kw):  # noqa: N802
    return Family(air=TWIN_AIR, **kw)

REQUIRED = ("ambient_expansion", "speed_dependent_heat", "bearing_heat", "moving_convection", "reversal_error")


@pytest.fixture(scope="module")
def run():
    return simulate_run("mixed", effects={"reversal_error": 0.0}, seed=5, noise_um=0.0)


def test_catalog_names_are_the_twins():
    assert set(REQUIRED) <= set(CATALOG)
    assert set(CATALOG) <= set(EFFECTS)
    for e in CATALOG.values():
        assert e.hook in ("heat", "convection", "output")
        assert e.params and all(p.lo < p.hi for p in e.params)


def test_hooks_follow_the_documented_forms(run):
    d = Drive(run)
    e = run.errors
    base = run.sensors_with_role("base")[0]
    rise = np.interp(e.time_s, run.temperatures.time_s, run.temperatures.column(base)) - run.temperatures.column(base)[0]
    np.testing.assert_allclose(CATALOG["ambient_expansion"].columns(d)[:, 0], d.alpha_per_K * 1e3 * rise * e.position_mm)
    np.testing.assert_allclose(CATALOG["reversal_error"].columns(d)[:, 0], 0.5 * e.direction)
    (hj, src), = CATALOG["speed_dependent_heat"].unit_inputs(d)
    assert src is None and hj.shape == d.travel.shape
    # every step is at one feed (the grid follows the motion boundaries): travel_feed = travel * feed / feed_ref
    moving = d.travel.sum(axis=1) > 0
    ratio = hj[moving].sum(axis=1) / d.travel[moving].sum(axis=1)
    assert set(np.round(ratio * FEED_REF_MM_MIN).tolist()) == set(run.motion.feed_mm_min.tolist())
    (hj, src), = CATALOG["bearing_heat"].unit_inputs(d)
    assert hj is None and np.all(src[:, 1:] == 0)
    np.testing.assert_allclose(src[:, 0], d.speed)
    g = CATALOG["moving_convection"].convection(d, {"rise": 0.7})
    np.testing.assert_allclose(g[~moving], 1.0)
    assert np.all(g[moving] > 1.0)


def test_zero_magnitude_effect_changes_nothing(run):
    fam = ScrewFamily()
    full = [np.ones(len(run.errors), bool)]
    a = fam.fit([run], full, (), None)
    for name in ("bearing_heat", "speed_dependent_heat", "reversal_error"):
        b = fam.fit([run], full, (name,), a)
        # noise-free data of the base model: the extra amplitude stays ~0 and the fit is as good
        assert abs(list(b.linear.values())[-1]) < 1e-2 * (CATALOG[name].params[0].hi - CATALOG[name].params[0].lo)
        assert b.rmse_um <= a.rmse_um + 1e-6


def test_base_fit_recovers_twin_parameters(run):
    fit = ScrewFamily().fit([run], [np.ones(len(run.errors), bool)], (), None)
    p = run.meta["simulation"]["params"]
    assert fit.nonlinear["h_W_m2K"] == pytest.approx(p["h_W_m2K"], rel=0.1)
    assert fit.linear["q_J_per_mm"] == pytest.approx(p["friction_J_per_mm"] * p["screw_share"], rel=0.1)
    assert fit.rmse_um < 0.2


def test_bounded_lstsq_matches_scipy():
    from scipy.optimize import lsq_linear

    from host.learning.discrepancy.screw_family import _bounded_lstsq

    rng = np.random.default_rng(8)
    X = rng.normal(size=(500, 6))
    X /= np.linalg.norm(X, axis=0)
    y = X @ np.array([3.0, -2.0, 0.5, 1.0, -4.0, 2.0]) + rng.normal(0, 0.1, 500)
    for lo, hi in ((np.full(6, -np.inf), np.full(6, np.inf)), (np.full(6, -1.0), np.full(6, 1.5))):
        ref = lsq_linear(X, y, bounds=(lo, hi), method="bvls").x
        np.testing.assert_allclose(_bounded_lstsq(X, y, lo, hi), ref, atol=1e-8)


def test_effect_definition_is_checked():
    from host.learning.discrepancy.catalog import CandidateEffect, Param

    with pytest.raises(ValueError, match="needs unit_inputs"):
        CandidateEffect("x", "heat", "no hook function", (Param("a", "W", 0.0, 1.0),))
    with pytest.raises(ValueError, match="hook must be one of"):
        CandidateEffect("x", "radiation", "bad hook", (Param("a", "W", 0.0, 1.0),), columns=lambda d: None)


def test_a_new_effect_plugs_in(run):
    """docs/discrepancy.md 'Adding an effect': one definition, the family fits it."""
    from host.learning.discrepancy.catalog import CandidateEffect, Param

    def floating_end(drive):
        src = np.zeros_like(drive.travel)
        src[:, -1] = drive.speed
        return [(None, src)]

    extra = CandidateEffect("floating_end_heat", "heat", "source at the floating end", (Param("P_W", "W", 0.0, 50.0),),
                            unit_inputs=floating_end, requires=("motion",))
    fam = ScrewFamily(catalog={**CATALOG, extra.name: extra})
    assert "floating_end_heat" in fam.candidates
    fit = fam.fit([run], [np.ones(len(run.errors), bool)], ("floating_end_heat",), None)
    assert "floating_end_heat.P_W" in fit.linear
