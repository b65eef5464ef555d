"""Vectorised physics core of the ball-screw segment model (shared with the digital twin).

The screw is a steel rod of length ``length_mm`` and diameter ``diameter_mm``,
fixed (axially located) at screw coordinate x = 0, free to grow towards +x.
Axis positions P map to screw coordinates by ``x = P - fixed_end_mm``.  It is cut
into M segments (``edges_mm``, M+1 ascending edges, ``edges_mm[0] = 0``).

State: T_i, the temperature of segment i over a FIXED reference temperature [K]
(the caller's choice: the air at the start of the run, or a calibration
temperature).  Energy balance of segment i (capacity C_i = c·ρ·V_i)::

    C_i dT_i/dt = q·u_i/dt                               friction heat of the nut
                  - Σ_j G_ij (T_i - T_j)                 axial conduction, G = λ·A/Δx
                  - g·h·S_i·(T_i - a(t))                 convection to the air, S_i = π·d·L_i
                  + p_i                                  extra source (bearing, ...)

a(t) is the air temperature over the same reference (``air_K``; None = the air
stays at the reference, which is the old "rise over a still air" model).  When
the air warms at a rate r the screw follows it with a lag r·τ, τ = c·ρ·d/(4h) for a
solid screw far from the nut.

q [J/mm] is the friction heat released per mm of nut travel; the heat of one nut
pass over a segment of length L is Q = q·L (so Q depends on the segmentation, q
does not, which is why q is the stored parameter).  u_i is the travel of the nut
inside segment i during the step [mm], g the convection multiplier of the step
(1 = still air, >1 = the ``moving_convection`` effect).

Time integration (``simulate_segments``): exact exponential integrator for a
zero-order-hold input.  Over a step of length dt with constant power the linear
system T' = K·T + C⁻¹p is solved exactly::

    T[k+1] = e^{K dt} T[k] + K⁻¹(e^{K dt} - I) C⁻¹ p[k]

The air enters as a first-order hold: a(t) linear between the grid values
a[k] and a[k+1], which the scheme integrates exactly.  Per mode (decay rate λ,
x = λ·dt) the weights of a[k] and a[k+1] on the convection power g·h·S are::

    Γ1 = ∫_0^dt e^{-λ(dt-s)} s/dt ds = dt·(x - 1 + e^{-x})/x²     (the K⁻² term)
    Γ0 = ∫_0^dt e^{-λ(dt-s)} ds - Γ1 = (1 - e^{-x})/λ - Γ1         (the K⁻¹ term)

(Γ1 → dt/2 as λ → 0, evaluated by its series there).  Γ0, Γ1 ≥ 0 and, for
uniform air and no heat, A·1 + (Γ0 + Γ1)-weights·1 = 1 exactly: a screw in
equilibrium with a still air stays there.

computed through the symmetric form C^{-1/2}(G + g·H)C^{-1/2} = U diag(s) Uᵀ (eigh),
so e^{K dt} = C^{-1/2} U diag(e^{-s dt}) Uᵀ C^{1/2}.  Every eigenvalue factor
e^{-s dt} lies in (0, 1], so the scheme is unconditionally stable and exact for any
dt, including the very long steps of a cool-down.  With one step length and one
multiplier the recurrence runs in the modal basis (z = e·z + w per mode, as a
blocked scan: batched matmuls inside blocks of 64 steps, a Python loop only over
blocks); otherwise propagators are cached per distinct (dt, g) and each step is one
M×M mat-vec.  There is never a Python loop over segments.

Thermal error (``thermal_error_um``): E_m(P) = α·Σ_i T_i·overlap_i(P), overlap_i(P)
the length of segment i inside [0, x(P)] (a partial segment counts pro rata;
E_m = 0 at the fixed end).

Units: mm for lengths in the API, SI inside; α in 1/K; errors in µm.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import get_lapack_funcs

if TYPE_CHECKING:
    from host.data.runs import Motion

MIN_RANGE_MM = 1e-6  # an interval whose range is shorter than this is a dwell: no travel, no friction heat
STEEL = {"density_kg_m3": 7850.0, "c_J_kgK": 460.0, "lambda_W_mK": 46.0, "alpha_per_K": 11.5e-6}
# The values a ball screw's steel can have (room temperature, the steels screws are made of: carbon steels such as
# C45/Cf53 ~50, low-alloy 42CrMo4 ~42, bearing steel 100Cr6 ~40-46, martensitic stainless X46Cr13 ~25-30 W/(m K);
# their expansion 10.5-12.5e-6 /K, specific heat 440-490 J/(kg K)), with a margin. An identified value outside is
# not the screw's material: the parameter is absorbing another effect (docs/screw-model.md, "Plausibility").
STEEL_RANGES = {"lambda_W_mK": (20.0, 60.0), "alpha_per_K": (10.0e-6, 13.0e-6), "c_J_kgK": (420.0, 500.0)}


@dataclass(frozen=True)
class ScrewGeometry:
    """Screw shape and segmentation.

    length_mm: thread length from the fixed end; diameter_mm: (root) diameter;
    fixed_end_mm: axis position of the fixed end (x = P - fixed_end_mm);
    segments: M; bore_mm: bore of a hollow (cooled) screw, 0 for solid.
    """

    length_mm: float
    diameter_mm: float
    fixed_end_mm: float = 0.0
    segments: int = 40
    bore_mm: float = 0.0

    def __post_init__(self) -> None:
        if not self.length_mm > 0:
            raise ValueError("screw length_mm must be positive (found %r)" % (self.length_mm,))
        if not self.diameter_mm > 0:
            raise ValueError("screw diameter_mm must be positive (found %r)" % (self.diameter_mm,))
        if not 0 <= self.bore_mm < self.diameter_mm:
            raise ValueError("screw bore_mm must be in [0, diameter_mm) (found %r)" % (self.bore_mm,))
        if int(self.segments) != self.segments or self.segments < 1:
            raise ValueError("segments must be a positive integer (found %r)" % (self.segments,))

    @property
    def edges_mm(self) -> np.ndarray:
        return np.linspace(0.0, self.length_mm, int(self.segments) + 1)

    @property
    def section_m2(self) -> float:
        return np.pi / 4.0 * ((self.diameter_mm * 1e-3) ** 2 - (self.bore_mm * 1e-3) ** 2)

    def with_segments(self, m: int) -> ScrewGeometry:
        return replace(self, segments=int(m))

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], segments: int = 40) -> ScrewGeometry:
        """From a run's meta.json ``screw`` block (length_mm, diameter_mm, fixed_end_mm, bore_mm)."""
        s = meta.get("screw") if isinstance(meta, dict) else None
        if not isinstance(s, dict):
            raise ValueError("meta.json has no 'screw' block (length_mm, diameter_mm, lead_mm, fixed_end_mm)")
        return cls(float(s["length_mm"]), float(s["diameter_mm"]), float(s.get("fixed_end_mm", 0.0)), int(segments), float(s.get("bore_mm", 0.0)))


