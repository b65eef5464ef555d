"""Closed-form checks of the physics core host/learning/screw/heat.py."""
import numpy as np
import pytest

from host.data.runs import Motion
from host.learning.screw import heat


def _motion(rows):
    cols = np.asarray(rows, dtype=float).T
    return Motion(*cols)


def test_fin_steady_state_within_2_percent():
    geo = heat.ScrewGeometry(length_mm=800.0, diameter_mm=32.0, segments=200)
    par = heat.ScrewParams(h_W_m2K=12.0)
    P = 5.0
    t = np.array([0.0, 1e6, 2e6, 3e6])
    src = np.zeros(geo.segments)
    src[0] = P
    T = heat.simulate_segments(geo, par, t, source_W=src)[-1]
    e = geo.edges_mm
    centres = 0.5 * (e[1:] + e[:-1])
    ref = heat.fin_steady_state(centres, P, geo.length_mm, geo.diameter_mm, par.lambda_W_mK, par.h_W_m2K)
    assert np.max(np.abs(T - ref)) < 0.02 * ref.max()
    # and the heat balance closes: all heat leaves by convection
    _, _, H = heat.segment_properties(e, geo.diameter_mm, par)
    assert np.sum(H * T) == pytest.approx(P, rel=1e-6)


@pytest.mark.parametrize("dt", [1.0, 60.0, 3600.0])
def test_uniform_screw_decays_at_hS_over_cm(dt):
    geo = heat.ScrewGeometry(length_mm=1000.0, diameter_mm=40.0, segments=25)
    par = heat.ScrewParams(h_W_m2K=20.0)
    t = np.arange(0.0, 6 * 3600.0 + dt / 2, dt)
    T = heat.simulate_segments(geo, par, t, T0=np.full(25, 7.0))
    d = geo.diameter_mm * 1e-3
    rate = par.h_W_m2K * np.pi * d / (par.c_J_kgK * par.density_kg_m3 * np.pi * d * d / 4)
    np.testing.assert_allclose(T, 7.0 * np.exp(-rate * t)[:, None] * np.ones((1, 25)), rtol=1e-9, atol=1e-12)


