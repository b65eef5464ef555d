"""Physics of the feed-axis twin against closed forms written here, independently of host/twin/screw.py.

Every closed form below is derived in its docstring; the twin's screw core is a
vertex-centred finite-volume grid stepped by sub-stepped Crank-Nicolson, so
agreement is a real check of the discretisation, the air forcing and the heat input.
"""
import math

import numpy as np
import pytest

from host.twin import NODES, STILL_AIR, Phase, Protocol, make_params, simulate
from host.twin.screw import ScrewGrid, ScrewIntegrator, contact_travel
from host.twin.structure import lagged



def _fin_green(x_m, xi_m, L_m, lam, area, m):
    """Steady 1-D fin theta'' - m^2 theta = -q'/(lambda A), insulated ends: response at x to 1 W/m at xi."""
    lo, hi = np.minimum(x_m, xi_m), np.maximum(x_m, xi_m)
    return np.cosh(m * lo) * np.cosh(m * (L_m - hi)) / (lam * area * m * np.sinh(m * L_m))


def _fin_profile(x_m, density_W_m, xi_m, L_m, lam, area, m):
    """theta(x) = integral G(x, xi) q'(xi) dxi (trapezoid over a fine xi grid)."""
    G = _fin_green(x_m[:, None], xi_m[None, :], L_m, lam, area, m)
    f = G * density_W_m[None, :]
    return np.sum(0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(xi_m)[None, :], axis=1)


def _band_density(xi_mm, a, b, nut_mm, q_W):
    """Time-averaged heat density (W/m) of a nut of length l reciprocating over [a, b]: the band smeared by the nut."""
    if nut_mm <= 0:
        inside = ((xi_mm >= a) & (xi_mm <= b)).astype(float)
    else:
        lo, hi = np.maximum(xi_mm - nut_mm / 2, a), np.minimum(xi_mm + nut_mm / 2, b)
        inside = np.clip(hi - lo, 0.0, None) / nut_mm
    return q_W / ((b - a) * 1e-3) * inside


@pytest.mark.parametrize(
    "feed,a,b,effects,nut_mm",
    [(8000, 210, 490, None, 0.0), (8000, 210, 490, None, 90.0), (15000, 100, 300, {"moving_convection": 1.0}, 90.0),
     (6500, 100, 700, {"speed_dependent_heat": 0.6}, 60.0)],
)
def test_steady_state_matches_fin_equation(feed, a, b, effects, nut_mm):
    hours = 12  # > 20 convective time constants
    proto = Protocol("steady", "constant heat", (Phase(hours * 60, feed, a, b),))
    sim = simulate(proto, effects, seed=0, noise_um=0.0, dt_s=30.0, sweep_duration_min=0.0, temp_noise_K=0.0,
                   nut_length_mm=nut_mm, **STILL_AIR)
    p, eff = sim.params, sim.effects
    mv = eff.get("speed_dependent_heat", 0.0)
    e_mm = p.friction_J_per_mm * ((1 - mv) + mv * feed / p.feed_ref_mm_min)
    q_W = p.screw_share * e_mm * feed / 60.0
    h = p.h_W_m2K * (1 + eff.get("moving_convection", 0.0) * (feed / p.feed_ref_mm_min) ** 0.8)
    lam, area = p.conductivity_W_mK, math.pi * (p.screw_diameter_mm * 1e-3) ** 2 / 4
    m = math.sqrt(h * math.pi * p.screw_diameter_mm * 1e-3 / (lam * area))
    L = p.screw_length_mm * 1e-3
    xi = np.linspace(0.0, p.screw_length_mm, 4001)
    density = _band_density(xi, a, b, nut_mm, q_W)
    assert np.sum(0.5 * (density[1:] + density[:-1]) * np.diff(xi) * 1e-3) == pytest.approx(q_W, rel=1e-3)
    rise = sim.screw_C[-1] - sim.air_C[-1]
    exact = _fin_profile(sim.screw_x_mm * 1e-3, density, xi * 1e-3, L, lam, area, m)
    assert np.max(np.abs(rise - exact)) <= 0.004 * exact.max()  # measured <= 0.31 %; a point nut misses the 90 mm nut by 1.3 %
    # the error integral too: E(P) = alpha * int_0^P theta dx at the last sweep
    xs = np.linspace(0.0, p.screw_length_mm, 401)
    theta = _fin_profile(xs * 1e-3, density, xi * 1e-3, L, lam, area, m)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (theta[1:] + theta[:-1]) * np.diff(xs) * 1e-3)])
    last = sim.err_time_s == sim.sweep_s[-1]
    E_exact = p.alpha_um_mK * np.interp(sim.err_position_mm[last], xs, cum)
    assert np.max(np.abs(sim.err_thermal_um[last] - E_exact)) <= 0.004 * E_exact.max()
    assert E_exact.max() > 10.0  # a meaningful size, not a trivially small comparison


