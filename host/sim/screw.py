"""Ball-screw segment heat transfer used by the twin while host/screw/heat.py is absent.

Model (per segment i of M, heat capacity C, axial conductance G, convective
conductance H at rest, air temperature T_f):

    C dT_i/dt = q_i(t) - G (2 T_i - T_{i-1} - T_{i+1}) - H k(t) (T_i - T_f(t))

with insulated screw ends (missing neighbours drop out), q_i the friction
(and bearing) power deposited in the segment and k(t) a convection multiplier.
Convection is uniform along the screw, so the conduction and convection
operators commute and the step is exact for inputs held constant over a step:
in the eigenbasis of the conduction matrix every mode j decays as
exp(-(mu_j + H k / C) dt) (exponential integrator, unconditionally stable for
any dt).
"""
import numpy as np


def conduction_modes(params):
    """Eigen-decomposition (mu, V) of G/C * Laplacian with insulated ends."""
    M = params.segments
    lap = np.zeros((M, M))
    i = np.arange(M - 1)
    lap[i, i] += 1.0
    lap[i + 1, i + 1] += 1.0
    lap[i, i + 1] -= 1.0
    lap[i + 1, i] -= 1.0
    mu, V = np.linalg.eigh(lap * (params.conductance_W_K / params.segment_heat_capacity_J_K))
    return np.clip(mu, 0.0, None), V


def step_overlaps(t_edges, t_start, t_end):
    """Seconds of each interval (columns) inside each step (rows)."""
    a = np.maximum(t_edges[:-1, None], t_start[None, :])
    b = np.minimum(t_edges[1:, None], t_end[None, :])
    return np.clip(b - a, 0.0, None)


def range_fractions(edges_x_mm, lo_x, hi_x):
    """Share of each range [lo, hi] (rows) lying inside each segment (columns)."""
    a = np.maximum(edges_x_mm[None, :-1], lo_x[:, None])
    b = np.minimum(edges_x_mm[None, 1:], hi_x[:, None])
    return np.clip(b - a, 0.0, None) / (hi_x - lo_x)[:, None]


def nut_travel_per_segment(motion, t_edges, params, weights=None):
    """mm travelled by the nut inside each segment during each step, (n_steps, M).

    ``motion`` rows are t_start, t_end, from_mm, to_mm, feed_mm_min. The nut
    reciprocates much faster than the screw's thermal time constants, so its
    travel in a step is spread over the range in proportion to overlap.
    ``weights`` (per interval) scales each interval's travel, e.g. to turn mm
    into joules with a feed-dependent friction energy per mm.
    """
    M = params.segments
    if len(motion) == 0:
        return np.zeros((len(t_edges) - 1, M))
    t0, t1, p0, p1, feed = (motion[:, j] for j in range(5))
    over = step_overlaps(t_edges, t0, t1)  # (n, k)
    lo = np.minimum(p0, p1) - params.fixed_end_mm
    hi = np.maximum(p0, p1) - params.fixed_end_mm
    frac = range_fractions(np.asarray(params.edges_mm), lo, hi)  # (k, M)
    per_interval = over * (feed / 60.0)[None, :]
    if weights is not None:
        per_interval = per_interval * np.asarray(weights, dtype=float)[None, :]
    return per_interval @ frac


def simulate_segments(T0, heat_J, conv_mult, T_air, dt, params):
    """Segment temperatures (n_steps + 1, M) in degC at the step edges.

    heat_J (n_steps, M): energy into each segment during each step;
    conv_mult (n_steps,): convection multiplier k; T_air (n_steps,): air
    temperature held over each step.
    """
    heat_J = np.asarray(heat_J, dtype=float)
    n, M = heat_J.shape
    C = params.segment_heat_capacity_J_K
    mu, V = conduction_modes(params)
    gamma = params.convection_W_K * np.asarray(conv_mult, dtype=float) / C  # (n,)
    rate = mu[None, :] + gamma[:, None]  # (n, M)
    decay = np.exp(-rate * dt)
    # exact ZOH gain (1 - e^{-r dt}) / r, with its limit dt for r -> 0
    gain = np.where(rate * dt > 1e-12, -np.expm1(-rate * dt) / np.where(rate > 0, rate, 1.0), dt)
    ones_modal = V.sum(axis=0)  # V^T 1
    forcing = (heat_J / dt / C) @ V + (gamma * np.asarray(T_air, dtype=float))[:, None] * ones_modal[None, :]
    drive = gain * forcing
    z = np.empty((n + 1, M))
    z[0] = np.asarray(T0, dtype=float) @ V
    for k in range(n):
        z[k + 1] = decay[k] * z[k] + drive[k]
    return z @ V.T


def thermal_error_um(T, T_air, positions_mm, params):
    """alpha * integral of (T - T_air) from the fixed end to each position, um.

    T (..., M), T_air (...) -> (..., len(positions)); partial segments pro rata.
    """
    T = np.asarray(T, dtype=float)
    theta = T - np.asarray(T_air, dtype=float)[..., None]
    edges = np.asarray(params.edges_mm)
    x = np.asarray(positions_mm, dtype=float) - params.fixed_end_mm
    seg = params.segment_mm
    cum = np.concatenate([np.zeros(theta.shape[:-1] + (1,)), np.cumsum(theta * seg, axis=-1)], axis=-1)  # K*mm at edges
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, params.segments - 1)
    part = x - edges[idx]
    integral = cum[..., idx] + theta[..., idx] * part  # K*mm
    return params.alpha_um_mK * integral * 1e-3