@dataclass(frozen=True)
class ScrewParams:
    """Thermal parameters.

    q_J_per_mm: friction heat per mm of nut travel (Q per pass over a segment of
    length L is q·L); c_J_kgK specific heat; density_kg_m3; lambda_W_mK axial
    conductivity; h_W_m2K convection coefficient; alpha_per_K expansion coefficient.
    """

    q_J_per_mm: float = 0.05
    c_J_kgK: float = STEEL["c_J_kgK"]
    density_kg_m3: float = STEEL["density_kg_m3"]
    lambda_W_mK: float = STEEL["lambda_W_mK"]
    h_W_m2K: float = 15.0
    alpha_per_K: float = STEEL["alpha_per_K"]

    def Q_per_pass_J(self, segment_mm: float) -> float:
        """Heat of one nut pass over a segment of ``segment_mm``."""
        return self.q_J_per_mm * segment_mm

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], **overrides: Any) -> ScrewParams:
        """Material defaults (steel) overridden by optional meta.json ``screw`` keys
        density_kg_m3, c_J_kgK, lambda_W_mK, h_W_m2K, alpha_per_K (or alpha_um_per_m_K)."""
        s = (meta or {}).get("screw") or {}
        kw = {}
        for k in ("density_kg_m3", "c_J_kgK", "lambda_W_mK", "h_W_m2K", "alpha_per_K", "q_J_per_mm"):
            if isinstance(s.get(k), (int, float)):
                kw[k] = float(s[k])
        if "alpha_per_K" not in kw and isinstance(s.get("alpha_um_per_m_K"), (int, float)):
            kw["alpha_per_K"] = float(s["alpha_um_per_m_K"]) * 1e-6
        kw.update(overrides)
        return cls(**kw)


