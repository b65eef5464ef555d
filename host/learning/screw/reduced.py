"""Reduced screw model for the firmware (docs/model-format.md, section ``screw``).

Few segments (default 12 over the whole screw), one fixed step dt, and the
recurrence ``T[k+1] = A·T[k] + B ∘ u[k] + c0·a[k] + c1·a[k+1]``:

- A = e^{K dt}, the exact step of the conduction + convection system (the same
  Propagator as the full model).  A ≥ 0 element-wise and its row sums are < 1
  when h > 0, which is what makes the integer recurrence safe to bound;
- B_i = q / C_i [K/mm]: the friction heat of the step's travel u_i (mm inside
  segment i) added as a temperature increment at the end of the step.  Keeping B
  diagonal (the contract) costs a delay of at most one step in where the heat
  appears; the measured effect is in the reduction-error figures.

- c0, c1 (``air_K0``, ``air_K1``, K per K): the exact weights of the air
  temperature a (over the reference) at the start and the end of the step, for
  air linear within the step (heat.Propagator.air_step).  c0, c1 ≥ 0 and
  A·1 + c0 + c1 = 1: without heat the state is a convex combination of its start
  and the air readings, so it stays inside the air's envelope.  A document
  without an air sensor (or written before the air term) has c0 = c1 = 0.

- effect terms (each effect's ``reduce`` in host/learning/screw/effects.py, defined
  there once): ``travel_heat_K_per_mm`` (M,), a temperature increment per mm of the
  step's total travel U = Σ u_i (bearing_heat: k·0.06/C_0 into the fixed-end segment);
  ``ee_um_per_mm_per_K``, the base term's coefficient (α for E_e, plus
  ambient_expansion's k); ``reversal_um``, +r moving in +, −r moving in − (the
  direction of the last position change); ``heat_scale0``, ``heat_scale_per_mm`` (speed_dependent_heat): the
  friction heat B_i·u_i times g(U) = heat_scale0 + heat_scale_per_mm·U; ``convection_per_mm`` (M,)
  (moving_convection): the step's extra loss −D_i·U·(T_i − a), explicit (state and air at the step's start).  An effect whose form the firmware cannot
  evaluate is listed in ``omitted_effects`` with the reason in ``omitted_reasons``;
  the reduction error below then shows what leaving it out costs, and the exporter
  refuses above its limit.

The state is the heat response plus the air response (the system is linear), so
it lies in [a_min, a_max + state_max_K] for an air envelope [a_min, a_max]; the
exporter certifies exactly that interval.  ``state_max_K`` is a certified bound
of the heat response: with u_i ≥ 0 and Σ_i u_i ≤ U = feed_max·dt,
T_j[k] ≤ U·Σ_m (max_i (A^m)_{ji}·B_i + (A^m·b_U)_j) for every input history (A^m ≥ 0,
b_U = travel_heat_K_per_mm ≥ 0), summed until the tail is below 1e-9 of the total
(geometric tail bound added).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import numpy as np

from host.learning.screw import heat
from host.learning.screw.context import run_motion
from host.learning.screw.effects import NoReducedForm

if TYPE_CHECKING:
    from host.data.runs import Motion, Run
    from host.learning.screw.screwmodel import ScrewModel


def build_reduced(model: ScrewModel, segments: int = 12, dt_s: float = 10.0, feed_max_mm_min: float = 12000.0) -> dict[str, Any]:
    """``thermal.reduced`` block of the document for a fitted ScrewModel."""
    if not 1 <= int(segments) <= 64:
        raise ValueError("reduced segments must be 1..64 (got %r)" % (segments,))
    if not dt_s > 0:
        raise ValueError("reduced dt_s must be positive (got %r)" % (dt_s,))
    geo = model.geometry_.with_segments(int(segments))
    p = model.params_
    edges = geo.edges_mm
    C, G, H = heat.segment_properties(edges, geo.diameter_mm, p, geo.bore_mm)
    prop = heat.Propagator(C, G, H)
    A, _ = prop.step(dt_s, 1.0)
    A = np.clip(A, 0.0, None)  # exp of a Metzler matrix is >= 0; clears round-off of order 1e-17
    B = p.q_J_per_mm / C
    air = getattr(model, "air_sensor_", None)
    c0, c1 = (np.clip(c, 0.0, None) for c in prop.air_step(dt_s, 1.0)) if air else (np.zeros(B.size), np.zeros(B.size))
    out = {
        "segments": int(segments),
        "dt_s": float(dt_s),
        "edges_mm": [float(e) for e in edges],
        "fixed_end_mm": float(geo.fixed_end_mm),
        "A": [[float(v) for v in row] for row in A],
        "B_K_per_mm": [float(b) for b in B],
        "air_sensor": air,
        "air_ref_C": getattr(model, "air_ref_C_", None),
        "air_K0": [float(c) for c in c0],
        "air_K1": [float(c) for c in c1],
        "alpha_um_per_mm_per_K": float(1e3 * p.alpha_per_K),
        "base_sensor": model.base_sensor_,
        "base_ref_C": model.base_ref_C_,
        "base_ref": getattr(model, "base_ref", "fixed"),
        # errors referred to a sensor: E_m loses alpha*(T_R - T_R,ref)*P, a temperature-linear term (reference.py)
        "error_reference": getattr(model, "error_reference_", "start"),
        "error_reference_C": getattr(model, "error_reference_C_", None),
        "feed_max_mm_min": float(feed_max_mm_min),
        "ee_um_per_mm_per_K": float(1e3 * p.alpha_per_K) if model.base_sensor_ is not None else 0.0,
    }
    omitted = {}
    for e in model.effects:
        try:
            e.reduce(model, model.effect_params_[e.name], out, C)
        except NoReducedForm as exc:
            omitted[e.name] = str(exc)
    heat_u = out.get("travel_heat_K_per_mm")
    if heat_u is not None and min(heat_u) < 0:
        bad = [e.name for e in model.effects if e.name not in omitted and e.name == "bearing_heat"]
        raise NoReducedForm("%s: negative heat per mm of travel %r K/mm: no certified state bound"
                            % (", ".join(bad) or "travel_heat_K_per_mm", min(heat_u)))
    umax = feed_max_mm_min / 60.0 * dt_s
    # speed_dependent_heat scales the friction heat by g(U) = heat_scale0 + heat_scale_per_mm·U >= 0 (checked by its
    # reduce): the bound takes g's largest value on [0, umax]; moving_convection only moves weight from the state to
    # the air (D_i·U <= A_ii), so the bound of the heat response without it holds
    g = out.get("heat_scale0", 1.0) + max(0.0, out.get("heat_scale_per_mm", 0.0)) * umax
    out["state_max_K"] = state_bound(A, B * g, umax, heat_u)
    if getattr(model, "air_lag_s_", 0.0) > 0:
        # the recurrence's air weights c0, c1 are convex (>= 0): the de-lag's derivative would make them negative and
        # lose the state envelope the exporter certifies; the reduction error below shows what the raw air costs
        omitted["air_lag_s"] = ("the air sensor's lag (%g s) needs negative air weights in the recurrence; the firmware "
                                "feeds the sensor's reading" % model.air_lag_s_)
    if omitted:
        out["omitted_effects"] = list(omitted)
        out["omitted_reasons"] = omitted
    return out


def state_bound(A: ArrayLike, B: ArrayLike, travel_max_mm: float, travel_heat: ArrayLike | None = None) -> float:
    """Certified max of every state for any travel history with Σu ≤ travel_max per step;
    ``travel_heat`` (M,) ≥ 0: the increment per mm of the step's total travel (effects)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    Bu = np.zeros(B.size) if travel_heat is None else np.asarray(travel_heat, dtype=float)
    rho = float(np.max(A.sum(axis=1)))
    if rho >= 1.0:
        raise ValueError("reduced model has no heat loss (row sum of A = %g >= 1): no finite state bound; h must be > 0" % rho)
    acc = np.zeros(A.shape[0])
    term = np.zeros(A.shape[0])
    P = np.eye(A.shape[0])
    for _ in range(200000):
        term = np.max(P * B[None, :], axis=1) + P @ Bu
        acc += term
        if term.max() <= 1e-9 * max(acc.max(), 1e-300):
            break
        P = P @ A
    # remaining terms are below term·rho^m: geometric tail
    tail = float(term.max()) * rho / (1.0 - rho)
    return float(travel_max_mm * (acc.max() + tail))


