"""The twin's own ball-screw heat model: finite volumes, Crank-Nicolson, absolute temperature.

This is a second, independent implementation of the screw physics the identified
model (host/learning/screw) also describes; it shares no code with it (tests/twin checks
that no host/twin module imports host.learning.screw). It differs on purpose in every
numerical choice and adds physics the model simplifies:

* grid: vertex-centred finite volumes, nodes at x_i = i*L/N (i = 0..N, both screw
  ends are nodes) with half volumes at the ends (the model uses cell-centred
  segments);
* time stepping: Crank-Nicolson (trapezoid) with sub-steps chosen so that no mode
  of the grid oscillates (h * lambda_max <= 2, Gershgorin bound on the stiffest
  mode) and h <= tau/50 (the model uses an exact exponential integrator);
* state: absolute temperature exchanging heat with the air T_air(t), linear
  within a step (the air enters every sub-step at its own mid-time);
* the nut: its friction heat is spread evenly over the nut length, integrated
  analytically along the nut's path (the model treats it as a point).

Equation of node i (volume width w_i, insulated screw ends):

    rho*c*A*w_i dT_i/dt = lambda*A/dx * sum_j (T_j - T_i) - g(t)*h*pi*d*w_i*(T_i - T_air) + Q_i(t)
"""

from __future__ import annotations

from typing import TYPE_CHECKING
import math

import numpy as np

if TYPE_CHECKING:
    from host.twin.axis import AxisParams


class ScrewGrid:
    """Nodes, volumes and conductances of the vertex-centred grid of an AxisParams."""

    def __init__(self, params: AxisParams) -> None:
        N = params.segments
        L = params.screw_length_mm
        self.n_nodes = N + 1
        self.dx_mm = L / N
        self.x_mm = np.linspace(0.0, L, N + 1)  # screw coordinate, fixed end at 0
        w = np.full(N + 1, self.dx_mm)
        w[0] = w[-1] = 0.5 * self.dx_mm
        self.width_mm = w
        area = math.pi * (params.screw_diameter_mm * 1e-3) ** 2 / 4.0
        rho_c = params.density_kg_m3 * params.heat_capacity_J_kgK
        self.capacity_J_K = rho_c * area * w * 1e-3
        self.link_W_K = params.conductivity_W_mK * area / (self.dx_mm * 1e-3)
        self.mantle_W_K = params.h_W_m2K * math.pi * params.screw_diameter_mm * 1e-3 * w * 1e-3
        # volume boundaries for the heat input: the outer ones at infinity, so nut heat
        # reaching past a screw end goes into the end volume and nothing is lost
        mid = 0.5 * (self.x_mm[1:] + self.x_mm[:-1])
        self.bounds_mm = np.concatenate([[-np.inf], mid, [np.inf]])

    def conduction(self) -> np.ndarray:
        """Conduction matrix K (W/K): (K T)_i = sum_j G (T_i - T_j); rows sum to 0 (insulated ends)."""
        n, G = self.n_nodes, self.link_W_K
        K = np.zeros((n, n))
        i = np.arange(n - 1)
        K[i, i + 1] = K[i + 1, i] = -G
        K[np.arange(n), np.arange(n)] = -K.sum(axis=1)
        return K


def _contact_antiderivative(u, nut_mm):
    """Psi(u) = integral of the nut's contact share psi(v) = clip(v/l + 1/2, 0, 1) from -inf to u.

    psi(b - p) is the share of a nut of length l centred at p that lies below b;
    nut_mm = 0 is a point contact (psi a step, Psi(u) = max(u, 0)).
    """
    if nut_mm <= 0:
        return np.maximum(u, 0.0)
    half = 0.5 * nut_mm
    with np.errstate(invalid="ignore"):
        inside = (u + half) ** 2 / (2.0 * nut_mm)
    return np.where(u <= -half, 0.0, np.where(u >= half, u, inside))