# ------------------------------------------------------------------ geometry helpers


def segment_properties(edges_mm: ArrayLike, diameter_mm: float, params: ScrewParams, bore_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C [J/K] per segment, G [W/K] per interface (M-1), H [W/K] = h·S per segment)."""
    edges = np.asarray(edges_mm, dtype=float) * 1e-3
    L = np.diff(edges)
    d, b = diameter_mm * 1e-3, bore_mm * 1e-3
    area = np.pi / 4.0 * (d * d - b * b)
    C = params.c_J_kgK * params.density_kg_m3 * area * L
    centres = 0.5 * (edges[1:] + edges[:-1])
    G = params.lambda_W_mK * area / np.diff(centres)
    H = params.h_W_m2K * np.pi * d * L
    return C, G, H


def overlap_mm(edges_mm: ArrayLike, x_mm: ArrayLike) -> np.ndarray:
    """Length of each segment inside [0, x]: shape x.shape + (M,)."""
    edges = np.asarray(edges_mm, dtype=float)
    x = np.asarray(x_mm, dtype=float)[..., None]
    return np.clip(x - edges[:-1], 0.0, np.diff(edges))


def interp_rows(t: ArrayLike, t_grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of ``values`` (len(t_grid), ...) at times t
    (clamped to the grid's ends): (len(t), ...)."""
    t = np.asarray(t, dtype=float)
    tg = np.asarray(t_grid, dtype=float)
    k = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, max(tg.size - 2, 0))
    if tg.size == 1:
        return np.repeat(values[:1], t.size, axis=0)
    w = np.clip((t - tg[k]) / (tg[k + 1] - tg[k]), 0.0, 1.0).reshape((-1,) + (1,) * (values.ndim - 1))
    return values[k] * (1.0 - w) + values[k + 1] * w


def thermal_error_um(edges_mm: ArrayLike, rises: np.ndarray, positions_mm: ArrayLike, fixed_end_mm: float, alpha: float) -> np.ndarray:
    """E_m in µm: α·Σ_i T_i·overlap_i(P).

    rises: (..., M) segment rises [K]; positions_mm broadcastable to rises.shape[:-1]
    (pass rises[:, None, :] and positions[None, :] for a time × position grid).
    """
    rises = np.asarray(rises, dtype=float)
    ov = overlap_mm(edges_mm, np.asarray(positions_mm, dtype=float) - fixed_end_mm)
    return 1e3 * alpha * np.sum(rises * ov, axis=-1)


# ------------------------------------------------------------------ nut travel


def _leg_overlap(p0, direction, r, lo, hi):
    """Overlap of the swept interval [p0, p0 + direction·r] with each [lo, hi]."""
    a = np.minimum(p0, p0 + direction * r)[..., None]
    b = np.maximum(p0, p0 + direction * r)[..., None]
    return np.clip(np.minimum(b, hi) - np.maximum(a, lo), 0.0, None)