def test_nut_length_spreads_the_heat_beyond_the_range_and_conserves_it():
    point = simulate("v8000_r210_490", None, noise_um=0.0, nut_length_mm=0.0, sweep_duration_min=0.0, **STILL_AIR)
    spread = simulate("v8000_r210_490", None, noise_um=0.0, nut_length_mm=90.0, sweep_duration_min=0.0, **STILL_AIR)
    np.testing.assert_allclose(spread.power_W["screw"], point.power_W["screw"], rtol=1e-9, atol=1e-12)
    warm = int(180 * 60 / point.params.dt_s)
    x = point.screw_x_mm
    outside = (x < 200) | (x > 500)
    gain = spread.screw_C[warm] - point.screw_C[warm]
    # heat now also enters up to 45 mm outside the range: warmer just outside, cooler at the range's core
    assert gain[(x > 160) & (x < 200)].min() > 0 and gain[(x > 500) & (x < 540)].min() > 0
    assert gain[(x > 300) & (x < 400)].max() < 0
    assert outside.any()


def test_contact_travel_matches_a_sampled_nut():
    """Sample the nut's path finely and credit each sample's travel to the volumes by the nut length inside them."""
    p = make_params()
    grid = ScrewGrid(p)
    t = np.arange(0.0, 121.0, 10.0)
    nut = 90.0
    got = contact_travel(grid.bounds_mm, t, 3.0, 113.0, 400.0, 130.0, 9000.0, nut)
    ts = np.linspace(3.0, 113.0, 55001)
    v = 9000.0 / 60.0
    s = (ts - 3.0) * v
    span = 270.0
    leg, r = np.floor(s / span), s - np.floor(s / span) * span
    pos = np.where(leg % 2 == 0, 400.0 - r, 130.0 + r)  # starts at 400 running down
    mid = 0.5 * (pos[1:] + pos[:-1])
    step = np.abs(np.diff(pos))
    lo = np.clip(grid.bounds_mm[:-1], -1e9, 1e9)
    hi = np.clip(grid.bounds_mm[1:], -1e9, 1e9)
    share = np.clip(np.minimum(hi[None, :], mid[:, None] + nut / 2) - np.maximum(lo[None, :], mid[:, None] - nut / 2),
                    0.0, None) / nut
    k = np.searchsorted(t, 0.5 * (ts[1:] + ts[:-1]), side="right") - 1
    want = np.zeros_like(got)
    np.add.at(want, k, step[:, None] * share)
    assert got.sum() == pytest.approx((113.0 - 3.0) * v, rel=1e-9)
    np.testing.assert_allclose(got, want, atol=2e-3 * got.max())


def test_screw_follows_a_linear_air_ramp_with_lag_r_tau():
    """No heat, insulated ends, uniform h: T(t) = T_air(t) - r*tau*(1 - exp(-t/tau)), tau = rho*c*d/(4h)."""
    p = make_params()
    tau = 7850.0 * 460.0 * 0.032 / (4 * 15.0)
    grid = ScrewGrid(p)
    t = np.arange(0.0, 6 * 3600.0 + 1, p.dt_s)
    r = 2.0 / 3600.0
    air = 20.0 + r * t
    T = ScrewIntegrator(grid, p.dt_s, p.time_constant_s).run(air, np.zeros((t.size - 1, grid.n_nodes)),
                                                              np.ones(t.size - 1))
    exact = air - r * tau * (1.0 - np.exp(-t / tau))
    assert r * tau > 1.0  # over 1 K of lag: a real size
    np.testing.assert_allclose(T, np.repeat(exact[:, None], grid.n_nodes, axis=1), atol=1e-4)


