"""The screw's reduced state recovered from its sensors when a board starts on a warm machine (issue 21).

The reduced recurrence (host/learning/screw/reduced.py) carries the screw's segment temperatures T_i over the
model's reference. A board restores them from heat.bin when the record matches its table; otherwise it starts
them "cold", in equilibrium with the air (T_i = a, the air over its reference). On a warm machine that start is
wrong by the screw's heat, and the recurrence forgets it only as fast as the screw cools (its time constant,
c·ρ·d/(4h), is about half an hour for a 32 mm screw; axial conduction is slower still).

The nut sensor reads the screw's warmth: the nut housing sits on the screw and follows it. The observer is the
dynamic model's idea (host/learning/empirical/observer.py) applied to the segment states:

1. Regressor: the screw-side sensor's rise over the air, r = (T_nut − T_nut,ref) − (T_air − T_air,ref), both over
   the references the model's own sensors use (the run's start under ``base_ref="run_start"``, where the board
   latches them at a cold start; the first training run's start under ``"fixed"``). The air is the model's air
   sensor, else its base sensor. r is 0 on a machine at rest whatever the shop's temperature.
2. Estimate: T̂_i = a + G_i·r, fitted by least squares on the training runs, where the true reduced state is
   known (the recurrence run through each run from its cold start, as the model was fitted). There is no
   constant term: a machine at rest (r = 0) gets exactly the cold state the board starts in without the observer.
3. Bound: E_i = max |T_i − T̂_i| over the training samples bounds the start error of segment i on conditions like
   the training's. The state error e then evolves as e ← A·e (the recurrence is linear in its state; the heat
   and air inputs are the same for both boards), A ≥ 0 element-wise, so the offset error at step k is at most

       B(k) = α·Σ_i w_i·(A^k·E)_i,      w_i = overlap of segment i with [0, x(P_far)] (mm)

   at the far end of the position envelope, the largest over the stroke (every term is ≥ 0). The observer is
   *settling* while B > ``SETTLE_TOLERANCE_UM``; ``settle_s`` (recorded in the document) is when B reaches it.
   The cold start's bound is the same with E_i = max |T_i − a| (the whole heat): the document records both, and the
   observer is kept only when it starts closer than the cold start (else it says so and there is none).

Why one regressor: the nut sensor is a single reading of a screw whose heat is distributed along the nut's
range; the gains G_i carry the training runs' average profile. The estimate is as good as the training runs'
heat profiles are like the machine's at power-on; E_i says how far off it was on them. What the sensor cannot
say about the profile (which part of the stroke ran last) stays in E_i, and the recurrence forgets it.

When the sensors do not allow it (no nut sensor, no air or base sensor to reference it to, a training run without
their columns, a nut reading that never rose over the air in training, or an estimate no better than the cold start), there is no observer and the
document says why (``thermal.observer_note``); ``tcomp fit`` prints it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from host.learning.screw import heat
from host.learning.screw.reduced import simulate_reduced

if TYPE_CHECKING:
    from host.data.runs import Run
    from host.learning.screw.screwmodel import ScrewModel

SETTLE_TOLERANCE_UM = 1.0  # the restart goal: within 1 µm of an uninterrupted board (as the dynamic observer)
MIN_NUT_RISE_K = 0.5  # a nut reading that never rises this far over the air in training cannot identify a gain
METHOD = "static_state_estimate"


class ScrewObserver:
    """T̂_i = a + G_i·r at power-on (module doc). ``gains_K_per_K`` G (M,), ``bound_K`` E (M,), ``rms_K`` (M,);
    ``sensor``: the screw-side sensor (nut), ``air``: the sensor r is referenced to; ``reference_C``: their
    references under ``base_ref="fixed"`` (None under "run_start": the board's latched references)."""

    def __init__(self, sensor: str, air: str, gains_K_per_K: ArrayLike, bound_K: ArrayLike, rms_K: ArrayLike, settle_s: float, start_error_um: float, cold_start_error_um: float,
                 cold_settle_s: float, reference_C: dict[str, float] | None = None,
                 tolerance_um: float = SETTLE_TOLERANCE_UM) -> None:
        self.sensor = sensor
        self.air = air
        self.gains = np.asarray(gains_K_per_K, dtype=float)
        self.bound = np.asarray(bound_K, dtype=float)
        self.rms = np.asarray(rms_K, dtype=float)
        self.settle_s = float(settle_s)
        self.start_error_um = float(start_error_um)
        self.cold_start_error_um = float(cold_start_error_um)
        self.cold_settle_s = float(cold_settle_s)
        self.reference_C = None if reference_C is None else {k: float(v) for k, v in reference_C.items()}
        self.tolerance_um = float(tolerance_um)

    def estimate(self, air_K: float, rise_K: float) -> np.ndarray:
        """Segment states (K over the model's reference) from the air over its reference and the nut's rise r."""
        return air_K + self.gains * rise_K

    def to_document(self) -> dict[str, Any]:
        return {"method": METHOD, "sensor": self.sensor, "air_sensor": self.air,
                "reference_C": self.reference_C,
                "gains_K_per_K": [float(g) for g in self.gains], "bound_K": [float(b) for b in self.bound],
                "rms_K": [float(v) for v in self.rms], "tolerance_um": self.tolerance_um,
                "start_error_um": self.start_error_um, "settle_s": self.settle_s,
                "cold_start_error_um": self.cold_start_error_um, "cold_settle_s": self.cold_settle_s}

    @classmethod
    def from_document(cls, obs: Any, segments: int) -> ScrewObserver:
        import math

        from host.learning.documents import ModelFormatError

        where = "screw model document: thermal.observer"

        def num(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        if not isinstance(obs, dict):
            raise ModelFormatError("%s must be an object or null, found %s" % (where, type(obs).__name__))
        if obs.get("method") != METHOD:
            raise ModelFormatError("%s.method must be %r, found %r" % (where, METHOD, obs.get("method")))
        for key in ("sensor", "air_sensor"):
            if not isinstance(obs.get(key), str) or not obs[key]:
                raise ModelFormatError("%s.%s must be a sensor name, found %r" % (where, key, obs.get(key)))
        for key in ("gains_K_per_K", "bound_K", "rms_K"):
            v = obs.get(key)
            if not isinstance(v, list) or len(v) != segments or not all(num(x) for x in v):
                raise ModelFormatError("%s.%s must list %d finite numbers (one per reduced segment), found %r"
                                       % (where, key, segments, v))
            if key != "gains_K_per_K" and min(v) < 0:
                raise ModelFormatError("%s.%s must be >= 0, found %r" % (where, key, min(v)))
        for key in ("tolerance_um", "start_error_um", "settle_s", "cold_start_error_um", "cold_settle_s"):
            if not num(obs.get(key)) or obs[key] < 0:
                raise ModelFormatError("%s.%s must be a finite number >= 0, found %r" % (where, key, obs.get(key)))
        ref = obs.get("reference_C")
        if ref is not None and (not isinstance(ref, dict) or set(ref) != {obs["sensor"], obs["air_sensor"]}
                                or not all(num(v) for v in ref.values())):
            raise ModelFormatError("%s.reference_C must be null or map %s and %s to degC, found %r"
                                   % (where, obs["sensor"], obs["air_sensor"], ref))
        return cls(obs["sensor"], obs["air_sensor"], obs["gains_K_per_K"], obs["bound_K"], obs["rms_K"], obs["settle_s"],
                   obs["start_error_um"], obs["cold_start_error_um"], obs["cold_settle_s"], ref, obs["tolerance_um"])


def companion_sensor(model: ScrewModel) -> str | None:
    """The sensor the nut's rise is referenced to: the model's air sensor, else its base sensor."""
    return getattr(model, "air_sensor_", None) or getattr(model, "base_sensor_", None)


def _references(model: ScrewModel, run: Run, sensor: str, air: str, reference_C: dict[str, float] | None) -> tuple[float, float]:
    tt = run.temperatures
    if model.base_ref == "run_start" or reference_C is None:
        return float(tt.column(sensor)[0]), float(tt.column(air)[0])
    return reference_C[sensor], reference_C[air]


def rise_K(model: ScrewModel, run: Run, times_s: np.ndarray, sensor: str, air: str,
           reference_C: dict[str, float] | None = None) -> np.ndarray:
    """r(t) = (T_sensor − ref) − (T_air − ref) at ``times_s`` (module doc, item 1)."""
    tt = run.temperatures
    for name in (sensor, air):
        if name not in tt.names:
            raise ValueError("%s: the observer reads sensor %s, which temperatures.csv lacks" % (run.path or run.name, name))
    rs, ra = _references(model, run, sensor, air, reference_C)
    return (np.interp(times_s, tt.time_s, tt.column(sensor)) - rs) - (np.interp(times_s, tt.time_s, tt.column(air)) - ra)


def reduced_run(model: ScrewModel, run: Run, t_start: float | None = None, T0: np.ndarray | None = None,
                spread: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reduced recurrence over ``run`` from ``t_start`` (default: the run's first grid time) as a board started
    then computes it: (step times, air over the reference at them (zeros without an air sensor), states (n+1, M)).
    ``T0``: the start state (None: cold, in equilibrium with the air)."""
    from host.learning.screw.context import check_screw_run

    red = model.reduced_
    assert red is not None  # callers pass fitted models with their reduced form
    check_screw_run(run, model.geometry_, require_nut=False)  # a run without motion is refused here, by name
    ctx = model._context(run)
    dt = red["dt_s"]
    t0 = ctx.t_grid[0] if t_start is None else float(t_start)
    n = int(np.floor((ctx.t_grid[-1] - t0) / dt + 1e-9))
    if n < 1:
        raise ValueError("%s: less than one reduced step (%g s) after %g s" % (run.path or run.name, dt, t0))
    ts = t0 + dt * np.arange(n + 1)
    air = model.air_K(ctx, delag=False)  # the firmware's air input: the sensor's reading
    a = np.zeros(n + 1) if air is None else np.interp(ts, ctx.t_grid, air)
    assert run.motion is not None  # check_screw_run above
    _, T = simulate_reduced(red, run.motion, t0, n, spread=spread, air_K=None if air is None else a, T0=T0)
    return ts, a, T


def offset_weights_mm(model: ScrewModel) -> np.ndarray:
    """w_i: each segment's overlap with [0, x(P_far)], P_far the end of the position envelope farthest from the
    fixed end (every segment's contribution to E_m is largest there)."""
    red = model.reduced_
    assert red is not None
    lo, hi = model.envelope_["position_mm"] if model.envelope_ else (0.0, model.geometry_.length_mm)
    far = max(abs(lo - red["fixed_end_mm"]), abs(hi - red["fixed_end_mm"]))
    return heat.overlap_mm(np.asarray(red["edges_mm"], dtype=float), far)


def error_bound_um(model: ScrewModel, state_error_K: np.ndarray, elapsed_s: np.ndarray) -> np.ndarray:
    """B at each elapsed time (µm): α·wᵀ·A^k·E, k = floor(elapsed / dt) steps (module doc, item 3)."""
    red = model.reduced_
    assert red is not None
    A = np.asarray(red["A"], dtype=float)
    w = offset_weights_mm(model) * red["alpha_um_per_mm_per_K"]
    ks = np.floor(np.asarray(elapsed_s, dtype=float) / red["dt_s"] + 1e-9).astype(int)
    out = np.empty(ks.size)
    e = np.asarray(state_error_K, dtype=float).copy()
    k = 0
    for i in np.argsort(ks):
        while k < ks[i]:
            e = A @ e
            k += 1
        out[i] = float(w @ e)
    return out


def settle_time_s(model: ScrewModel, state_error_K: np.ndarray, tolerance_um: float = SETTLE_TOLERANCE_UM,
                  max_s: float = 7 * 86400.0) -> float:
    """First step time at which the bound B falls to ``tolerance_um`` (B decreases: A ≥ 0, wᵀA ≤ wᵀ)."""
    red = model.reduced_
    assert red is not None
    A = np.asarray(red["A"], dtype=float)
    w = offset_weights_mm(model) * red["alpha_um_per_mm_per_K"]
    e = np.asarray(state_error_K, dtype=float).copy()
    dt = red["dt_s"]
    k = 0
    while float(w @ e) > tolerance_um:
        e = A @ e
        k += 1
        if k * dt > max_s:
            raise ValueError("screw observer: the start error bound stays above %g um for %g h" % (tolerance_um, max_s / 3600))
    return k * dt


def fit_observer(model: ScrewModel, runs: Sequence[Run], tolerance_um: float = SETTLE_TOLERANCE_UM
                 ) -> tuple[ScrewObserver | None, str]:
    """The observer of ``model``'s reduced state fitted on ``runs`` (module doc) -> (observer, note); (None, why) when
    the sensors do not allow one."""
    sensor = getattr(model, "nut_sensor_", None)
    air = companion_sensor(model)
    if model.reduced_ is None:
        return None, "no observer: the model has no reduced form"
    if sensor is None:
        return None, ("no observer: no screw-side sensor (role 'nut' in meta.json); the board starts the screw cold "
                      "when heat.bin gives no trusted state")
    if air is None:
        return None, ("no observer: the nut sensor %s has no air or base sensor to be referenced to; the board starts "
                      "the screw cold when heat.bin gives no trusted state" % sensor)
    lacking = [(r.path or r.name, name) for r in runs for name in (sensor, air) if name not in r.temperatures.names]
    if lacking:  # the nut sensor is optional for the model itself (docs/screw-model.md): no observer, not a failed fit
        return None, ("no observer: training run %s has no column for sensor %s in temperatures.csv; the observer is "
                      "fitted on every training run" % lacking[0])
    reference_C = None
    if model.base_ref != "run_start":
        t0 = runs[0].temperatures
        reference_C = {sensor: float(t0.column(sensor)[0]), air: float(t0.column(air)[0])}
    X, Y = [], []
    for r in runs:
        ts, a, T = reduced_run(model, r)
        X.append(rise_K(model, r, ts, sensor, air, reference_C))
        Y.append(T - a[:, None])
    x, Yall = np.concatenate(X), np.vstack(Y)
    if not (np.isfinite(x).all() and np.isfinite(Yall).all()):
        return None, "no observer: NaN/inf in the nut sensor %s or the air sensor %s of the training runs" % (sensor, air)
    span = float(np.max(np.abs(x)))
    if span < MIN_NUT_RISE_K:
        return None, ("no observer: the nut sensor %s rises at most %.2f K over %s in the training runs (< %g K): "
                      "no gain can be identified" % (sensor, span, air, MIN_NUT_RISE_K))
    gains = (x @ Yall) / float(x @ x)  # least squares without a constant term, one regressor per segment
    res = Yall - x[:, None] * gains[None, :]
    bound = np.max(np.abs(res), axis=0)
    rms = np.sqrt(np.mean(res ** 2, axis=0))
    cold = np.max(np.abs(Yall), axis=0)  # the cold start's error: the whole heat
    start = float(error_bound_um(model, bound, np.array([0.0]))[0])
    cold_start = float(error_bound_um(model, cold, np.array([0.0]))[0])
    if start >= cold_start:
        return None, ("no observer: estimating the screw state from nut sensor %s starts no closer than the cold start "
                      "on the training runs (bound %.3g um against %.3g um)" % (sensor, start, cold_start))
    obs = ScrewObserver(sensor, air, gains, bound, rms, settle_time_s(model, bound, tolerance_um), start, cold_start,
                        settle_time_s(model, cold, tolerance_um), reference_C, tolerance_um)
    return obs, ("observer: screw state from nut sensor %s over %s; start error bound %.2f um (cold start %.2f um), "
                 "settles to %g um in %.0f min (cold start %.0f min)"
                 % (sensor, air, start, cold_start, tolerance_um, obs.settle_s / 60, obs.cold_settle_s / 60))


def restart(model: ScrewModel, run: Run, t_restart: float, observer: ScrewObserver | None,
            start_K: Callable[[float], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A board reset at ``t_restart`` on ``run`` against the uninterrupted board, both on the reduced recurrence:
    (step times from the restart, restarted states, uninterrupted states), states (n+1, M). ``observer`` None: the
    restarted board starts cold (in equilibrium with the air), as without an observer. ``start_K``: the start state
    as a function of the restart's step time instead (e.g. the board's integer start, tools/bench_screw_restart.py)."""
    red = model.reduced_
    assert red is not None
    ts_full, _, T_full = reduced_run(model, run)
    dt = red["dt_s"]
    k0 = int(round((t_restart - ts_full[0]) / dt))
    if not 0 <= k0 < ts_full.size - 1:
        raise ValueError("%s: restart at %g s is outside the run's reduced steps" % (run.path or run.name, t_restart))
    t0 = ts_full[k0]
    T0 = None if start_K is None else np.asarray(start_K(float(t0)), dtype=float)
    if observer is not None and start_K is None:
        ctx = model._context(run)
        air = model.air_K(ctx, delag=False)
        a0 = 0.0 if air is None else float(np.interp(t0, ctx.t_grid, air))
        r0 = float(rise_K(model, run, np.array([t0]), observer.sensor, observer.air, observer.reference_C)[0])
        T0 = observer.estimate(a0, r0)
    ts, _, T = reduced_run(model, run, t_start=t0, T0=T0)
    n = min(ts.size, T_full.shape[0] - k0)
    return ts[:n], T[:n], T_full[k0:k0 + n]


def restart_deviation_um(model: ScrewModel, run: Run, t_restart: float, observer: ScrewObserver | None,
                         positions: int = 21, start_K: Callable[[float], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(elapsed s since the restart, largest |E_m(restarted) − E_m(uninterrupted)| over ``positions`` points of the
    position envelope at each step), µm."""
    from host.learning.screw.reduced import reduced_error_um

    red = model.reduced_
    assert red is not None
    ts, T, Tu = restart(model, run, t_restart, observer, start_K)
    lo, hi = model.envelope_["position_mm"] if model.envelope_ else (0.0, model.geometry_.length_mm)
    P = np.linspace(lo, hi, positions)
    d = reduced_error_um(red, T[:, None, :], P[None, :]) - reduced_error_um(red, Tu[:, None, :], P[None, :])
    return ts - ts[0], np.max(np.abs(d), axis=1)