def _below(bounds, lo, hi, nut_mm):
    """Nut-centre travel (mm) over [lo, hi] weighted by the share of the nut below each bound."""
    b = bounds[None, :]
    with np.errstate(invalid="ignore"):
        full = _contact_antiderivative(b - lo[:, None], nut_mm) - _contact_antiderivative(b - hi[:, None], nut_mm)
    # at +inf both terms are inf: the whole travel lies below
    return np.where(np.isposinf(b), (hi - lo)[:, None], full)


def contact_travel(bounds_mm: np.ndarray, t_edges: np.ndarray, t_start: float, t_end: float, a_mm: float, b_mm: float, feed_mm_min: float, nut_mm: float) -> np.ndarray:
    """Nut travel (mm) credited to each volume in each step for one reciprocating interval: (n_steps, n_vol).

    The nut centre starts at a_mm at t_start, runs to b_mm and back at the feed
    until t_end (the motion.csv convention). Each mm of travel is shared among the
    volumes in proportion to the nut length inside them. Along a pass the share
    integrates in closed form (_contact_antiderivative), so the result is exact for
    any step and feed.
    """
    lo, hi = min(a_mm, b_mm), max(a_mm, b_mm)
    span = hi - lo
    n_vol = len(bounds_mm) - 1
    out = np.zeros((len(t_edges) - 1, n_vol))
    if span <= 0 or feed_mm_min <= 0 or t_end <= t_start:
        return out
    k0 = max(int(np.searchsorted(t_edges, t_start, side="right")) - 1, 0)
    k1 = min(int(np.searchsorted(t_edges, t_end, side="left")), len(t_edges) - 1)
    if k1 <= k0:
        return out
    t = np.clip(t_edges[k0:k1 + 1], t_start, t_end)
    s = (t - t_start) * feed_mm_min / 60.0  # distance run since the interval start
    legs = np.floor(s / span)
    r = s - legs * span
    up = (legs % 2 == 0) == (a_mm <= b_mm)  # the current leg runs towards +x
    start = np.where(up, lo, hi - r)
    end = np.where(up, lo + r, hi)
    per_leg = _below(bounds_mm, np.array([lo]), np.array([hi]), nut_mm)[0]
    cum = legs[:, None] * per_leg[None, :] + _below(bounds_mm, start, end, nut_mm)
    # travel inside volume j = travel below its upper bound - travel below its lower bound
    in_volume = np.diff(cum, axis=1)
    out[k0:k1] = np.diff(in_volume, axis=0)
    return out


MAX_SUBSTEPS = 100000  # Crank-Nicolson sub-steps in one step: beyond, the step map takes minutes to build