def test_twin_screw_and_error_follow_the_drifting_air():
    """Idle, no friction, air = mean + dT*(1 - cos(w t))/2: the screw is a first-order lag of it (closed form),
    and the error is alpha * P * (T - T(0))."""
    over = dict(STILL_AIR, ambient_rise_min_K=2.2, ambient_rise_max_K=2.2, friction_J_per_mm=0.0, temp_noise_K=0.0)
    sim = simulate("idle", None, noise_um=0.0, **over)
    dT, hours = 2.2, 8.0
    w = math.pi / (hours * 3600.0)
    tau = 7850.0 * 460.0 * 0.032 / (4 * 15.0)
    t = sim.t_s
    np.testing.assert_allclose(sim.air_C, 20.0 + dT * (1 - np.cos(w * t)) / 2, atol=1e-12)
    k = 1.0 + (w * tau) ** 2
    lagged_air = dT / 2 * (1 - (np.cos(w * t) + w * tau * np.sin(w * t)) / k) - dT / 2 * (1 - 1 / k) * np.exp(-t / tau)
    np.testing.assert_allclose(sim.screw_C - 20.0, np.repeat(lagged_air[:, None], sim.screw_C.shape[1], axis=1),
                               atol=1e-4)
    lag_K = (20.0 + dT * (1 - np.cos(w * t)) / 2 - sim.screw_C[:, 0])[t <= 4 * 3600].max()
    assert lag_K > 0.2  # the screw trails a 2.2 K rise over 8 h (r up to 0.43 K/h, tau 32 min) by r*tau
    E = sim.err_thermal_um
    P = sim.err_position_mm
    T_at = np.interp(sim.err_time_s, t, lagged_air)
    np.testing.assert_allclose(E, sim.params.alpha_um_mK * T_at * P * 1e-3, atol=1e-6)
    assert E.max() > 10.0


def test_sensor_reading_is_an_exact_first_order_lag():
    """A ramp through a first-order sensor: u - r*tau*(1 - exp(-t/tau)) at every sample."""
    t = np.arange(0.0, 3600.0 + 1, 10.0)
    u = np.stack([5.0 + 0.01 * t, 5.0 + 0.01 * t], axis=1)
    y = lagged(u, [150.0, 0.0], 10.0)
    np.testing.assert_allclose(y[:, 0], u[:, 0] - 0.01 * 150.0 * (1 - np.exp(-t / 150.0)), atol=1e-10)
    np.testing.assert_array_equal(y[:, 1], u[:, 1])


def test_every_sensor_lags_its_body_with_its_own_time_constant():
    sim = simulate("v8000_r210_490", None, noise_um=0.0, temp_noise_K=0.0)
    taus = [nd.sensor_s for nd in NODES]
    assert min(taus) > 0 and len(set(taus)) > 1
    np.testing.assert_allclose(sim.readings_true_C, lagged(sim.nodes_true_C, taus, sim.params.dt_s), atol=1e-12)
    ideal = simulate("v8000_r210_490", None, noise_um=0.0, temp_noise_K=0.0, sensor_tau_scale=0.0)
    np.testing.assert_array_equal(ideal.readings_true_C, ideal.nodes_true_C)
    assert np.abs(ideal.readings_true_C - sim.readings_true_C).max() > 0.01
    air = [i for i, nd in enumerate(NODES) if nd.location.startswith("air 0.5 m")][0]
    np.testing.assert_allclose(sim.nodes_true_C[:, air], sim.air_C, atol=1e-12)
    # the air sensor trails the rising air: below it on average, never by more than the warming of one lag
    d = sim.air_C - sim.sensors_C[:, air]
    assert d[sim.t_s < 4 * 3600].mean() > 0 and np.abs(d).max() < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_air_rises_by_the_seeded_amount_with_an_hvac_ripple(seed):
    sim = simulate("v8000_r210_490", None, seed=seed, noise_um=0.0)
    p = sim.params
    assert p.ambient_rise_min_K <= sim.air_rise_K <= p.ambient_rise_max_K
    assert p.hvac_period_min_min <= sim.hvac_period_min <= p.hvac_period_max_min
    still = simulate("v8000_r210_490", None, seed=seed, noise_um=0.0, hvac_ripple_K=0.0, ambient_wander_K=0.0)
    assert still.air_C[-1] - still.air_C[0] == pytest.approx(sim.air_rise_K, abs=1e-9)
    ripple = sim.air_C - simulate("v8000_r210_490", None, seed=seed, noise_um=0.0, hvac_ripple_K=0.0).air_C
    assert np.abs(ripple).max() == pytest.approx(p.hvac_ripple_K, rel=0.05)
    # a triangle wave repeating with the drawn period (shifted by whole samples: off by at most a half-sample slope)
    period_s = sim.hvac_period_min * 60
    lag = int(round(period_s / p.dt_s))
    assert np.abs(ripple[lag:] - ripple[:-lag]).max() <= 4 * p.hvac_ripple_K / period_s * p.dt_s