def _cumulative_travel(s, start, end, lo, hi):
    """Travel inside each segment [lo, hi] after distance s along a reciprocation start->end->start...

    s: (k,) distances; returns (k, M)."""
    span = abs(end - start)
    if span <= MIN_RANGE_MM:
        return np.zeros((s.size, lo.size))
    full_cov = np.clip(np.minimum(max(start, end), hi) - np.maximum(min(start, end), lo), 0.0, None)
    legs = np.floor(s / span)
    r = s - legs * span
    odd = (legs % 2) == 1
    direction = np.where(odd, -1.0, 1.0) * np.sign(end - start)
    p0 = np.where(odd, end, start)
    return legs[:, None] * full_cov[None, :] + _leg_overlap(p0, direction, r, lo, hi)


def nut_travel_per_segment(motion: Motion | None, edges_mm: ArrayLike, fixed_end_mm: float, t_grid: np.ndarray, spread: bool = False) -> np.ndarray:
    """Travel of the nut inside each segment during each step [mm]: (n_steps, M).

    motion: host.data.runs.Motion, or None for a run without motion (no travel) (or any object with t_start_s, t_end_s, from_mm, to_mm,
    feed_mm_min arrays): during each interval the nut reciprocates from from_mm to
    to_mm and back at feed_mm_min, starting at from_mm.  t_grid: (n_steps+1,)
    ascending times.  Exact by default (the loop runs over motion intervals,
    vectorised over steps and segments); ``spread=True`` spreads feed·time over the
    range in proportion to overlap instead (the firmware's feed/range-state input,
    docs/model-format.md), one matrix product for all intervals."""
    t = np.asarray(t_grid, dtype=float)
    edges = np.asarray(edges_mm, dtype=float) + fixed_end_mm  # axis coordinates
    lo, hi = edges[:-1], edges[1:]
    if spread:
        if motion is None or len(motion.t_start_s) == 0:
            return np.zeros((t.size - 1, lo.size))
        ts, te = np.asarray(motion.t_start_s, float), np.asarray(motion.t_end_s, float)
        a = np.minimum(motion.from_mm, motion.to_mm)
        b = np.maximum(motion.from_mm, motion.to_mm)
        span = b - a
        frac = np.clip(np.minimum(b[:, None], hi[None, :]) - np.maximum(a[:, None], lo[None, :]), 0.0, None)
        frac = np.divide(frac, span[:, None], out=np.zeros_like(frac), where=span[:, None] > MIN_RANGE_MM)
        moved = np.clip(t[:, None] - ts[None, :], 0.0, (te - ts)[None, :]) * (np.asarray(motion.feed_mm_min, float) / 60.0)[None, :]
        return np.diff(moved @ frac, axis=0)
    cum = np.zeros((t.size, lo.size))
    if motion is not None:
        for ts, te, a, b, f in zip(motion.t_start_s, motion.t_end_s, motion.from_mm, motion.to_mm, motion.feed_mm_min):
            i0 = np.searchsorted(t, ts, side="right")
            i1 = np.searchsorted(t, te, side="left")
            v = f / 60.0
            if i1 > i0:
                cum[i0:i1] += _cumulative_travel((t[i0:i1] - ts) * v, a, b, lo, hi)
            if i1 < t.size:
                cum[i1:] += _cumulative_travel(np.array([(te - ts) * v]), a, b, lo, hi)
    return np.diff(cum, axis=0)


def friction_heat_J(travel_mm: ArrayLike, params: ScrewParams) -> np.ndarray:
    """Friction heat delivered into each segment during each step [J]: q·u."""
    return params.q_J_per_mm * np.asarray(travel_mm, dtype=float)


# ------------------------------------------------------------------ integration