class ScrewIntegrator:
    """Crank-Nicolson stepping of the grid, with the step maps cached per convection multiplier."""

    def __init__(self, grid: ScrewGrid, dt_s: float, tau_s: float) -> None:
        self.grid = grid
        self.dt = float(dt_s)
        self.K = grid.conduction()
        self._maps = {}
        self.tau_s = tau_s

    def substeps(self, g: float) -> int:
        """Sub-steps per step: h*lambda_max <= 2 (monotone CN, Gershgorin bound) and h <= tau/50."""
        C, H = self.grid.capacity_J_K, self.grid.mantle_W_K
        lam = np.max((np.abs(self.K).sum(axis=1) + g * H) / C)
        with np.errstate(all="ignore"):  # a time constant that underflowed to 0 gives inf, refused below
            need = max(self.dt * lam / 2.0, np.float64(50.0 * self.dt * g) / np.float64(self.tau_s))
        if not need <= MAX_SUBSTEPS:  # also NaN/inf: parameters far outside a real screw (h_W_m2K=1e308)
            raise ValueError("the screw's fastest thermal mode (%.3g 1/s) needs %.3g sub-steps per %g s step, more than "
                             "%d: a parameter is far outside a real axis (h_W_m2K, conductivity_W_mK, density_kg_m3, "
                             "heat_capacity_J_kgK, segments, sensor time constants)" % (lam, need, self.dt, MAX_SUBSTEPS))
        return max(1, int(math.ceil(self.dt * lam / 2.0 - 1e-12)), int(math.ceil(50.0 * self.dt / (self.tau_s / g))))

    def maps(self, g: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(P, Q, A0, A1) with T(k+1) = P T(k) + Q power(k) + A0 T_air(k) + A1 T_air(k+1) for one whole step."""
        hit = self._maps.get(g)
        if hit is not None:
            return hit
        n_sub = self.substeps(g)
        h = self.dt / n_sub
        C, gH = self.grid.capacity_J_K, g * self.grid.mantle_W_K
        Kg = self.K + np.diag(gH)
        left = np.diag(C / h) + 0.5 * Kg
        right = np.diag(C / h) - 0.5 * Kg
        S = np.linalg.inv(left)
        Psub = S @ right
        n = len(C)
        P, Q = np.eye(n), np.zeros((n, n))
        A0, A1 = np.zeros(n), np.zeros(n)
        for j in range(n_sub):
            # each sub-step sees the air at its mid-time, linear between the step's edges
            frac = (j + 0.5) / n_sub
            P, Q = Psub @ P, Psub @ Q + S
            A0, A1 = Psub @ A0 + (1 - frac) * (S @ gH), Psub @ A1 + frac * (S @ gH)
        self._maps[g] = hit = (P, Q, A0, A1)
        return hit

    def run(self, air_edges_C: np.ndarray, power_W: np.ndarray, conv_mult: np.ndarray) -> np.ndarray:
        """Node temperatures (n_steps + 1, n_nodes), starting uniform at the air's first value.

        power_W: (n_steps, n_nodes) heat input held over each step; conv_mult:
        (n_steps,) convection multiplier g(t) of each step.
        """
        air = np.asarray(air_edges_C, dtype=float)
        n = len(air) - 1
        T = np.empty((n + 1, self.grid.n_nodes))
        T[0] = air[0]
        force = np.empty((n, self.grid.n_nodes))
        props = []
        for g in np.unique(conv_mult):
            rows = np.flatnonzero(conv_mult == g)
            P, Q, A0, A1 = self.maps(float(g))
            force[rows] = power_W[rows] @ Q.T + air[rows, None] * A0 + air[rows + 1, None] * A1
            props.append((rows, P))
        which = np.empty(n, dtype=np.intp)
        for i, (rows, _) in enumerate(props):
            which[rows] = i
        mats = [P for _, P in props]
        for k in range(n):
            T[k + 1] = mats[which[k]] @ T[k] + force[k]
        return T


def expansion_um(x_mm: np.ndarray, T_C: np.ndarray, T0_C: float | np.ndarray, positions_mm: np.ndarray, alpha_um_mK: float) -> np.ndarray:
    """alpha * integral_0^x (T - T0) dx at each position, with T linear between nodes: (n_times, n_pos).

    x_mm: node coordinates; T_C: (n_times, n_nodes); positions in screw coordinate.
    """
    d = np.atleast_2d(T_C) - T0_C
    dx = np.diff(x_mm)
    cum = np.concatenate([np.zeros((d.shape[0], 1)), np.cumsum(0.5 * (d[:, 1:] + d[:, :-1]) * dx, axis=1)], axis=1)
    pos = np.clip(np.asarray(positions_mm, dtype=float), x_mm[0], x_mm[-1])
    i = np.clip(np.searchsorted(x_mm, pos, side="right") - 1, 0, len(x_mm) - 2)
    u = pos - x_mm[i]
    slope = (d[:, i + 1] - d[:, i]) / dx[i]
    integral_K_mm = cum[:, i] + u * d[:, i] + 0.5 * u * u * slope
    return alpha_um_mK * integral_K_mm * 1e-3