def _arr(reduced):
    return (np.asarray(reduced["A"], dtype=float), np.asarray(reduced["B_K_per_mm"], dtype=float),
            np.asarray(reduced["edges_mm"], dtype=float))


def air_weights(reduced: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(c0, c1) of the recurrence; zeros for a document without the air term."""
    M = int(reduced["segments"])
    return (np.asarray(reduced.get("air_K0") or np.zeros(M), dtype=float),
            np.asarray(reduced.get("air_K1") or np.zeros(M), dtype=float))


def simulate_reduced(reduced: dict[str, Any], motion: Motion, t0: float, n_steps: int, spread: bool = False, air_K: np.ndarray | None = None,
                     T0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """States (n_steps+1, M) of the float recurrence from a cold start at t0
    (in equilibrium with the air: T = a[0]), or from ``T0`` (M,) (a warm start: host/learning/screw/observer.py).

    spread: feed the travel as a feed/range state (spread over the range) instead of
    the exact reciprocation (position reports); air_K: (n_steps+1,) air temperature
    over the reference at the step times (None: constant air at the reference)."""
    A, B, edges = _arr(reduced)
    c0, c1 = air_weights(reduced)
    dt = reduced["dt_s"]
    t = t0 + dt * np.arange(n_steps + 1)
    u = heat.nut_travel_per_segment(motion, edges, reduced["fixed_end_mm"], t, spread=spread)
    U = u.sum(axis=1)  # the step's total travel (mm)
    # speed_dependent_heat: the friction heat times g(U) = heat_scale0 + heat_scale_per_mm·U
    g = reduced.get("heat_scale0", 1.0) + reduced.get("heat_scale_per_mm", 0.0) * U
    drive = u * g[:, None] * B[None, :]
    if reduced.get("travel_heat_K_per_mm") is not None:
        drive = drive + U[:, None] * np.asarray(reduced["travel_heat_K_per_mm"], dtype=float)[None, :]
    T = np.zeros((n_steps + 1, B.size))
    a = np.zeros(n_steps + 1)
    if air_K is not None:
        a = np.asarray(air_K, dtype=float)
        drive = drive + a[:-1, None] * c0[None, :] + a[1:, None] * c1[None, :]
        T[0] = a[0]
    if T0 is not None:
        T[0] = np.asarray(T0, dtype=float)
    # moving_convection: the extra loss D_i·U·(T_i − a) of the step, explicit (the state and the air at its start)
    D = reduced.get("convection_per_mm")
    D = None if D is None else np.asarray(D, dtype=float)
    x = T[0].copy()
    for k in range(n_steps):
        xn = A @ x + drive[k]
        if D is not None:
            xn -= D * U[k] * (x - a[k])
        x = xn
        T[k + 1] = x
    return t, T


def reduced_error_um(reduced: dict[str, Any], T: np.ndarray, positions_mm: ArrayLike, base_rise_K: ArrayLike | None = None) -> np.ndarray:
    """E(P) of the reduced model without the geometric part: α·Σ T_i·overlap_i(P) (+ α·ΔT_b·P).

    T: (..., M); positions broadcastable to T.shape[:-1]."""
    _, _, edges = _arr(reduced)
    a = reduced["alpha_um_per_mm_per_K"]
    E = heat.thermal_error_um(edges, T, positions_mm, reduced["fixed_end_mm"], a * 1e-3)
    if base_rise_K is not None:
        E = E + a * np.asarray(base_rise_K) * np.asarray(positions_mm)
    return E


def reduced_predict(model: ScrewModel, run: Run, spread: bool = False) -> np.ndarray:
    """The reduced form's error at every row of ``run.errors`` (µm), as the board evaluates it: the latest state
    (a step at t0 + k·dt), α·Σ T_i·overlap_i(P) + ee·(T_b − T_b,ref)·P − α·(T_R − T_R,ref)·P under a sensor error
    reference R + the reversal term by the row's direction
    (none in the feed/range mode, which has no direction) + the geometric polynomial."""
    red = model.reduced_form()
    ctx = model._context(run)
    t0 = ctx.t_grid[0]
    dt = red["dt_s"]
    n = int(np.floor((ctx.t_grid[-1] - t0) / dt + 1e-9))
    air = model.air_K(ctx, delag=False)  # the firmware's air input: the sensor's reading
    if air is not None:
        air = np.interp(t0 + dt * np.arange(n + 1), ctx.t_grid, air)
    _, Tr = simulate_reduced(red, run_motion(run), t0, n, spread=spread, air_K=air)
    e = run.errors
    k = np.clip(np.floor((e.time_s - t0) / dt + 1e-9).astype(int), 0, n)
    P = e.position_mm
    E = reduced_error_um(red, Tr[k], P)
    base = red.get("base_sensor")
    if base is not None:
        tb = run.temperatures
        ref = float(tb.column(base)[0]) if red.get("base_ref") == "run_start" else float(red["base_ref_C"])
        ee = red.get("ee_um_per_mm_per_K", red["alpha_um_per_mm_per_K"])
        E = E + ee * (np.interp(e.time_s, tb.time_s, tb.column(base)) - ref) * P
    eref = red.get("error_reference", "start")
    if eref not in (None, "start"):
        # errors corrected to sensor R: the table's -alpha coefficient on R (models_export/exact.py), from the same
        # start rule as the base term
        tr = run.temperatures
        ref = float(tr.column(eref)[0]) if red.get("base_ref") == "run_start" else float(red["error_reference_C"])
        E = E - red["alpha_um_per_mm_per_K"] * (np.interp(e.time_s, tr.time_s, tr.column(eref)) - ref) * P
    if red.get("reversal_um") and e.direction is not None and not spread:
        E = E + red["reversal_um"] * e.direction
    return E + model.geometric_um(P)


def reduction_error(model: ScrewModel, run: Run, positions: int = 21, spread: bool = False) -> dict[str, Any]:
    """Difference between the full model and its reduced form on one run.

    E_m (``rms_um``, ``max_um``): both evaluated at every reduced step time on ``positions`` equally spaced
    points over the model's position envelope; the reduced model uses its latest state (as the firmware does),
    the full model its own grid interpolated. The whole output (``rows_rms_um``, ``rows_max_um``): the full
    model's prediction against :func:`reduced_predict` at the run's error rows (E_e, effect outputs, direction).
    ``spread`` feeds the reduced model from the feed/range state.
    Returns {"rms_um", "max_um", "points", "full_max_um", "rows_rms_um", "rows_max_um"}."""
    red = model.reduced_form()
    ctx_full = model._context(run)
    rises = model.simulate_context(ctx_full)
    t0 = ctx_full.t_grid[0]
    n = int(np.floor((ctx_full.t_grid[-1] - t0) / red["dt_s"] + 1e-9))
    air = model.air_K(ctx_full, delag=False)
    if air is not None:
        air = np.interp(t0 + red["dt_s"] * np.arange(n + 1), ctx_full.t_grid, air)
    t, Tr = simulate_reduced(red, run_motion(run), t0, n, spread=spread, air_K=air)
    lo, hi = model.envelope_["position_mm"] if model.envelope_ else (0.0, model.geometry_.length_mm)
    P = np.linspace(lo, hi, positions)
    Rf = heat.interp_rows(t, ctx_full.t_grid, rises)
    Ef = heat.thermal_error_um(ctx_full.edges_mm, Rf[:, None, :], P[None, :], model.geometry_.fixed_end_mm, model.params_.alpha_per_K)
    Er = reduced_error_um(red, Tr[:, None, :], P[None, :])
    d = Er - Ef
    rows = reduced_predict(model, run, spread=spread) - model.predict(run)
    return {"rms_um": float(np.sqrt(np.mean(d ** 2))), "max_um": float(np.max(np.abs(d))), "points": int(d.size),
            "full_max_um": float(np.max(np.abs(Ef))),
            "rows_rms_um": float(np.sqrt(np.mean(rows ** 2))), "rows_max_um": float(np.max(np.abs(rows)))}


def reduction_certificate(model: ScrewModel, runs: Sequence[Run]) -> dict[str, Any]:
    """{run: reduction_error} with position reports, and the same fed from the feed/range state under "feed_range"."""
    out = {}
    for r in runs:
        e = reduction_error(model, r)
        e["feed_range"] = {k: v for k, v in reduction_error(model, r, spread=True).items() if k.endswith("_um")}
        out[r.path or r.name] = e
    return out