def test_sweeps_move_the_nut_and_heat_the_screw():
    """Idle with still air: the only heat is each sweep's round trip over the targets (2 * 700 mm of travel)."""
    sim = simulate("idle", None, noise_um=0.0, **STILL_AIR)
    p = sim.params
    sweeps_with_travel = np.sum(sim.sweep_s < sim.t_s[-1])
    expected_J = sweeps_with_travel * 2 * 700.0 * p.friction_J_per_mm * p.screw_share
    assert np.sum(sim.power_W["screw"]) * p.dt_s == pytest.approx(expected_J, rel=1e-9)
    assert sim.motion.size == 0  # motion.csv holds the protocol, not the measurement travel
    assert sim.err_thermal_um.max() > 0.05  # small but present
    two = simulate("idle", None, noise_um=0.0, sweep_trips=2.0, **STILL_AIR)
    assert np.sum(two.power_W["screw"]) == pytest.approx(2 * np.sum(sim.power_W["screw"]), rel=1e-9)
    for off in (simulate("idle", None, noise_um=0.0, sweep_duration_min=0.0, **STILL_AIR),
                simulate("idle", None, noise_um=0.0, sweep_trips=0.0, **STILL_AIR)):
        np.testing.assert_allclose(off.err_thermal_um, 0.0, atol=1e-9)  # rounding of the step maps only


@pytest.mark.parametrize("protocol", ["idle", "v15000_r210_490"])
def test_zero_heat_and_still_air_give_zero_thermal_error(protocol):
    sim = simulate(protocol, None, noise_um=0.0, friction_J_per_mm=0.0, **STILL_AIR)
    assert np.all(sim.power_W["screw"] == 0.0)
    # the step maps of a screw at rest in still air reproduce it to rounding (1e-12 um measured)
    np.testing.assert_allclose(sim.err_thermal_um, 0.0, atol=1e-9)
    np.testing.assert_allclose(sim.err_um, sim.err_geometric_um, atol=1e-9)


def test_uniformly_warmed_screw_error_is_linear_and_monotone_in_P():
    # a point nut covering the whole insulated screw heats it uniformly: theta const, E = alpha*theta*P
    proto = Protocol("uniform", "whole screw", (Phase(240, 8000, 0, 800),))
    sim = simulate(proto, None, noise_um=0.0, stroke_mm=800.0, sweep_duration_min=0.0, temp_noise_K=0.0,
                   positions_mm=tuple(range(0, 801, 25)), nut_length_mm=0.0, **STILL_AIR)
    last = sim.err_time_s == sim.sweep_s[-1]
    P, E = sim.err_position_mm[last], sim.err_thermal_um[last]
    rise = sim.screw_C[-1] - sim.air_C[-1]
    assert np.ptp(rise) < 0.01 * rise.mean()
    assert np.all(np.diff(E) > 0)
    np.testing.assert_allclose(E, sim.params.alpha_um_mK * rise.mean() * P * 1e-3, rtol=0.01, atol=1e-9)


def test_error_is_zero_at_the_fixed_end_and_grows_during_warm_up():
    sim = simulate("v8000_r210_490", None, noise_um=0.0, **STILL_AIR)
    at0 = sim.err_position_mm == 0.0
    np.testing.assert_allclose(sim.err_thermal_um[at0], 0.0, atol=1e-12)
    far = sim.err_position_mm == 700.0
    E = sim.err_thermal_um[far]
    warm = sim.sweep_s <= 180 * 60
    assert np.all(np.diff(E[warm]) > -0.05)  # rises through the warm-up (small dips while stopped)
    assert np.all(np.diff(E[~warm]) < 0)  # and decays through the cool-down
    assert 15.0 < E.max() < 80.0  # the size reported for such axes


