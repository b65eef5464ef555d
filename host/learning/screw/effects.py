"""Extension point of the screw model: effects that add parameters and hook into the
heat input, the convection, or the error output (docs/screw-model.md, "Effects").

An effect is an object with

- ``name``: unique key (also its document key);
- ``parameters()``: list of :class:`ParamSpec` (the effect's own parameters; the
  model namespaces them as ``"<name>.<param>"`` and identifies them with the
  base parameters);
- optional hooks, each receiving the per-run :class:`host.learning.screw.screwmodel.RunContext`
  and ``p``, a dict of the effect's parameter values by short name:
    ``heat_W(ctx, p)``            -> (n_steps, M) extra power [W] into the segments;
    ``heat_scale(ctx, p)``        -> (n_steps,) factor on the friction heat;
    ``convection_mult(ctx, p)``   -> (n_steps,) or (n_steps, M) factor on h·S;
    ``error_um(ctx, p)``          -> (n_rows,) extra error at the run's error rows;
- optional ``check(contexts)``: raise ValueError when the runs cannot show the
  effect at all (e.g. reversal error without bidirectional sweeps); the protocols HeatHook,
  HeatScaleHook, ConvectionHook, ErrorHook and CheckHook below are the hooks' types;
- ``to_document()`` -> dict and a ``from_document(d)`` classmethod for settings
  that are not parameters (reference speeds, sensor names);
- ``reduce(model, p, red, C)``: the effect's reduced (firmware) form: it adds its
  terms to ``red``, the ``thermal.reduced`` block being built (C: the reduced
  segments' heat capacities, J/K), or raises :class:`NoReducedForm` saying why the
  firmware's recurrence cannot carry it (docs/screw-model.md, "Reduced forms of the effects"); Effect's own
  raises it, so an effect without a reduced form is listed in the block's ``omitted_effects``.

Register a new effect class in ``EFFECTS`` (or pass instances to ScrewModel(effects=...)).
The five effects below are the catalog the discrepancy workflow (issue 5) tests.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from dataclasses import dataclass

import numpy as np

if TYPE_CHECKING:
    from host.learning.screw.context import RunContext
    from host.learning.screw.screwmodel import ScrewModel


class NoReducedForm(ValueError):
    """The firmware's recurrence has no place for an effect (the message says why)."""


# Travel per step <-> mean speed: v [m/min] = U [mm] / dt [s] * 60 / 1000, so a power k·v [W] over a step
# of dt seconds is the energy k·U·0.06 [J]: linear in the step's total travel whatever dt is.
J_PER_W_PER_M_MIN_PER_MM = 0.06


@dataclass
class ParamSpec:
    """A parameter: value > 0 are identified in log space (``positive``), others linearly."""

    name: str
    start: float
    lo: float
    hi: float
    unit: str = ""
    positive: bool = True


class Effect:
    name: str = "effect"

    def parameters(self) -> list[ParamSpec]:
        return []

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        """An effect that defines no reduced form has none: the reduced block lists it in ``omitted_effects``."""
        raise NoReducedForm("the effect defines no reduce(): the firmware's recurrence has no form of it")

    def to_document(self) -> dict[str, Any]:
        return {}

    @classmethod
    def from_document(cls, d: dict[str, Any]) -> Effect:
        return cls(**d)

    def __repr__(self) -> str:
        return "%s(%s)" % (type(self).__name__, self.to_document())