def hold_weights(s: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Modal integrals over a step of length dt for decay rates s [1/s] (array).

    Returns (phi, gamma0, gamma1): phi = ∫_0^dt e^{-s(dt-τ)} dτ (zero-order hold of a
    constant input), gamma1 = ∫_0^dt e^{-s(dt-τ)} τ/dt dτ (weight of the input's value
    at the step's end under a first-order hold) and gamma0 = phi - gamma1 (weight of
    its value at the step's start)."""
    s = np.asarray(s, dtype=float)
    x = s * dt
    small = x < 1e-4
    safe = np.where(small, 1.0, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(x > 1e-12, -np.expm1(-safe) / safe, 1.0 - x / 2.0) * dt
        # (x - 1 + e^{-x}) / x²: cancels for small x, so its series there (error < x³/720)
        g1 = np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (safe + np.expm1(-safe)) / (safe * safe)) * dt
    return phi, phi - g1, g1


(_DSTEVD,) = get_lapack_funcs(("stevd",), (np.zeros(1),))  # float64 dstevd


def _tridiagonal_eigh(d: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors of the symmetric tridiagonal matrix (diagonal d,
    off-diagonal e): LAPACK's dstevd, the driver scipy.linalg.eigh_tridiagonal chooses for all
    eigenpairs, called directly (the same numbers; its argument checks cost more than the solve for
    the 12-40 segments here, and a screw fit solves tens of thousands)."""
    d = np.ascontiguousarray(d, dtype=float)
    e = np.ascontiguousarray(e, dtype=float)
    if not (np.isfinite(d).all() and np.isfinite(e).all()):
        raise ValueError("array must not contain infs or NaNs")
    s, U, info = _DSTEVD(d, e, compute_v=1)
    if info != 0:
        raise np.linalg.LinAlgError("dstevd (the segment modes) failed: info %d" % info)
    return s, U


def _gkey(g: Any) -> float | bytes:
    """A convection multiplier (scalar, or one per segment) as a cache key: its exact value, so a cached
    matrix is the one these very numbers give, whichever call computed it first (shared_propagator)."""
    return float(g) if np.ndim(g) == 0 else np.ascontiguousarray(g, dtype=float).tobytes()


class Propagator:
    """Exact step matrices of the segment system for given properties.

    ``step(dt, g)`` -> (A, Bp): T[k+1] = A·T[k] + Bp·p[k] with p the (constant) power
    [W] per segment during the step and g the convection multiplier;
    ``air_step(dt, g)`` -> (c0, c1): the air's contribution c0·a[k] + c1·a[k+1] (air
    linear within the step)."""

    def __init__(self, C: ArrayLike, G: ArrayLike, H: ArrayLike) -> None:
        self.C = np.asarray(C, dtype=float)
        self.G = np.asarray(G, dtype=float)
        self.H = np.asarray(H, dtype=float)
        self._rs = 1.0 / np.sqrt(self.C)
        self._s = np.sqrt(self.C)
        self._cache = {}

    def symmetric(self, g: float = 1.0) -> np.ndarray:
        M = self.C.size
        L = np.zeros((M, M))
        if M > 1:
            i = np.arange(M - 1)
            L[i, i + 1] = L[i + 1, i] = -self.G
            L[np.arange(M), np.arange(M)] = np.r_[self.G, 0.0] + np.r_[0.0, self.G]
        L[np.diag_indices(M)] += np.asarray(g, dtype=float) * self.H
        return self._rs[:, None] * L * self._rs[None, :]

    def modes(self, g: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Decay rates s [1/s] (ascending) and orthonormal modes U of the symmetric system.

        The system is tridiagonal, so LAPACK's tridiagonal solver is used (O(M²),
        single-threaded: a dense eigh is slower and fights over BLAS threads)."""
        key = ("modes", _gkey(g))
        if key not in self._cache:
            M = self.C.size
            deg = np.zeros(M)
            if M > 1:
                deg[:-1] += self.G
                deg[1:] += self.G
            d = (deg + np.asarray(g, dtype=float) * self.H) * self._rs ** 2
            if M == 1:
                s, U = d.copy(), np.ones((1, 1))
            else:
                e = -self.G * self._rs[:-1] * self._rs[1:]
                s, U = _tridiagonal_eigh(d, e)
            self._cache[key] = (np.clip(s, 0.0, None), U)
        return self._cache[key]

    def step(self, dt: float, g: float = 1.0) -> Any:
        key = (round(float(dt), 9), _gkey(g))
        if key not in self._cache:
            s, U = self.modes(g)
            e = np.exp(-s * dt)
            with np.errstate(divide="ignore", invalid="ignore"):
                phi = np.where(s * dt > 1e-12, -np.expm1(-s * dt) / np.where(s > 0, s, 1.0), dt)
            A = (self._rs[:, None] * (U * e) @ U.T) * self._s[None, :]
            Bp = (self._rs[:, None] * (U * phi) @ U.T) * self._rs[None, :]
            self._cache[key] = (A, Bp)
        return self._cache[key]

    def air_step(self, dt: float, g: float = 1.0) -> Any:
        key = ("air", round(float(dt), 9), _gkey(g))
        if key not in self._cache:
            s, U = self.modes(g)
            _, g0, g1 = hold_weights(s, dt)
            v = (np.broadcast_to(np.asarray(g, dtype=float), self.H.shape) * self.H * self._rs) @ U  # g·h·S in the modal basis
            self._cache[key] = (self._rs * (U @ (g0 * v)), self._rs * (U @ (g1 * v)))
        return self._cache[key]


# Propagators shared across simulate_segments calls: a screw fit simulates the same segment properties
# (C, G, H) over and over (its Jacobian perturbs one parameter at a time, and most do not touch them;
# every fold of a discrepancy analysis starts from the same values), each time building the same modes and
# step matrices. Keyed by the exact bytes of C, G and H, so a hit is the very propagator a fresh build gives.
# Bounded: the least recently used propagator goes past _SHARED_KEPT, and one whose cache outgrows
# _ENTRIES_KEPT matrices (a continuous convection multiplier gives a new key per value) starts over.
_SHARED: dict[tuple[bytes, bytes, bytes], Propagator] = {}
_SHARED_KEPT = 16
_ENTRIES_KEPT = 256


def shared_propagator(C: np.ndarray, G: np.ndarray, H: np.ndarray) -> Propagator:
    """The Propagator of (C, G, H), built once and kept for later calls with the same properties."""
    C, G, H = (np.ascontiguousarray(a, dtype=float) for a in (C, G, H))
    key = (C.tobytes(), G.tobytes(), H.tobytes())
    prop = _SHARED.pop(key, None)
    if prop is None:
        prop = Propagator(C, G, H)
        while len(_SHARED) >= _SHARED_KEPT:
            _SHARED.pop(next(iter(_SHARED)), None)
    elif len(prop._cache) > _ENTRIES_KEPT:
        prop._cache.clear()
    _SHARED[key] = prop  # (re)inserted last: the dict's order is the use order
    return prop


def rows_matmul(X: np.ndarray, A: np.ndarray, rows: int | None = None) -> np.ndarray:
    """X @ A for a tall X, computed in row blocks (default: about 2·10⁵ multiply-adds each).

    Each block product stays under OpenBLAS's threading threshold, so no BLAS
    threads are started: for these thin products they gain nothing, and on a busy
    machine their spinning cost 20x (measured: 2880x40 @ 40x40 17-20 ms threaded
    vs 0.8 ms blocked at load average 8)."""
    n, k = X.shape
    if rows is None:
        rows = max(8, 200000 // max(1, k * A.shape[1]))
    if n <= rows:
        return X @ A
    nb = -(-n // rows)
    Xp = np.zeros((nb * rows, k))
    Xp[:n] = X
    return (Xp.reshape(nb, rows, k) @ A).reshape(nb * rows, A.shape[1])[:n]


def modal_scan(e: np.ndarray, W: np.ndarray, z0: np.ndarray, block: int = 64) -> np.ndarray:
    """z[k+1] = e∘z[k] + W[k] for k < n, returned as (n, M) = z[1..n].

    Blocked scan: inside a block of B steps the response is a product with the
    lower-triangular Toeplitz kernel e^(a-b) (one batched matmul for all blocks and
    modes); only the carry between blocks loops in Python (n/B iterations).
    0 < e ≤ 1, so the powers never overflow."""
    n, M = W.shape
    if n == 0:
        return np.empty((0, M))
    B = min(block, n)
    nb = -(-n // B)
    Wp = np.zeros((nb * B, M))
    Wp[:n] = W
    lag = np.arange(B)[:, None] - np.arange(B)[None, :]
    with np.errstate(under="ignore"):
        # the kernel holds only B distinct powers per mode: take them once and index (M·B powers, not M·B²; the
        # same values, so the same result, at a sixth of the scan's time for 12 modes)
        powers = np.concatenate([e[:, None] ** np.arange(B)[None, :], np.zeros((M, 1))], axis=1)  # (M, B+1), last = 0
        K = powers[:, np.where(lag >= 0, lag, B)]  # (M, B, B): e^(a-b) on and below the diagonal, 0 above
        Wt = Wp.reshape(nb, B, M).transpose(2, 1, 0)
        # zero-start response (M, B, nb), in column chunks that stay single-threaded in BLAS
        local = np.concatenate([np.matmul(K, Wt[:, :, j:j + 48]) for j in range(0, nb, 48)], axis=2)
        grow = e[:, None] ** np.arange(1, B + 1)[None, :]  # (M, B): e^(a+1)
    carry = np.empty((nb, M))
    c = np.asarray(z0, dtype=float)
    eB = grow[:, -1]
    for j in range(nb):
        carry[j] = c
        c = eB * c + local[:, -1, j]
    Z = local.transpose(2, 1, 0) + grow.T[None, :, :] * carry[:, None, :]  # (nb, B, M)
    return Z.reshape(nb * B, M)[:n]


def simulate_segments(geometry: ScrewGeometry, params: ScrewParams, t_grid: np.ndarray, heat_J: np.ndarray | None = None, convection_mult: np.ndarray | None = None, source_W: np.ndarray | None = None, T0: np.ndarray | None = None, edges_mm: np.ndarray | None = None, air_K: np.ndarray | None = None) -> np.ndarray:
    """Integrate the segment temperatures over ``t_grid``; returns (n_steps+1, M) in K
    over the reference temperature.

    heat_J: (n_steps, M) heat delivered into each segment during each step [J]
      (e.g. ``friction_heat_J(nut_travel_per_segment(...), params)``); None = none.
    convection_mult: None, a scalar, (n_steps,) per step, or (n_steps, M) per step
      and segment: multiplies h·S (the moving_convection effect).
    source_W: None, (M,) constant or (n_steps, M) extra power [W] (bearing heat
      into segment 0, ...).
    T0: (M,) initial temperatures (default: in equilibrium with the air, a[0]; 0
      without air).
    edges_mm: segment edges (default the geometry's uniform segmentation).
    air_K: None or (n_steps+1,) air temperature over the reference at the grid
      times, linear in between.
    Exact for piecewise-constant power and multiplier and piecewise-linear air (see
    module doc)."""
    t = np.asarray(t_grid, dtype=float)
    edges = geometry.edges_mm if edges_mm is None else np.asarray(edges_mm, dtype=float)
    M = edges.size - 1
    n = t.size - 1
    if n < 0:
        raise ValueError("t_grid is empty")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError("t_grid must be strictly ascending")
    C, G, H = segment_properties(edges, geometry.diameter_mm, params, geometry.bore_mm)
    power = np.zeros((n, M))
    if heat_J is not None:
        heat_J = np.asarray(heat_J, dtype=float)
        if heat_J.shape != (n, M):
            raise ValueError("heat_J must have shape (n_steps, M) = (%d, %d), found %s" % (n, M, heat_J.shape))
        power += heat_J / dt[:, None]
    if source_W is not None:
        power += np.broadcast_to(np.asarray(source_W, dtype=float), (n, M))
    air = None
    if air_K is not None:
        air = np.asarray(air_K, dtype=float)
        if air.shape != (n + 1,):
            raise ValueError("air_K must have shape (n_steps+1,) = (%d,), found %s" % (n + 1, air.shape))
        if not np.all(np.isfinite(air)):
            raise ValueError("air_K contains non-finite values")
    prop = shared_propagator(C, G, H)
    out = np.empty((n + 1, M))
    out[0] = (0.0 if air is None else air[0]) if T0 is None else np.asarray(T0, dtype=float)
    if n == 0:
        return out
    gk = np.ones(n) if convection_mult is None else np.asarray(convection_mult, dtype=float)
    gk = np.broadcast_to(gk, (n,) if gk.ndim <= 1 else (n, M))
    if np.ptp(dt) <= 1e-9 * dt.max() and np.ptp(gk, axis=0).max() == 0.0:
        # one propagator: run the recurrence in the modal basis, where it is an
        # element-wise decay per mode (z = e*z + w); one matrix product each way
        g = gk[0]
        s, U = prop.modes(g)
        h = dt[0]
        e = np.exp(-s * h)
        phi = np.where(s * h > 1e-12, -np.expm1(-s * h) / np.where(s > 0, s, 1.0), h)
        W = rows_matmul(power * prop._rs, U) * phi
        if air is not None:
            _, g0, g1 = hold_weights(s, h)
            v = (np.broadcast_to(g, (M,)) * H * prop._rs) @ U
            W += np.outer(air[:-1], g0 * v) + np.outer(air[1:], g1 * v)
        Z = modal_scan(e, W, (out[0] * prop._s) @ U)
        out[1:] = rows_matmul(Z, U.T) * prop._rs
        return out
    # several propagators (variable dt or convection): group steps by (dt, g) so each
    # distinct propagator is built once and applied to its inputs in one product
    if gk.ndim == 1:
        keys = np.stack([np.round(dt, 9), gk], axis=1)
    else:
        keys = np.concatenate([np.round(dt, 9)[:, None], gk], axis=1)
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    As = np.empty((len(uniq), M, M))
    drive = np.empty((n, M))
    for j, row in enumerate(uniq):
        g = row[1] if gk.ndim == 1 else row[1:]
        A, Bp = prop.step(row[0], g)
        As[j] = A
        idx = np.flatnonzero(inv == j)
        drive[idx] = rows_matmul(power[idx], Bp.T)
        if air is not None:
            c0, c1 = prop.air_step(row[0], g)
            drive[idx] += np.outer(air[idx], c0) + np.outer(air[idx + 1], c1)
    T = out[0].copy()
    for k in range(n):
        T = As[inv[k]] @ T + drive[k]
        out[k + 1] = T
    return out


def fin_steady_state(x_mm: ArrayLike, power_W: float, length_mm: float, diameter_mm: float, lambda_W_mK: float, h_W_m2K: float) -> np.ndarray:
    """1-D fin with heat ``power_W`` entering at x = 0, adiabatic tip at length_mm:
    T(x) = P·cosh(m(L-x)) / (λ·A·m·sinh(mL)), m = sqrt(h·π·d/(λ·A))."""
    d = diameter_mm * 1e-3
    A = np.pi * d * d / 4.0
    m = np.sqrt(h_W_m2K * np.pi * d / (lambda_W_mK * A))
    L = length_mm * 1e-3
    x = np.asarray(x_mm, dtype=float) * 1e-3
    return power_W * np.cosh(m * (L - x)) / (lambda_W_mK * A * m * np.sinh(m * L))