def test_structure_has_collinear_candidates_with_every_role():
    assert len(NODES) >= 11
    roles = {n.role for n in NODES}
    assert {"nut", "base", "ambient", "bearing", "motor", "structure"} <= roles
    sim = simulate("v8000_r0_700", None)
    # the heat-driven parts (reading minus the air sensor): the drifting air is a second, uncorrelated input
    air = [i for i, n in enumerate(NODES) if n.location.startswith("air 0.5 m")][0]
    T = sim.sensors_C - sim.sensors_C[:, [air]]
    heated = [i for i, n in enumerate(NODES) if n.role in ("nut", "bearing", "motor")]
    corr = np.corrcoef(T[:, heated].T)
    assert corr[np.triu_indices(len(heated), 1)].min() > 0.8
    # own time constants: the slow bed lags the nut (air held still to see the heat's response alone)
    T = simulate("v8000_r0_700", None, **STILL_AIR).sensors_C
    nut, base = T[:, 0] - T[0, 0], T[:, 1] - T[0, 1]
    def t63(y):
        return sim.t_s[np.argmax(y >= 0.63 * y[: int(180 * 60 / sim.params.dt_s)].max())]
    assert t63(base) > 2 * t63(nut)


def test_day24h_covers_a_day_with_the_air_falling_into_the_evening():
    # speed is measured by tools/bench_sim.py, not asserted here (shared CI machines)
    sim = simulate("day24h", ["bearing_heat", "moving_convection", "sensor_lag"])
    assert sim.t_s[-1] == 24 * 3600 and len(sim.sweep_s) == 24 * 4 + 1
    hour = 6.0 + sim.t_s / 3600.0
    peak = hour[np.argmax(sim.air_C)]
    assert 13.0 < peak < 17.0
    assert sim.air_C[hour >= 22.0].max() < sim.air_C.max() - 1.0


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="unknown parameter.*bogus"):
        make_params(bogus=1)
    with pytest.raises(ValueError, match="must cover the stroke"):
        make_params(screw_length_mm=600.0)
    with pytest.raises(ValueError, match="positions_mm"):
        make_params(positions_mm=(0, 750))
    with pytest.raises(ValueError, match="ambient_rise_min_K"):
        make_params(ambient_rise_min_K=3.0)
    with pytest.raises(ValueError, match="nut_length_mm"):
        make_params(nut_length_mm=-1.0)
    with pytest.raises(ValueError, match="unknown protocol"):
        simulate("v9000")
    with pytest.raises(ValueError, match="seed"):
        simulate("idle", seed=-1)
    with pytest.raises(ValueError, match="phase 1.*outside the stroke"):
        simulate(Protocol("bad", "", (Phase(10, 8000, 0, 900),)))


def test_energy_balance_of_the_screw():
    """Heat put in = heat stored + heat convected to the drifting air (trapezoid over each 10 s step).

    Volumes: half width at both ends; capacity rho*c*A*w, mantle h*pi*d*w, computed here from the parameters.
    """
    sim = simulate("mixed", {"bearing_heat": 5.0, "moving_convection": 1.0, "speed_dependent_heat": 0.6}, noise_um=0.0)
    p, dt = sim.params, sim.params.dt_s
    dx = p.screw_length_mm / p.segments * 1e-3
    w = np.full(p.segments + 1, dx)
    w[[0, -1]] = dx / 2
    area = math.pi * (p.screw_diameter_mm * 1e-3) ** 2 / 4
    C = p.density_kg_m3 * p.heat_capacity_J_kgK * area * w
    H = p.h_W_m2K * math.pi * p.screw_diameter_mm * 1e-3 * w
    rise = sim.screw_C - sim.air_C[:, None]
    heat_in = np.sum(sim.power_W["screw"]) * dt
    stored = np.sum(C * (sim.screw_C[-1] - sim.screw_C[0]))
    lost = np.sum(sim.conv_mult * dt * (0.5 * (rise[:-1] + rise[1:]) @ H))
    assert heat_in > 1e4 and abs(sim.air_C[-1] - sim.air_C[0]) > 1.0  # the air drifts: storage from both
    # the integrator sub-steps (air at each sub-step's mid-time), the trapezoid here uses the step edges:
    # agreement to 1e-4 of the heat put in (measured in docs/twin.md)
    assert abs(heat_in - stored - lost) < 1e-4 * heat_in
