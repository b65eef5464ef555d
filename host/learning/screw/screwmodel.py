"""The identified ball-screw model: E(P, t) = geometric(P) + E_m + E_e (+ effects).

``ScrewModel`` follows the scikit-learn estimator pattern: settings in ``__init__``,
``fit(runs)`` identifies the parameters (learned attributes end in ``_``),
``predict(run)`` simulates the run's own motion and base temperature and returns
one error per row of ``run.errors``.  ``to_document``/``from_document`` give the
``screw`` kind of docs/model-format.md, with the reduced firmware recurrence in
``thermal.reduced`` (host/learning/screw/reduced.py).  docs/screw-model.md has the equations.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import warnings

import numpy as np

from host.data.runs import START as RAW, check_model_reference, common_error_reference
from host.learning.screw import heat
from host.learning.screw import reference as errref
from models_export.document import FORMAT
from host.learning.screw.context import RunContext, check_screw_run, run_motion
from host.learning.screw.effects import EFFECTS, CheckHook, ConvectionHook, Effect, ErrorHook, HeatHook, HeatScaleHook, ParamSpec
from host.learning.screw.identify import IdentifiabilityWarning, fit_parameters

if TYPE_CHECKING:
    from host.data.runs import Run
    from host.learning.screw.observer import ScrewObserver

BASE_PARAMS = ("q_J_per_mm", "h_W_m2K", "lambda_W_mK", "c_J_kgK", "alpha_per_K")
ALIASES = {"q": "q_J_per_mm", "h": "h_W_m2K", "lambda": "lambda_W_mK", "c": "c_J_kgK", "alpha": "alpha_per_K"}
BOUNDS = {
    "q_J_per_mm": (1e-5, 20.0, "J/mm"),
    "h_W_m2K": (0.5, 500.0, "W/(m2 K)"),
    "lambda_W_mK": (2.0, 400.0, "W/(m K)"),
    "c_J_kgK": (100.0, 3000.0, "J/(kg K)"),
    "alpha_per_K": (1e-7, 5e-5, "1/K"),
}
START = {"q_J_per_mm": 0.1, "h_W_m2K": 15.0}
MAX_GEOMETRIC_DEGREE = 4
BASE_ALPHA_MIN_SPAN_K = 0.5  # base-temperature span below which alpha is not identified (no E_e signal)
# The air sensor's lag (air_lag_s): its reading's derivative is taken over a 300 s moving average. The logger's
# noise (0.01 K at 10 s on the twin) differentiated sample to sample and times a 150 s lag is 0.2 K of white noise
# in the air input, an error in the regressor that biased alpha by +7 % / -16 % (start / T3, tools/bench_reference.py);
# 300 s is short against the air's drifts (HVAC periods of 15 min and more) and removes that noise.
AIR_LAG_SMOOTH_S = 300.0
MAX_AIR_LAG_S = 3600.0


def delagged(time_s: ArrayLike, reading: ArrayLike, lag_s: float, smooth_s: float = AIR_LAG_SMOOTH_S) -> np.ndarray:
    """The temperature a first-order sensor of time constant ``lag_s`` lags behind: T = reading + lag·d(reading)/dt,
    the derivative of the reading's moving average over ``smooth_s`` (uneven sampling: averaged by time)."""
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(reading, dtype=float)
    if t.size < 3:
        return x.copy()
    half = 0.5 * smooth_s
    # moving average by time: the integral of the piecewise-linear reading over [t - half, t + half] (ends held)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])

    def integral(s):
        s = np.clip(s, t[0], t[-1])
        i = np.clip(np.searchsorted(t, s, side="right") - 1, 0, t.size - 2)
        ds = s - t[i]
        slope = (x[i + 1] - x[i]) / (t[i + 1] - t[i])
        return cum[i] + ds * (x[i] + 0.5 * slope * ds)

    lo, hi = np.clip(t - half, t[0], t[-1]), np.clip(t + half, t[0], t[-1])
    avg = (integral(hi) - integral(lo)) / np.maximum(hi - lo, 1e-12)
    return x + lag_s * np.gradient(avg, t)


def _resolve(name: str) -> str:
    return ALIASES.get(name, name)


# Margin (K) added on both sides of the training range of the base sensor in the exported envelope.
BASE_ENVELOPE_MARGIN_K = 5.0

def implausible_parameters(identified: dict[str, float]) -> list[dict[str, Any]]:
    """[{parameter, value, accepted, steel, warning}] of the identified parameters outside what a screw's steel can
    have (heat.STEEL_RANGES); fixed parameters are the user's statement and are not judged."""
    out = []
    for name, value in identified.items():
        if name not in heat.STEEL_RANGES:
            continue
        lo, hi = heat.STEEL_RANGES[name]
        if lo <= value <= hi:
            continue
        unit = {"lambda_W_mK": "W/(m K)", "alpha_per_K": "/K", "c_J_kgK": "J/(kg K)"}[name]
        out.append({"parameter": name, "value": value, "accepted": [lo, hi], "steel": heat.STEEL[name],
                    "warning": "identified %s = %.4g %s is not a steel's (screw steels: %.4g..%.4g %s, nominal %.4g): the "
                               "parameter absorbs another effect or the data do not identify it; do not read it as the "
                               "screw's material" % (name, value, unit, lo, hi, unit, heat.STEEL[name])})
    return out