def test_stable_for_any_step_and_matches_fine_grid():
    geo = heat.ScrewGeometry(length_mm=600.0, diameter_mm=25.0, segments=30)
    par = heat.ScrewParams(q_J_per_mm=0.1, h_W_m2K=10.0)
    mot = _motion([[0, 3600, 100, 400, 6000]])
    coarse = np.array([0.0, 900.0, 3600.0, 20000.0])
    fine = np.linspace(0.0, 20000.0, 20001)
    Tc = heat.simulate_segments(geo, par, coarse, heat.friction_heat_J(heat.nut_travel_per_segment(mot, geo.edges_mm, 0.0, coarse), par))
    Tf = heat.simulate_segments(geo, par, fine, heat.friction_heat_J(heat.nut_travel_per_segment(mot, geo.edges_mm, 0.0, fine), par))
    assert np.all(np.isfinite(Tc)) and Tc.min() >= -1e-12
    # the coarse step is exact for constant power; the motion's power is constant on [0, 3600]
    np.testing.assert_allclose(Tc[2], Tf[3600], rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(Tc[3], Tf[-1], rtol=1e-3, atol=1e-9)


def test_nut_travel_counts_passes():
    edges = np.array([0.0, 100.0, 200.0, 300.0, 400.0])
    # 100->300 at 6000 mm/min = 100 mm/s for 10 s: 1000 mm = 5 legs of 200 mm
    mot = _motion([[0, 10, 100, 300, 6000]])
    u = heat.nut_travel_per_segment(mot, edges, 0.0, np.array([0.0, 1.0, 3.0, 10.0, 20.0]))
    np.testing.assert_allclose(u.sum(axis=0), [0, 500, 500, 0])
    np.testing.assert_allclose(u[0], [0, 100, 0, 0])  # first second: 100->200
    np.testing.assert_allclose(u[1], [0, 0, 200, 0])  # 200->300, then back 300->200
    np.testing.assert_allclose(u[3], 0)
    # fixed end offset shifts the segments in axis coordinates
    u2 = heat.nut_travel_per_segment(mot, edges, -100.0, np.array([0.0, 10.0]))
    np.testing.assert_allclose(u2[0], [0, 0, 500, 500])


def test_error_zero_when_cold_and_at_fixed_end():
    edges = np.linspace(0, 500, 11)
    rises = np.zeros((4, 10))
    assert np.all(heat.thermal_error_um(edges, rises, np.array([0, 100, 250, 490]), 0.0, 11.5e-6) == 0)
    warm = np.linspace(1, 3, 10)
    assert heat.thermal_error_um(edges, warm, 0.0, 0.0, 11.5e-6) == 0.0
    assert heat.thermal_error_um(edges, warm, -20.0, -20.0, 11.5e-6) == 0.0
    # pro-rata partial segment: 1.5 segments of 1 K, 50 mm each
    E = heat.thermal_error_um(edges, np.ones(10), 75.0, 0.0, 1e-5)
    assert E == pytest.approx(1e3 * 1e-5 * 75.0)
    grid = heat.thermal_error_um(edges, np.ones((3, 1, 10)), np.array([[0.0, 250.0, 500.0]]), 0.0, 1e-5)
    assert grid.shape == (3, 3)
    np.testing.assert_allclose(grid[0], [0, 2.5, 5.0])


def test_convection_multiplier_and_bad_shapes():
    geo = heat.ScrewGeometry(length_mm=400.0, diameter_mm=20.0, segments=8)
    par = heat.ScrewParams()
    t = np.arange(0, 3601, 60.0)
    T1 = heat.simulate_segments(geo, par, t, T0=np.ones(8))
    g = np.where(t[:-1] < 1800, 2.0, 1.0)
    T2 = heat.simulate_segments(geo, par, t, T0=np.ones(8), convection_mult=g)
    assert np.all(T2[1:] < T1[1:])
    with pytest.raises(ValueError, match="heat_J must have shape"):
        heat.simulate_segments(geo, par, t, heat_J=np.zeros((3, 8)))
    with pytest.raises(ValueError, match="diameter_mm"):
        heat.ScrewGeometry(length_mm=100.0, diameter_mm=0.0)


@pytest.mark.parametrize("n", [1, 5, 64, 65, 1000])
def test_blocked_modal_scan_equals_the_plain_recurrence(n):
    rng = np.random.default_rng(n)
    e = rng.uniform(0.0, 1.0, 7)
    e[0], e[1] = 1.0, 1e-30  # an undamped mode and a mode that dies within one step
    W = rng.normal(size=(n, 7))
    z = rng.normal(size=7)
    got = heat.modal_scan(e, W, z)
    ref = []
    for k in range(n):
        z = e * z + W[k]
        ref.append(z)
    np.testing.assert_allclose(got, np.array(ref), rtol=1e-12, atol=1e-12)


def test_spread_travel_matches_exact_travel_on_average():
    edges = np.linspace(0.0, 800.0, 17)
    mot = _motion([[0, 3600, 210, 490, 8000], [4000, 5000, 700, 0, 12000]])
    t = np.arange(0.0, 6001.0, 10.0)
    exact = heat.nut_travel_per_segment(mot, edges, 0.0, t)
    spread = heat.nut_travel_per_segment(mot, edges, 0.0, t, spread=True)
    np.testing.assert_allclose(spread.sum(axis=1), exact.sum(axis=1), rtol=1e-12, atol=1e-9)  # same distance per step
    # same travel per segment over each interval, up to the last unfinished leg
    np.testing.assert_allclose(spread[:360].sum(axis=0), exact[:360].sum(axis=0), atol=280.0)
    assert np.all(spread[:360].sum(axis=0)[edges[1:] <= 210] == 0)
    assert heat.nut_travel_per_segment(None, edges, 0.0, t, spread=True).shape == (600, 16)


def test_interp_rows_matches_np_interp():
    tg = np.array([0.0, 10.0, 25.0, 40.0])
    v = np.arange(12.0).reshape(4, 3) ** 2
    t = np.array([-5.0, 0.0, 3.0, 10.0, 24.9, 40.0, 50.0])
    ref = np.stack([np.interp(t, tg, v[:, j]) for j in range(3)], axis=1)
    np.testing.assert_allclose(heat.interp_rows(t, tg, v), ref)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(a=st.floats(0, 700), b=st.floats(0, 700), feed=st.floats(100, 20000), t0=st.floats(0, 500), dur=st.floats(1, 5000),
       dt=st.floats(0.5, 400), spread=st.booleans())
def test_nut_travel_conserves_distance(a, b, feed, t0, dur, dt, spread):
    edges = np.linspace(0.0, 800.0, 23)
    mot = _motion([[t0, t0 + dur, a, b, feed]])
    t = np.arange(0.0, t0 + dur + 3 * dt, dt)
    u = heat.nut_travel_per_segment(mot, edges, 0.0, t, spread=spread)
    assert np.all(u >= -1e-9)
    moved = feed / 60.0 * (min(t[-1], t0 + dur) - t0) if abs(b - a) > heat.MIN_RANGE_MM else 0.0
    assert u.sum() == pytest.approx(moved, rel=1e-9, abs=1e-6)
    # nothing outside the range
    lo, hi = min(a, b), max(a, b)
    outside = (edges[1:] <= lo) | (edges[:-1] >= hi)
    assert np.all(u[:, outside] == 0)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), M=st.integers(1, 30), dt=st.floats(0.1, 5000))
def test_nonnegative_heat_gives_nonnegative_rises(seed, M, dt):
    rng = np.random.default_rng(seed)
    geo = heat.ScrewGeometry(length_mm=500.0, diameter_mm=25.0, segments=M)
    t = np.arange(0, 30) * dt
    T = heat.simulate_segments(geo, heat.ScrewParams(), t, rng.uniform(0, 50, (29, M)) * (rng.uniform(size=(29, 1)) > 0.5))
    assert np.all(T >= -1e-9 * max(1.0, T.max()))
    assert np.all(np.isfinite(T))