class BearingHeat(Effect):
    """Fixed-end bearing friction: power k·v into the fixed-end segment while the
    axis moves (v = mean feed of the step in m/min)."""

    name = "bearing_heat"

    def parameters(self) -> list[ParamSpec]:
        return [ParamSpec("W_per_m_min", 0.1, 0.0, 50.0, "W/(m/min)", positive=False)]

    def heat_W(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray:
        out = np.zeros((ctx.n_steps, ctx.M))
        out[:, 0] = p["W_per_m_min"] * ctx.step_speed_m_min
        return out

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        # energy k·U·0.06 J per step into the fixed-end segment: a temperature increment linear in the step's travel
        heat = red.setdefault("travel_heat_K_per_mm", [0.0] * len(C))
        heat[0] += p["W_per_m_min"] * J_PER_W_PER_M_MIN_PER_MM / float(C[0])


class SpeedDependentHeat(Effect):
    """Friction heat per mm grows with speed: q·(1 + k·(v/v_ref − 1))."""

    name = "speed_dependent_heat"

    def __init__(self, v_ref_m_min: float = 8.0) -> None:
        self.v_ref_m_min = float(v_ref_m_min)

    def parameters(self) -> list[ParamSpec]:
        return [ParamSpec("k", 0.0, -0.9, 5.0, "1", positive=False)]

    def heat_scale(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray:
        v = ctx.step_speed_m_min
        return np.where(v > 0, 1.0 + p["k"] * (v / self.v_ref_m_min - 1.0), 1.0)

    def to_document(self) -> dict[str, Any]:
        return {"v_ref_m_min": self.v_ref_m_min}

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        # q·u_i·(1 + k(v/v_ref − 1)) with v = U·0.06/dt (U: the step's total travel, mm): the friction heat B_i·u_i
        # times a factor linear in U, the same for every segment (firmware: the step's effective travel u_i·g(U))
        k = p["k"]
        dt = float(red["dt_s"])
        per_mm = k * J_PER_W_PER_M_MIN_PER_MM / (self.v_ref_m_min * dt)
        g0 = 1.0 - k
        umax = float(red["feed_max_mm_min"]) / 60.0 * dt
        if g0 < 0 or g0 + per_mm * umax < 0:
            # a negative friction heat (the full model has it too) has no certified state bound in the firmware
            raise NoReducedForm("the friction heat factor 1 + k(v/v_ref - 1) = %.3g at rest and %.3g at the top feed "
                                "(k = %.3g) is negative: the firmware's state bound needs heat >= 0"
                                % (g0, g0 + per_mm * umax, k))
        red["heat_scale0"] = g0
        red["heat_scale_per_mm"] = per_mm


class MovingConvection(Effect):
    """Forced convection while the screw turns: h·(1 + k·v/v_ref)."""

    name = "moving_convection"

    def __init__(self, v_ref_m_min: float = 8.0) -> None:
        self.v_ref_m_min = float(v_ref_m_min)

    def parameters(self) -> list[ParamSpec]:
        return [ParamSpec("k", 0.1, 0.0, 20.0, "1", positive=False)]

    def convection_mult(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray:
        return 1.0 + p["k"] * ctx.step_speed_m_min / self.v_ref_m_min

    def to_document(self) -> dict[str, Any]:
        return {"v_ref_m_min": self.v_ref_m_min}

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        # the extra loss over a step, k·(v/v_ref)·h·S_i/C_i·dt·(T_i − a) with v = U·0.06/dt, is D_i·U·(T_i − a):
        # D_i = k·0.06·h·S_i/(v_ref·C_i) per mm of the step's travel (dt cancels), explicit in the step (the state
        # and the air at its start)
        from host.learning.screw import heat
        _, _, H = heat.segment_properties(red["edges_mm"], model.geometry_.diameter_mm, model.params_, model.geometry_.bore_mm)
        D = p["k"] * J_PER_W_PER_M_MIN_PER_MM * H / (self.v_ref_m_min * np.asarray(C, dtype=float))
        umax = float(red["feed_max_mm_min"]) / 60.0 * float(red["dt_s"])
        A = np.asarray(red["A"], dtype=float)
        bad = [i for i in range(len(C)) if not 0.0 <= D[i] * umax <= A[i][i]]
        if bad:
            # the weight moved from T_i to the air must not exceed A_ii: else the step is no convex combination and
            # the state (and its error) lose their certified bounds
            i = bad[0]
            raise NoReducedForm("the extra loss per step D·U = %.3g at the top feed exceeds the state's own weight A_ii = %.3g "
                                "in segment %d (k = %.3g): the explicit step is unstable" % (D[i] * umax, A[i][i], i, p["k"]))
        red["convection_per_mm"] = [float(d) for d in D]


class ReversalEffect(Effect):
    """Backlash-like offset: +b/2 on +1 sweeps, −b/2 on −1 sweeps (bidirectional data)."""

    name = "reversal_error"

    def parameters(self) -> list[ParamSpec]:
        return [ParamSpec("b_um", 0.0, -100.0, 100.0, "um", positive=False)]

    def check(self, contexts: Sequence[RunContext]) -> None:
        if not any(c.direction is not None and np.any(c.direction > 0) and np.any(c.direction < 0) for c in contexts):
            raise ValueError("reversal_error needs bidirectional sweeps (errors.csv 'direction' column with +1 and -1); "
                             "none of %s has them" % ", ".join(c.run_name for c in contexts))

    def error_um(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray:
        if ctx.direction is None:
            return np.zeros(ctx.n_rows)
        return 0.5 * p["b_um"] * ctx.direction

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        # the board knows the direction of the last position change (position reports); +b/2 moving in +, -b/2 in -
        red["reversal_um"] = red.get("reversal_um", 0.0) + 0.5 * p["b_um"]


class AmbientExpansion(Effect):
    """Expansion with the machine's surroundings as its own term: k·(T_s − T_s,start)·P.

    T_s is ``sensor``, by default the base sensor (as in the twin's effect of the same
    name), else the first air sensor.  It duplicates the model's E_e term, so use it
    with ``ScrewModel(ambient=False)`` (a base model without E_e + this effect)."""

    name = "ambient_expansion"

    def __init__(self, sensor: str | None = None) -> None:
        self.sensor = sensor

    def parameters(self) -> list[ParamSpec]:
        return [ParamSpec("um_per_m_K", 0.0, -50.0, 50.0, "um/(m K)", positive=False)]

    def error_um(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray:
        name = self.sensor or ctx.base_sensor or ctx.ambient_sensor
        if name is None:
            raise ValueError("ambient_expansion: run %s has no sensor with role 'base' or 'ambient'" % ctx.run_name)
        rise = ctx.sensor_rise_at_rows(name)
        return 1e-3 * p["um_per_m_K"] * rise * ctx.positions_mm

    def reduce(self, model: ScrewModel, p: dict[str, float], red: dict[str, Any], C: np.ndarray) -> None:
        # k·(T_s - T_s,start)·P is the table's base term: its coefficient grows by k (um/(m K) -> um/(mm K)); the
        # reference is each run's start, which the board latches at its cold start
        name = self.sensor or model.effect_sensor_(self)
        if name is None:
            raise NoReducedForm("no sensor with role 'base' or 'ambient' to read")
        if red.get("base_sensor") not in (None, name):
            raise NoReducedForm("it reads %s but the model's E_e term reads %s: the table has one base term"
                                % (name, red["base_sensor"]))
        if red.get("base_sensor") is None:
            red["base_sensor"], red["base_ref"] = name, "run_start"
            red["base_ref_C"] = model.start_C_(name)
        red["ee_um_per_mm_per_K"] = red.get("ee_um_per_mm_per_K", 0.0) + 1e-3 * p["um_per_m_K"]

    def to_document(self) -> dict[str, Any]:
        return {"sensor": self.sensor}


# The optional hooks (the module docstring): ScrewModel asks isinstance(effect, HeatHook) etc., which is true when the
# effect defines the method, as hasattr was
@runtime_checkable
class HeatHook(Protocol):
    def heat_W(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray: ...


@runtime_checkable
class HeatScaleHook(Protocol):
    def heat_scale(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray: ...


@runtime_checkable
class ConvectionHook(Protocol):
    def convection_mult(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray: ...


@runtime_checkable
class ErrorHook(Protocol):
    def error_um(self, ctx: RunContext, p: dict[str, float]) -> np.ndarray: ...


@runtime_checkable
class CheckHook(Protocol):
    def check(self, contexts: Sequence[RunContext]) -> None: ...


EFFECTS = {cls.name: cls for cls in (BearingHeat, SpeedDependentHeat, MovingConvection, ReversalEffect, AmbientExpansion)}


def make_effect(name: str, **settings: Any) -> Effect:
    if name not in EFFECTS:
        raise ValueError("unknown screw-model effect %r (known: %s)" % (name, ", ".join(EFFECTS)))
    return EFFECTS[name](**settings)