class ScrewModel:
    """Segment heat-transfer model of a ball screw, identified from runs.

    segments, dt_s: the full model's resolution; free: parameters to identify
    (names or aliases q, h, lambda, c, alpha; None = q, h, lambda, plus alpha when
    the runs' meta.json gives none and the base temperature varies); geometric_degree:
    0..4 or "auto" (CV/AIC); effects: Effect instances (host/learning/screw/effects.py);
    channel: errors.csv channel; ambient: include E_e from the base sensor (True/False, or "auto":
    the default structure of the runs' error reference, host/learning/screw/reference.py ambient_default);
    nut_weight: weight (µm per K) of the nut-temperature residuals in the
    identification (0 = nut sensor only reported); reduced_segments, reduced_dt_s:
    the firmware recurrence; feed_max_mm_min: top feed for the reduced state bound
    (None = 1.5 × the fastest training feed); base_sensor: the E_e sensor (None = the
    first sensor with role 'base'); base_ref: reference of the E_e term, "run_start"
    (each run's first base reading: every run starts in equilibrium and its cold
    geometric error is the one measured then) or "fixed" (``base_ref_C_``, the first
    training run's start, as a firmware with a fixed calibration temperature does);
    fit_window: (t_lo, t_hi) in s, fit only on error rows in that window (None = all);
    air: the air temperature the screw exchanges heat with: "auto" (the first sensor
    with role 'ambient'; else the base sensor, else a constant air, each fallback
    warned about in statistics.warnings), a sensor name, or "off" (constant air: the
    screw as a rise over a still air, the model before the air term); air_lag_s: the air sensor's own time
    constant (s, first order, from its datasheet or a step test; 0 = the
    sensor is the air): the screw exchanges heat with the air, not with the sensor's lagged reading, so the model
    takes the air as reading + air_lag_s · d(reading)/dt (the derivative of the reading averaged over
    AIR_LAG_SMOOTH_S); ftol: relative change of the cost that
    ends the identification (the discrepancy workflow's fold fits use a looser one).

    The runs' declared error reference (meta.json ``error_reference``) is read, not set: under a sensor
    reference E_m is over that sensor's temperature (S004 Eq. 9, host/learning/screw/reference.py); runs of
    different references are refused."""

    # Learned by fit (a trailing underscore, scikit-learn style) or read back by from_document
    geometry_: heat.ScrewGeometry
    density_: float
    values_: dict[str, float]  # every parameter by name, the effects' as "<effect>.<param>"
    params_: heat.ScrewParams
    effect_params_: dict[str, dict[str, float]]  # {effect: {param: value}}
    free_: list[str]
    ambient_: bool
    base_sensor_: str | None  # E_e's sensor; None: no E_e term
    base_ref_C_: float | None  # E_e's reference under base_ref "fixed" (None without E_e)
    nut_sensor_: str | None
    air_sensor_: str | None  # None: a constant air
    air_ref_C_: float | None  # the air's reference under base_ref "fixed" (None without an air sensor)
    air_source_: str
    air_lag_s_: float
    error_reference_: str  # "start" (raw errors) or the sensor the errors are referred to
    error_reference_C_: float | None  # its reference under base_ref "fixed" (None for "start")
    axis_: str | None
    geometric_: list[float]
    geometric_degree_: int
    envelope_: dict[str, Any] | None  # None: a document without one
    statistics_: dict[str, Any] | None
    training_: dict[str, Any] | None
    reduced_: dict[str, Any] | None  # thermal.reduced; None after fit(reduce=False) or from a document without it
    observer_: ScrewObserver | None  # thermal.observer (issue 21); None: the sensors do not allow one (observer_note_ says why)
    observer_note_: str | None
    # fit only: what the effects' reduced forms read (effect_sensor_, start_C_) and the position scale of the fit
    first_roles_: tuple[str | None, str | None]
    run_start_C_: dict[str, float]
    p_scale_: float

    def __init__(self, segments: int = 40, dt_s: float = 10.0, free: str | Sequence[str] | None = None,
                 geometric_degree: int | str = "auto", effects: Sequence[Effect] = (), channel: str | None = None,
                 ambient: bool | str = "auto", nut_weight: float = 0.0, reduced_segments: int = 12, reduced_dt_s: float = 10.0,
                 feed_max_mm_min: float | None = None, max_nfev: int = 200, base_sensor: str | None = None,
                 base_ref: str = "run_start", fit_window: tuple[float | None, float | None] | None = None, air: str = "auto",
                 ftol: float = 1e-12, air_lag_s: float = 0.0) -> None:
        self.segments = segments
        self.dt_s = dt_s
        self.free = free
        self.geometric_degree = geometric_degree
        self.effects = list(effects)
        self.channel = channel
        self.ambient = ambient
        self.nut_weight = nut_weight
        self.reduced_segments = reduced_segments
        self.reduced_dt_s = reduced_dt_s
        self.feed_max_mm_min = feed_max_mm_min
        self.max_nfev = max_nfev
        self.base_sensor = base_sensor
        self.base_ref = base_ref
        self.fit_window = fit_window
        self.air = air
        self.ftol = ftol
        self.air_lag_s = air_lag_s

    # ------------------------------------------------------------ parameters

    def _specs(self, base_params):
        specs = []
        for n in BASE_PARAMS:
            lo, hi, unit = BOUNDS[n]
            specs.append(ParamSpec(n, getattr(base_params, n), lo, hi, unit, positive=True))
        for eff in self.effects:
            for s in eff.parameters():
                specs.append(ParamSpec("%s.%s" % (eff.name, s.name), s.start, s.lo, s.hi, s.unit, s.positive))
        return specs

    def _values_dict(self, values, specs):
        return {s.name: float(v) for s, v in zip(specs, values)}

    def _split(self, allvals):
        base = heat.ScrewParams(**{k: allvals[k] for k in BASE_PARAMS}, density_kg_m3=self.density_)
        eff = {}
        for e in self.effects:
            pre = e.name + "."
            eff[e.name] = {k[len(pre):]: v for k, v in allvals.items() if k.startswith(pre)}
        return base, eff

    # ------------------------------------------------------------ simulation

    def _context(self, run, rows=None):
        return RunContext(run, self.geometry_, self.dt_s, rows=rows)

    def air_K(self, ctx: RunContext, delag: bool = True) -> np.ndarray | None:
        """Air temperature over the model's reference on the context's grid (None: constant air).

        The reference is the air at the run's start (base_ref "run_start": the screw starts in
        equilibrium at 0) or ``air_ref_C_`` (base_ref "fixed": it starts at the air's offset).
        delag: with ``air_lag_s_`` > 0, the air the sensor lags behind (:func:`delagged`); False: the
        sensor's reading itself (what the firmware's air input is)."""
        name = getattr(self, "air_sensor_", None)
        if name is None:
            return None
        if name not in ctx.run.temperatures.names:
            raise ValueError("%s: the model's air sensor %r is not in temperatures.csv" % (ctx.run_name, name))
        tt = ctx.run.temperatures
        col = tt.column(name)
        lag = getattr(self, "air_lag_s_", 0.0)
        if delag and lag > 0:
            col = delagged(tt.time_s, col, lag)
        air = np.interp(ctx.t_grid, tt.time_s, col)
        return air - self._start_reference(ctx.run, name, self.air_ref_C_)

    def simulate_context(self, ctx: RunContext, allvals: dict[str, float] | None = None) -> np.ndarray:
        """Segment rises (n_steps+1, M) on the context's grid."""
        allvals = self.values_ if allvals is None else allvals
        base, eff = self._split(allvals)
        scale = np.ones(ctx.n_steps)
        conv = None
        extra = np.zeros((ctx.n_steps, ctx.M))
        for e in self.effects:
            p = eff[e.name]
            if isinstance(e, HeatScaleHook):
                scale = scale * e.heat_scale(ctx, p)
            if isinstance(e, ConvectionHook):
                g = np.asarray(e.convection_mult(ctx, p), dtype=float)
                conv = g if conv is None else conv * g
            if isinstance(e, HeatHook):
                extra += e.heat_W(ctx, p) * ctx.dt[:, None]
        heat_J = heat.friction_heat_J(ctx.travel_mm, base) * scale[:, None] + extra
        return heat.simulate_segments(ctx.geometry, base, ctx.t_grid, heat_J, convection_mult=conv, edges_mm=ctx.edges_mm,
                                      air_K=self.air_K(ctx))

    def thermal_context(self, ctx: RunContext, allvals: dict[str, float] | None = None, rises: np.ndarray | None = None) -> np.ndarray:
        """E_m + E_e + effect outputs at the context's rows (µm), without the geometric part."""
        allvals = self.values_ if allvals is None else allvals
        base, eff = self._split(allvals)
        if rises is None:
            rises = self.simulate_context(ctx, allvals)
        E = 1e3 * base.alpha_per_K * np.sum(ctx.at_rows(rises) * ctx.overlap_mm, axis=1)
        if self.base_sensor_ is not None:
            if self.base_sensor_ not in ctx.run.temperatures.names:
                raise ValueError("%s: the model's base sensor %r is not in temperatures.csv" % (ctx.run_name, self.base_sensor_))
            E = E + 1e3 * base.alpha_per_K * (ctx.sensor_at_rows(self.base_sensor_)
                                              - self._start_reference(ctx.run, self.base_sensor_, self.base_ref_C_)) * ctx.positions_mm
        if self.error_reference_ != RAW:
            if self.error_reference_ not in ctx.run.temperatures.names:
                raise ValueError("%s: the model's error reference %r is not in temperatures.csv" % (ctx.run_name, self.error_reference_))
            rise = ctx.sensor_at_rows(self.error_reference_) - self._reference_start(ctx.run)
            E = E - errref.reference_um(base.alpha_per_K, rise, ctx.positions_mm)
        for e in self.effects:
            if isinstance(e, ErrorHook):
                E = E + e.error_um(ctx, eff[e.name])
        return E

    def _reference_start(self, run):
        """T_R,ref of a sensor-referenced model: the same start rule as E_e's base_ref."""
        return self._start_reference(run, self.error_reference_, self.error_reference_C_)

    def _start_reference(self, run: Run, sensor: str, fixed_C: float | None) -> float:
        """The reference temperature of a term reading ``sensor``: its first reading in ``run`` (base_ref "run_start")
        or ``fixed_C`` (base_ref "fixed": fit sets it for every sensor the model reads, from_document refuses a
        document without it)."""
        if self.base_ref == "run_start":
            return float(run.temperatures.column(sensor)[0])
        if fixed_C is None:
            raise ValueError("screw model: base_ref is 'fixed' but %s has no fixed reference temperature" % sensor)
        return float(fixed_C)

    def _reference_K(self, run, times_s):
        """T_R − T_R,ref at ``times_s``."""
        if self.error_reference_ not in run.temperatures.names:
            raise ValueError("%s: the model's error reference %r is not in temperatures.csv" % (run.path or run.name, self.error_reference_))
        return errref.reference_K(run, self.error_reference_, times_s, self._reference_start(run))

    def _check_inputs(self, ctx):
        """Every temperature the model reads is logged over the error rows (the air enters on the model's grid, where
        np.interp would silently hold the log's ends)."""
        for name in self.input_sensors_():
            if name not in ctx.run.temperatures.names:
                raise ValueError("%s: the model's sensor %r is not in temperatures.csv" % (ctx.run_name, name))
            ctx.sensor_at_rows(name)

    def _check_reference(self, run):
        check_model_reference(run, self.error_reference_)

    def geometric_um(self, positions_mm: ArrayLike) -> np.ndarray:
        P = np.asarray(positions_mm, dtype=float)
        return np.polynomial.polynomial.polyval(P, self.geometric_) if len(self.geometric_) else np.zeros_like(P)

    # ------------------------------------------------------------ fitting

    def _rows(self, run, index=None):
        rows = self._channel_rows(run)
        masks = getattr(self, "_row_masks", None)
        if masks is not None and index is not None and masks[index] is not None:
            m = masks[index]
            if m.shape != (len(run.errors),):
                raise ValueError("%s: row mask of %d rows for %d errors.csv rows" % (run.path or run.name, m.size, len(run.errors)))
            keep = m.copy() if rows is None else (m & np.isin(np.arange(m.size), rows))
            if not keep.any():
                raise ValueError("%s: no error rows selected to fit on" % (run.path or run.name))
            rows = np.flatnonzero(keep)
        if self.fit_window is None:
            return rows
        lo, hi = self.fit_window
        t = run.errors.time_s
        keep = (t >= (-np.inf if lo is None else lo)) & (t <= (np.inf if hi is None else hi))
        if rows is not None:
            keep &= np.isin(np.arange(t.size), rows)
        if not keep.any():
            raise ValueError("%s: no error rows in the fit window %s..%s s" % (run.path or run.name, lo, hi))
        return np.flatnonzero(keep)

    def _channel_rows(self, run):
        e = run.errors
        if e.channel is None:
            if self.channel:
                raise ValueError("%s: errors.csv has no 'channel' column but channel %r was asked for" % (run.path or run.name, self.channel))
            return None
        chans = e.channels()
        if self.channel is None:
            if len(chans) > 1:
                raise ValueError("%s: errors.csv has channels %s; choose one (--channel)" % (run.path or run.name, ", ".join(chans)))
            return None
        if self.channel not in chans:
            raise ValueError("%s: channel %r not in errors.csv (channels: %s)" % (run.path or run.name, self.channel, ", ".join(chans)))
        return np.flatnonzero(e.channel == self.channel)

    def _choose_air(self, runs):
        """(air sensor or None, how it was chosen, warnings) for ``self.air``."""
        first = runs[0]
        name0 = first.path or first.name
        notes = []
        if self.air == "off":
            return None, "off", notes
        if self.air != "auto":
            if not isinstance(self.air, str) or self.air not in first.temperatures.names:
                raise ValueError("%s: air sensor %r is not a column of temperatures.csv (columns: %s)"
                                 % (name0, self.air, ", ".join(first.temperatures.names)))
            name, source = self.air, "option"
        else:
            amb = [n for n in first.sensors_with_role("ambient") if n in first.temperatures.names]
            base = [n for n in first.sensors_with_role("base") if n in first.temperatures.names]
            if amb:
                name, source = amb[0], "role ambient"
            elif base:
                name, source = base[0], "base sensor (fallback)"
                notes.append("no sensor with role 'ambient': the screw exchanges heat with the base sensor %s instead of the air; "
                             "the lag of the base behind the air is then missing from the model" % name)
            else:
                notes.append("no sensor with role 'ambient' or 'base': the air is taken as constant (no air drift in the model)")
                return None, "constant (no ambient or base sensor)", notes
        missing = [r.path or r.name for r in runs if name not in r.temperatures.names]
        if missing:
            raise ValueError("air sensor %r missing from temperatures.csv of %s" % (name, ", ".join(missing)))
        return name, source, notes

    def _free_names(self, runs, meta_params):
        if self.free is not None:
            names = [_resolve(n.strip()) for n in (self.free.split(",") if isinstance(self.free, str) else self.free) if n.strip()]
            unknown = [n for n in names if n not in BASE_PARAMS]
            if unknown:
                raise ValueError("unknown screw parameter(s) %s in free= (known: %s, aliases %s)"
                                 % (", ".join(str(u) for u in unknown), ", ".join(BASE_PARAMS), ", ".join(ALIASES)))
            base = names
        else:
            base = ["q_J_per_mm", "h_W_m2K", "lambda_W_mK"]
            screw = runs[0].meta.get("screw") or {}
            given = any(k in screw for k in ("alpha_per_K", "alpha_um_per_m_K"))
            # alpha has its own signal in a temperature-linear term: E_e's base sensor, or the error reference's
            # sensor (its expansion is taken out of E_m), when that temperature moves
            linear = [s for s in (self.base_sensor_, None if self.error_reference_ == RAW else self.error_reference_) if s]
            spans = [np.ptp(r.temperatures.column(s)) for s in linear for r in runs if s in r.temperatures.names]
            if not given and spans and max(spans) >= BASE_ALPHA_MIN_SPAN_K:
                base.append("alpha_per_K")
        return base + ["%s.%s" % (e.name, s.name) for e in self.effects for s in e.parameters()]

    def fit(self, runs: Sequence[Run], row_masks: Sequence[np.ndarray | None] | None = None, start: dict[str, float] | None = None, reduce: bool = True) -> ScrewModel:
        """Identify the parameters from one or more runs (host.data.runs.Run).

        row_masks: per run a boolean array over its errors.csv rows to fit on (None: all; the discrepancy
        workflow's held-out folds); start: {parameter: value} to start the search from (a previous fit's
        ``values_``; unknown names ignored); reduce: build the firmware's reduced form and its reduction
        certificate (the workflow's fold fits skip it, the model it exports has it)."""
        self._row_masks = None if row_masks is None else [None if m is None else np.asarray(m, dtype=bool) for m in row_masks]
        if self._row_masks is not None and len(self._row_masks) != len(runs):
            raise ValueError("row_masks: %d masks for %d runs" % (len(self._row_masks), len(runs)))
        self._start = dict(start or {})
        if not runs:
            raise ValueError("no runs to fit on")
        if self.base_ref not in ("run_start", "fixed"):
            raise ValueError("base_ref must be 'run_start' or 'fixed' (got %r)" % (self.base_ref,))
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ValueError("effects must be Effect instances (got %r)" % (e,))
        if self.ambient not in (True, False, "auto"):
            raise ValueError("ambient must be on, off or auto (got %r)" % (self.ambient,))
        if not (isinstance(self.air_lag_s, (int, float)) and not isinstance(self.air_lag_s, bool)
                and 0 <= self.air_lag_s <= MAX_AIR_LAG_S):
            raise ValueError("air_lag_s must be a number of seconds in 0..%g (got %r)" % (MAX_AIR_LAG_S, self.air_lag_s))
        self.air_lag_s_ = float(self.air_lag_s)
        self.error_reference_ = common_error_reference(runs)
        if self.error_reference_ != RAW:
            errref.check_reference_sensor(runs, self.error_reference_)
            self.error_reference_C_ = float(runs[0].temperatures.column(self.error_reference_)[0])
        else:
            self.error_reference_C_ = None
        self.ambient_ = errref.ambient_default(self.error_reference_) if self.ambient == "auto" else bool(self.ambient)
        geo = heat.ScrewGeometry.from_meta(runs[0].meta, self.segments) if isinstance(runs[0].meta.get("screw"), dict) else None
        if geo is None:
            raise ValueError("%s: meta.json has no 'screw' block (length_mm, diameter_mm, lead_mm, fixed_end_mm)" % (runs[0].path or runs[0].name))
        for r in runs:
            check_screw_run(r, geo, require_nut=self.nut_weight > 0)
            s0, s = runs[0].meta["screw"], r.meta.get("screw") or {}
            for k in ("length_mm", "diameter_mm", "fixed_end_mm"):
                if float(s.get(k, 0)) != float(s0.get(k, 0)):
                    raise ValueError("%s: screw.%s = %r differs from %r in %s; fit one screw at a time"
                                     % (r.path or r.name, k, s.get(k), s0.get(k), runs[0].path or runs[0].name))
        self.geometry_ = geo
        self.axis_ = runs[0].meta.get("axis")
        meta_params = heat.ScrewParams.from_meta(runs[0].meta, **{k: v for k, v in START.items() if k not in (runs[0].meta.get("screw") or {})})
        self.density_ = meta_params.density_kg_m3
        if self.base_sensor and self.base_sensor not in runs[0].temperatures.names:
            raise ValueError("%s: base sensor %r is not a column of temperatures.csv (columns: %s)"
                             % (runs[0].path or runs[0].name, self.base_sensor, ", ".join(runs[0].temperatures.names)))
        bases = [self.base_sensor] if self.base_sensor else runs[0].sensors_with_role("base")
        self.base_sensor_ = next((b for b in bases if b in runs[0].temperatures.names), None) if self.ambient_ else None
        if self.base_sensor_ is not None:
            missing = [r.path or r.name for r in runs if self.base_sensor_ not in r.temperatures.names]
            if missing:
                raise ValueError("base sensor %r missing from temperatures.csv of %s" % (self.base_sensor_, ", ".join(missing)))
            self.base_ref_C_ = float(runs[0].temperatures.column(self.base_sensor_)[0])
        else:
            self.base_ref_C_ = None
        # the nut sensor is not a model input: reported against the simulated screw under the nut when present
        self.nut_sensor_ = next((n for n in runs[0].sensors_with_role("nut") if n in runs[0].temperatures.names), None)
        self.air_sensor_, self.air_source_, air_notes = self._choose_air(runs)
        self.air_ref_C_ = float(runs[0].temperatures.column(self.air_sensor_)[0]) if self.air_sensor_ else None
        specs_all = self._specs(meta_params)
        free = self._free_names(runs, meta_params)
        self.free_ = free
        fixed = {s.name: s.start for s in specs_all if s.name not in free}
        specs = [s for s in specs_all if s.name in free]
        if self._start:  # a previous fit's values, inside the bounds
            specs = [ParamSpec(s.name, min(max(float(self._start[s.name]), s.lo), s.hi) if s.name in self._start and
                               (not s.positive or self._start[s.name] > 0) else s.start, s.lo, s.hi, s.unit, s.positive)
                     for s in specs]
        ctxs = [self._context(r, self._rows(r, i)) for i, r in enumerate(runs)]
        # what the effects' reduced forms read (effects.py reduce): the first run's role sensors and start readings
        self.first_roles_ = (ctxs[0].base_sensor, ctxs[0].ambient_sensor)
        self.run_start_C_ = {n: float(runs[0].temperatures.column(n)[0]) for n in runs[0].temperatures.names}
        for c in ctxs:
            self._check_inputs(c)
        for e in self.effects:
            if isinstance(e, CheckHook):
                e.check(ctxs)
        y = np.concatenate([c.measured_um for c in ctxs])
        if not np.all(np.isfinite(y)):
            raise ValueError("errors.csv contains non-finite values")
        P = np.concatenate([c.positions_mm for c in ctxs])
        self.p_scale_ = float(max(np.max(np.abs(P)), 1.0))
        nut_meas = [c.nut_rise_measured() for c in ctxs] if self.nut_weight > 0 else None
        if nut_meas is not None:  # the nut's temperature over the reference, as the state is
            nut_meas = [m + (self.air_K(c) if self.air_sensor_ else 0.0) for m, c in zip(nut_meas, ctxs)]

        def thermal_all(values):
            allv = dict(fixed)
            allv.update(self._values_dict(values, specs))
            out, nut = [], []
            for i, c in enumerate(ctxs):
                rises = self.simulate_context(c, allv)
                out.append(self.thermal_context(c, allv, rises))
                if nut_meas is not None:
                    nut.append(self.nut_weight * (nut_meas[i] - c.nut_rise_predicted(rises)))
            return np.concatenate(out), (np.concatenate(nut) if nut else np.zeros(0))

        def make_residual(degree):
            Phi = np.vander(P / self.p_scale_, degree + 1, increasing=True)
            Q, _ = np.linalg.qr(Phi)

            def residual(values):
                f, nut = thermal_all(values)
                z = y - f
                return np.concatenate([z - Q @ (Q.T @ z), nut])

            return residual, Phi

        top = MAX_GEOMETRIC_DEGREE if self.geometric_degree == "auto" else int(self.geometric_degree)
        if not 0 <= top <= MAX_GEOMETRIC_DEGREE:
            raise ValueError("geometric_degree must be 0..%d or 'auto' (got %r)" % (MAX_GEOMETRIC_DEGREE, self.geometric_degree))
        unknowns = len(specs) + top + 1
        if y.size <= unknowns:
            raise ValueError("%s: %d error row%s to identify %d unknowns (%d thermal parameter%s %s and %d geometric "
                             "coefficients up to degree %d); the fit needs more rows than unknowns: more sweeps, or "
                             "fewer free parameters (--option free=...) or a lower geometric_degree"
                             % (", ".join(c.run_name for c in ctxs), y.size, "" if y.size == 1 else "s", unknowns,
                                len(specs), "" if len(specs) == 1 else "s", ",".join(s.name for s in specs) or "-",
                                top + 1, top))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IdentifiabilityWarning)
            res = fit_parameters(make_residual(top)[0], specs, max_nfev=self.max_nfev, n_linear=top + 1, ftol=self.ftol) if specs else None
        values = res["values"] if res else np.zeros(0)
        degree = top
        degree_scores = None
        if self.geometric_degree == "auto":
            f, _ = thermal_all(values)
            degree, degree_scores = choose_geometric_degree(P, y - f, MAX_GEOMETRIC_DEGREE, len(specs))
            if degree != top and specs:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", IdentifiabilityWarning)
                    specs_start = [ParamSpec(s.name, v, s.lo, s.hi, s.unit, s.positive) for s, v in zip(specs, values)]
                    res = fit_parameters(make_residual(degree)[0], specs_start, max_nfev=self.max_nfev, n_linear=degree + 1,
                                         ftol=self.ftol)
                values = res["values"]
        for w in caught:
            warnings.warn(str(w.message), IdentifiabilityWarning, stacklevel=2)
        allv = dict(fixed)
        allv.update(self._values_dict(values, specs))
        self.values_ = allv
        self.params_, self.effect_params_ = self._split(allv)
        f, _ = thermal_all(values)
        Phi = np.vander(P / self.p_scale_, degree + 1, increasing=True)
        beta, *_ = np.linalg.lstsq(Phi, y - f, rcond=None)
        self.geometric_ = list(beta / self.p_scale_ ** np.arange(degree + 1))
        self.geometric_degree_ = degree
        pred = f + self.geometric_um(P)
        stats = {"rmse_um": float(np.sqrt(np.mean((y - pred) ** 2))), "max_abs_residual_um": float(np.max(np.abs(y - pred))),
                 "runs": [], "parameters": {}, "warnings": (res["warnings"] if res else []) + air_notes,
                 "flat_directions": res["flat"] if res else [],
                 "geometric_degree_scores": degree_scores, "nfev": res["nfev"] if res else 0}
        for s, v, sd, rel in zip(specs, values, res["std"] if res else [], res["rel_std"] if res else []):
            stats["parameters"][s.name] = {"value": float(v), "std": float(sd), "rel_std": float(rel), "unit": s.unit}
        stats["implausible"] = implausible_parameters({s.name: float(v) for s, v in zip(specs, values)})
        stats["warnings"] += [i["warning"] for i in stats["implausible"]]
        for n, v in fixed.items():
            stats["parameters"][n] = {"value": float(v), "std": 0.0, "rel_std": 0.0, "fixed": True,
                                     "unit": next(s.unit for s in specs_all if s.name == n)}
        off = 0
        for c in ctxs:
            r = y[off:off + c.n_rows] - pred[off:off + c.n_rows]
            off += c.n_rows
            rises = self.simulate_context(c)
            nut_rmse = None
            if c.nut_sensor is not None:
                air = self.air_K(c)
                nut_rmse = float(np.sqrt(np.mean((c.nut_rise_measured() + (0.0 if air is None else air) - c.nut_rise_predicted(rises)) ** 2)))
            stats["runs"].append({"run": c.run_name, "rows": int(c.n_rows), "rmse_um": float(np.sqrt(np.mean(r ** 2))),
                                  "max_abs_residual_um": float(np.max(np.abs(r))), "nut_rise_rmse_K": nut_rmse})
        self.statistics_ = stats
        self.training_ = {"runs": [c.run_name for c in ctxs], "free": free, "segments": self.segments, "dt_s": self.dt_s,
                          "geometric_degree": self.geometric_degree, "nut_weight": self.nut_weight, "channel": self.channel,
                          "effects": [e.name for e in self.effects], "fit_window_s": self.fit_window, "air": self.air,
                          "ambient": self.ambient, "error_reference": self.error_reference_, "air_lag_s": self.air_lag_s_}
        motions = [run_motion(r) for r in runs]  # check_screw_run refused a run without
        feeds = np.concatenate([m.feed_mm_min for m in motions])
        P_all = np.concatenate([P] + [np.r_[m.from_mm, m.to_mm] for m in motions])
        strokes = [float(r.meta["stroke_mm"]) for r in runs if isinstance(r.meta.get("stroke_mm"), (int, float))]
        p_lo, p_hi = float(P_all.min()), float(P_all.max())
        if strokes:  # the firmware is asked for offsets anywhere on the stroke, not only where the laser measured
            p_lo, p_hi = min(p_lo, 0.0), max(p_hi, min(strokes))
        envelope: dict[str, Any] = {"position_mm": [p_lo, p_hi], "feed_mm_min": [float(feeds.min()), float(feeds.max())]}
        self.envelope_ = envelope
        if self.base_sensor_ is not None:
            tb = np.concatenate([r.temperatures.column(self.base_sensor_) for r in runs])
            # E_e is linear in the base temperature (alpha * dT * P), so a margin beyond the training range is
            # physics, not extrapolation of a regression: BASE_ENVELOPE_MARGIN_K covers a shop's daily swing.
            envelope["temperature_C"] = {self.base_sensor_: [float(tb.min()) - BASE_ENVELOPE_MARGIN_K,
                                                             float(tb.max()) + BASE_ENVELOPE_MARGIN_K]}
            envelope["temperature_margin_K"] = BASE_ENVELOPE_MARGIN_K
        if self.air_sensor_ is not None and self.air_sensor_ != self.base_sensor_:
            ta = np.concatenate([r.temperatures.column(self.air_sensor_) for r in runs])
            envelope.setdefault("temperature_C", {})[self.air_sensor_] = [float(ta.min()) - BASE_ENVELOPE_MARGIN_K,
                                                                          float(ta.max()) + BASE_ENVELOPE_MARGIN_K]
            envelope["temperature_margin_K"] = BASE_ENVELOPE_MARGIN_K
        if self.error_reference_ != RAW and self.error_reference_ not in envelope.get("temperature_C", {}):
            tr = np.concatenate([r.temperatures.column(self.error_reference_) for r in runs])
            envelope.setdefault("temperature_C", {})[self.error_reference_] = [float(tr.min()) - BASE_ENVELOPE_MARGIN_K,
                                                                               float(tr.max()) + BASE_ENVELOPE_MARGIN_K]
            envelope["temperature_margin_K"] = BASE_ENVELOPE_MARGIN_K
        if not reduce:
            self.reduced_ = None
            self.observer_, self.observer_note_ = None, "no observer: the model has no reduced form (fit with reduce=False)"
            return self
        from host.learning.screw.reduced import build_reduced
        self.reduced_ = reduced = build_reduced(self, self.reduced_segments, self.reduced_dt_s,
                                                feed_max_mm_min=self.feed_max_mm_min or 1.5 * float(feeds.max()))
        envelope["state_K"] = [0.0, reduced["state_max_K"]]
        ee = reduced.get("base_sensor")
        if ee is not None and ee not in envelope.get("temperature_C", {}):  # an effect's sensor (ambient_expansion)
            te = np.concatenate([r.temperatures.column(ee) for r in runs])
            envelope.setdefault("temperature_C", {})[ee] = [float(te.min()) - BASE_ENVELOPE_MARGIN_K,
                                                            float(te.max()) + BASE_ENVELOPE_MARGIN_K]
            envelope["temperature_margin_K"] = BASE_ENVELOPE_MARGIN_K
        from host.learning.screw.reduced import reduction_certificate
        reduced["reduction_error_um"] = reduction_certificate(self, [c.run for c in ctxs])
        # the reduced state recovered from the nut sensor at power-on (issue 21), or why the sensors do not allow it
        from host.learning.screw.observer import fit_observer
        self.observer_, self.observer_note_ = fit_observer(self, [c.run for c in ctxs])
        obs = self.observer_
        if obs is not None and obs.sensor not in envelope.get("temperature_C", {}):
            # the observer's nut sensor is a table input (its start, issue 21): its certified envelope is its training
            # range widened like the other sensors' (models_export.exact reads it)
            tn = np.concatenate([c.run.temperatures.column(obs.sensor) for c in ctxs])
            envelope.setdefault("temperature_C", {})[obs.sensor] = [float(tn.min()) - BASE_ENVELOPE_MARGIN_K,
                                                                    float(tn.max()) + BASE_ENVELOPE_MARGIN_K]
        return self

    # ------------------------------------------------------------ prediction

    def predict(self, run: Run) -> np.ndarray:
        """Predicted error (µm) at every row of ``run.errors``: the run's own motion and
        base temperature are simulated from a cold (ambient) screw at the run's start."""
        if not hasattr(self, "geometry_"):
            raise ValueError("screw model: predict before fit (fit(runs) first, or load a fitted document)")
        check_screw_run(run, self.geometry_, require_nut=False)
        self._check_reference(run)
        ctx = self._context(run)
        self._check_inputs(ctx)
        out = self.thermal_context(ctx) + self.geometric_um(ctx.positions_mm)
        bad = np.flatnonzero(~np.isfinite(out))
        if bad.size:
            raise ValueError("%s: the prediction at errors.csv row %d (%g s) is NaN/inf: a temperature the model reads "
                             "(base sensor %s) is NaN/inf" % (ctx.run_name, bad[0], run.errors.time_s[bad[0]], self.base_sensor_))
        return out

    def predict_grid(self, run: Run, positions_mm: ArrayLike, times_s: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Thermal + geometric error on a time × position grid (default times: the model grid)."""
        check_screw_run(run, self.geometry_, require_nut=False)
        ctx = self._context(run)
        rises = self.simulate_context(ctx)
        t = ctx.t_grid if times_s is None else np.asarray(times_s, dtype=float)
        R = heat.interp_rows(t, ctx.t_grid, rises)
        P = np.asarray(positions_mm, dtype=float)
        E = heat.thermal_error_um(ctx.edges_mm, R[:, None, :], P[None, :], self.geometry_.fixed_end_mm, self.params_.alpha_per_K)
        if self.base_sensor_ is not None:
            tb = np.interp(t, run.temperatures.time_s, run.temperatures.column(self.base_sensor_))
            ref = self._start_reference(run, self.base_sensor_, self.base_ref_C_)
            E = E + 1e3 * self.params_.alpha_per_K * (tb - ref)[:, None] * P[None, :]
        if self.error_reference_ != RAW:
            self._check_reference(run)
            E = E - errref.reference_um(self.params_.alpha_per_K, self._reference_K(run, t)[:, None], P[None, :])
        return t, E + self.geometric_um(P)[None, :]

    # ------------------------------------------------------------ document

    def to_document(self) -> dict[str, Any]:
        g = self.geometry_
        thermal = {
            "parameters": {k: float(v) for k, v in self.values_.items()},
            "density_kg_m3": self.density_,
            "free": list(self.free_),
            "segments": int(g.segments),
            "dt_s": float(self.dt_s),
            "geometry": {"length_mm": g.length_mm, "diameter_mm": g.diameter_mm, "fixed_end_mm": g.fixed_end_mm, "bore_mm": g.bore_mm},
            "effects": [{"name": e.name, "settings": e.to_document()} for e in self.effects],
            "base_sensor": self.base_sensor_,
            "base_ref_C": self.base_ref_C_,
            "base_ref": self.base_ref,
            "nut_sensor": self.nut_sensor_,
            "air_sensor": self.air_sensor_,
            "air_ref_C": self.air_ref_C_,
            "air_source": self.air_source_,
            "air_lag_s": self.air_lag_s_,
            "error_reference": self.error_reference_,
            "error_reference_C": self.error_reference_C_,
            "reduced": self.reduced_,
            "observer": None if (obs := getattr(self, "observer_", None)) is None else obs.to_document(),
            "observer_note": getattr(self, "observer_note_", None),
        }
        return {
            "format": FORMAT,
            "kind": "screw",
            "method": "screw",
            "axis": self.axis_,
            "channel": self.channel,
            "sensors": self.input_sensors_(),
            "error_reference": self.error_reference_,
            "reference_C": {n: r for n, r in ((self.error_reference_, self.error_reference_C_), (self.base_sensor_, self.base_ref_C_),
                                              (self.air_sensor_, self.air_ref_C_), self._reduced_base())
                            if n is not None and n != RAW},
            "geometric": {"degree": int(self.geometric_degree_), "coefficients_um": [float(c) for c in self.geometric_]},
            "thermal": thermal,
            "envelope": self.envelope_,
            "statistics": self.statistics_,
            "training": self.training_,
        }

    def input_sensors_(self) -> list[str]:
        """The temperatures prediction reads: the base sensor (E_e), the air sensor, a sensor only an effect reads
        (ambient_expansion without E_e: the reduced form's base term), then the error reference's sensor."""
        out = [self.base_sensor_] if self.base_sensor_ else []
        for name in (self.air_sensor_, self._reduced_base()[0], None if self.error_reference_ == RAW else self.error_reference_):
            if name and name not in out:
                out.append(name)
        return out

    def _reduced_base(self):
        """(sensor, reference) of the reduced form's base term when an effect put it there, else (None, None)."""
        red = getattr(self, "reduced_", None) or {}
        name = red.get("base_sensor")
        if name is None or name == self.base_sensor_:
            return None, None
        return name, red.get("base_ref_C")

    def reduced_form(self) -> dict[str, Any]:
        """``reduced_``, the thermal.reduced block; ValueError when the model has none (fit(reduce=False), or a
        document without it)."""
        if self.reduced_ is None:
            raise ValueError("screw model: no reduced (firmware) form: fit with reduce=True, or load a document with "
                             "thermal.reduced")
        return self.reduced_

    def effect_sensor_(self, effect: Effect) -> str | None:
        """The sensor an effect reading the machine's surroundings reads on the training runs (base, else ambient)."""
        base, ambient = getattr(self, "first_roles_", (self.base_sensor_, self.air_sensor_))
        return base or ambient

    def start_C_(self, name: str) -> float:
        """The first training run's first reading of ``name`` (degC)."""
        return self.run_start_C_[name]

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> ScrewModel:
        from host.learning.documents import ModelFormatError

        th = doc.get("thermal") or {}
        for where, block in (("thermal", th), ("thermal.geometry", th.get("geometry") if isinstance(th, dict) else None),
                             ("thermal.parameters", th.get("parameters") if isinstance(th, dict) else None),
                             ("geometric", doc.get("geometric"))):
            if block is not None and not isinstance(block, dict):
                raise ModelFormatError("screw model document: field '%s' must be an object, found %s" % (where, type(block).__name__))
        effects_doc = th.get("effects", [])
        if not isinstance(effects_doc, list) or not all(isinstance(e, dict) and isinstance(e.get("name"), str) for e in effects_doc):
            raise ModelFormatError("screw model document: thermal.effects must be a list of {name, settings} objects")
        unknown = [e["name"] for e in effects_doc if e["name"] not in EFFECTS]
        if unknown:
            raise ModelFormatError("screw model document: thermal.effects has unknown effect %r (known: %s)" % (unknown[0], ", ".join(EFFECTS)))
        try:
            effects = [EFFECTS[e["name"]].from_document(e.get("settings") or {}) for e in th.get("effects", [])]
            if not (int(th["segments"]) >= 1 and float(th["dt_s"]) > 0):
                raise ValueError("thermal.segments must be >= 1 and thermal.dt_s > 0")
            m = cls(segments=int(th["segments"]), dt_s=float(th["dt_s"]), effects=effects, channel=doc.get("channel"),
                    ambient=th.get("base_sensor") is not None, base_ref=th.get("base_ref", "fixed"))
            geo = th["geometry"]
            m.geometry_ = heat.ScrewGeometry(float(geo["length_mm"]), float(geo["diameter_mm"]), float(geo.get("fixed_end_mm", 0.0)),
                                             int(th["segments"]), float(geo.get("bore_mm", 0.0)))
            m.density_ = float(th["density_kg_m3"])
            m.values_ = {k: float(v) for k, v in th["parameters"].items()}
            missing = [k for k in BASE_PARAMS if k not in m.values_]
            if missing:
                raise KeyError("thermal.parameters." + missing[0])
            m.params_, m.effect_params_ = m._split(m.values_)
            m.free_ = list(th.get("free", []))
            m.base_sensor_ = th.get("base_sensor")
            m.base_ref_C_ = th.get("base_ref_C")
            m.nut_sensor_ = th.get("nut_sensor")
            # documents written before the air term have no air_sensor: their screw ran over a still air
            m.air_sensor_ = th.get("air_sensor")
            m.air_ref_C_ = th.get("air_ref_C")
            m.air_source_ = th.get("air_source", "off" if m.air_sensor_ is None else "document")
            m.air = "auto" if m.air_sensor_ else "off"
            # documents written before the air sensor's lag was modelled: the reading is the air
            m.air_lag_s_ = float(th.get("air_lag_s", 0.0))
            if not 0 <= m.air_lag_s_ <= MAX_AIR_LAG_S:
                raise ValueError("thermal.air_lag_s must be 0..%g s" % MAX_AIR_LAG_S)
            m.air_lag_s = m.air_lag_s_
            if m.base_sensor_ is not None and m.base_ref == "fixed" and not isinstance(m.base_ref_C_, (int, float)):
                raise KeyError("thermal.base_ref_C")
            if m.air_sensor_ is not None and m.base_ref == "fixed" and not isinstance(m.air_ref_C_, (int, float)):
                raise KeyError("thermal.air_ref_C")
            # documents written before the error reference was data: raw errors ("start")
            m.error_reference_ = th.get("error_reference", RAW)
            m.error_reference_C_ = th.get("error_reference_C")
            if m.error_reference_ != RAW and not isinstance(m.error_reference_, str):
                raise TypeError("thermal.error_reference must be \"start\" or a sensor name, found %r" % (m.error_reference_,))
            if m.error_reference_ != RAW and m.base_ref == "fixed" and not isinstance(m.error_reference_C_, (int, float)):
                raise KeyError("thermal.error_reference_C")
            m.ambient_ = m.base_sensor_ is not None
            m.reduced_ = th.get("reduced")
            # documents written before the screw observer (issue 21) have none: the board starts the screw cold
            m.observer_note_ = th.get("observer_note")
            m.observer_ = None
            if th.get("observer") is not None:
                from host.learning.screw.observer import ScrewObserver
                if not isinstance(m.reduced_, dict):
                    raise KeyError("thermal.reduced (thermal.observer estimates its state)")
                m.observer_ = ScrewObserver.from_document(th["observer"], int(m.reduced_["segments"]))
            gm = doc.get("geometric") or {"degree": 0, "coefficients_um": []}
            m.geometric_ = [float(c) for c in gm["coefficients_um"]]
            m.geometric_degree_ = int(gm["degree"])
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ModelFormatError("screw model document: missing or invalid field %s" % exc)
        m.axis_ = doc.get("axis")
        m.envelope_ = doc.get("envelope")
        m.statistics_ = doc.get("statistics")
        m.training_ = doc.get("training")
        return m


def choose_geometric_degree(P: np.ndarray, resid: np.ndarray, max_degree: int, n_thermal: int) -> tuple[int, dict[str, Any]]:
    """Degree 0..max_degree of the cold polynomial for the residual after the thermal part.

    Uses host.learning.empirical.geometric (leave-one-out CV over position-averaged points); when it
    refuses the data (e.g. fewer than 4 positions), AIC = n·ln(RSS/n) + 2(d+1+n_thermal) here,
    and the returned method names why. Returns (degree, scores)."""
    from host.learning.empirical import EmpiricalDataError
    from host.learning.empirical.geometric import GeometricPolynomial

    try:
        gp = GeometricPolynomial(max_degree=max_degree, criterion="cv").fit(P, resid)
        return int(gp.degree_), {"method": "host.empirical.geometric (cv)", "scores": gp.scores_}
    except EmpiricalDataError as exc:
        note = str(exc)
    n = P.size
    u = P / max(np.max(np.abs(P)), 1.0)
    scores = []
    for d in range(max_degree + 1):
        V = np.vander(u, d + 1, increasing=True)
        beta, *_ = np.linalg.lstsq(V, resid, rcond=None)
        rss = float(np.sum((resid - V @ beta) ** 2))
        scores.append({"degree": d, "aic": float(n * np.log(max(rss, 1e-300) / n) + 2 * (d + 1 + n_thermal))})
    best = min(scores, key=lambda s: (s["aic"], s["degree"]))
    return best["degree"], {"method": "aic (%s)" % note, "scores": scores}