@pytest.mark.parametrize("dt", [10.0, 600.0, 3600.0])
def test_screw_follows_a_linear_air_ramp_with_the_analytic_lag(dt):
    # Far from any heat a solid screw is a lumped body: τ dθ/dt = a(t) - θ with τ = c·ρ·d/(4h).
    # For a(t) = r·t from equilibrium, θ(t) = r·(t - τ·(1 - e^{-t/τ})), so the lag tends to r·τ.
    # The first-order hold is exact for this input at any step; a zero-order hold (air held at
    # a[k] over the step) would lag by a further r·dt/2 = 0.17 K at dt = 600 s.
    geo = heat.ScrewGeometry(800.0, 32.0, segments=16)
    par = heat.ScrewParams(h_W_m2K=12.0)
    tau = par.c_J_kgK * par.density_kg_m3 * 0.032 / (4 * par.h_W_m2K)
    r = 2.0 / 3600.0
    t = np.arange(0.0, 6 * 3600.0 + 1, dt)
    exact = r * (t - tau * (1.0 - np.exp(-t / tau)))
    T = heat.simulate_segments(geo, par, t, air_K=r * t)
    assert np.max(np.abs(T - exact[:, None])) < 1e-9
    assert abs((r * t[-1] - T[-1, 0]) - r * tau) < 0.01 * r * tau  # steady lag r·τ after 9 τ
    # the same exactness on the variable-step path (one propagator per distinct step)
    tv = np.r_[t[:3], t[3:] + np.linspace(0.0, 1.0, t.size - 3)]
    Tv = heat.simulate_segments(geo, par, tv, air_K=r * tv)
    assert np.max(np.abs(Tv - (r * (tv - tau * (1.0 - np.exp(-tv / tau))))[:, None])) < 1e-9


def test_air_forcing_keeps_equilibrium_and_superposes_with_heat():
    geo = heat.ScrewGeometry(600.0, 25.0, segments=12)
    par = heat.ScrewParams()
    t = np.linspace(0.0, 7200.0, 121)
    still = heat.simulate_segments(geo, par, t, air_K=np.full(t.size, 3.0))
    assert np.max(np.abs(still - 3.0)) < 1e-12  # starts in equilibrium with the air (T0 default a[0]) and stays
    rng = np.random.default_rng(3)
    q = rng.uniform(0.0, 20.0, (t.size - 1, 12))
    air = np.cumsum(rng.normal(0.0, 0.05, t.size))
    both = heat.simulate_segments(geo, par, t, q, air_K=air)
    parts = heat.simulate_segments(geo, par, t, q, T0=np.zeros(12)) + heat.simulate_segments(geo, par, t, air_K=air)
    assert np.max(np.abs(both - parts)) < 1e-10  # linear system: heat and air superpose
    with pytest.raises(ValueError, match="air_K must have shape"):
        heat.simulate_segments(geo, par, t, air_K=air[:-1])


def test_shared_propagators_give_what_a_fresh_build_gives_whatever_came_before():
    """simulate_segments keeps its propagators across calls for the same segment properties
    (heat.shared_propagator): a cached matrix must be the one these very (dt, g) give, not one of a
    multiplier that only rounds the same (g 1e-13 apart), and a warm call must equal a cold one."""
    geo, params = heat.ScrewGeometry(length_mm=800, diameter_mm=32, segments=12), heat.ScrewParams()
    C, G, H = heat.segment_properties(geo.edges_mm, geo.diameter_mm, params, geo.bore_mm)
    g1 = 1.0 + 0.25 * np.arange(C.size) + 1e-13
    g2 = g1 + 2e-13  # equal to g1 in 12 decimals
    heat._SHARED.clear()
    shared = heat.shared_propagator(C, G, H)
    assert heat.shared_propagator(C.copy(), G.copy(), H.copy()) is shared  # the same properties: kept
    first = shared.step(600.0, g1)
    second = shared.step(600.0, g2)
    fresh = heat.Propagator(C, G, H).step(600.0, g2)
    assert not np.array_equal(first[0], fresh[0])  # the two multipliers do give different matrices
    for a, b in zip(second, fresh):
        np.testing.assert_array_equal(a, b)
    fresh_air = heat.Propagator(C, G, H).air_step(600.0, g2)
    for a, b in zip(shared.air_step(600.0, g2), fresh_air):
        np.testing.assert_array_equal(a, b)
    # a whole simulation with varying steps and multipliers, cold and then warm
    t = np.r_[0.0, np.cumsum(np.tile([60.0, 90.0, 600.0], 20))]
    rng = np.random.default_rng(5)
    heat_J = rng.uniform(0, 50, (t.size - 1, C.size))
    mult = np.tile([[1.0], [1.5], [2.0]], (20, C.size))
    air = np.linspace(0.0, 2.0, t.size)
    heat._SHARED.clear()
    cold = heat.simulate_segments(geo, params, t, heat_J, convection_mult=mult, air_K=air)
    warm = heat.simulate_segments(geo, params, t, heat_J, convection_mult=mult, air_K=air)
    np.testing.assert_array_equal(cold, warm)
    assert len(heat._SHARED) == 1
