"""Candidate effects the discrepancy workflow tests, one small definition each.

Every effect hooks into the screw model (host/learning/screw/heat.py) at one place:

- ``heat``: extra heat input. ``unit_inputs(drive)`` returns one unit input per
  parameter, each ``(heat_J, source_W)`` as ``simulate_segments`` takes them;
  the response to it is scaled by the parameter (heat input enters the linear
  segment equations linearly, so these parameters are solved exactly by linear
  least squares inside the fit).
- ``convection``: a multiplier on h·S per step, ``convection(drive, values)``;
  its parameters are nonlinear and identified by the outer optimiser.
- ``output``: extra error columns at the error rows, ``columns(drive)``, one per
  (linear) parameter.

``applicable(run)`` says why an effect cannot be tested on a run (None = it can).
The physical forms follow the digital twin (host/twin/effects.py) so the names
mean the same thing on both sides. Add an effect by writing one more instance of
:class:`CandidateEffect` and putting it in ``CATALOG`` (docs/discrepancy.md).
"""
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

FEED_REF_MM_MIN = 8000.0  # reference feed of the speed-dependent forms (the twin's)


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    lo: float  # bounds of the fit (the prior range)
    hi: float
    start: float = 0.0
    description: str = ""


@dataclass(frozen=True)
class CandidateEffect:
    name: str
    hook: str  # "heat", "convection" or "output"
    description: str
    params: tuple
    unit_inputs: Optional[Callable[[Any], list]] = None  # heat: drive -> [(heat_J|None, source_W|None)] per param
    convection: Optional[Callable[[Any, dict], Any]] = None  # convection: (drive, values) -> (n_steps,) multiplier
    columns: Optional[Callable[[Any], Any]] = None  # output: drive -> (n_rows, n_params)
    requires: tuple = field(default_factory=tuple)  # "motion", "direction", "base_sensor", "feeds"

    def __post_init__(self):
        need = {"heat": "unit_inputs", "convection": "convection", "output": "columns"}
        if self.hook not in need:
            raise ValueError("effect %r: hook must be one of %s (found %r)" % (self.name, ", ".join(need), self.hook))
        if getattr(self, need[self.hook]) is None:
            raise ValueError("effect %r: a %s-hook effect needs %s=..." % (self.name, self.hook, need[self.hook]))
        if not self.params:
            raise ValueError("effect %r: needs at least one Param" % self.name)

    def applicable(self, runs):
        """None, or why the effect cannot be tested on ``runs`` (a list of host.data.runs.Run)."""
        if "motion" in self.requires and not any(r.motion is not None and len(r.motion) for r in runs):
            return "no run has motion.csv"
        if "direction" in self.requires and not any(r.errors.direction is not None for r in runs):
            return "no run has bidirectional sweeps (errors.csv 'direction')"
        if "base_sensor" in self.requires:
            missing = [r.name for r in runs if not r.sensors_with_role("base")]
            if missing:
                return "run %s has no temperature sensor with role 'base'" % ", ".join(missing)
        return None


# ------------------------------------------------------------------ hooks


def _speed_dependent_inputs(drive):
    # friction energy per mm q*((1-m) + m*f/f_ref) = q0 + q1*f/f_ref: the f/f_ref-weighted
    # travel is a second heat input with its own linear amplitude q1 [J/mm at f_ref]
    return [(drive.travel_feed, None)]


def _bearing_inputs(drive):
    src = np.zeros_like(drive.travel)
    src[:, 0] = drive.speed  # 1 W at the reference speed, in the segment holding the fixed end
    return [(None, src)]


def _moving_convection(drive, values):
    return 1.0 + values["rise"] * drive.speed08


def _ambient_columns(drive):
    # alpha*(T_base - T_base(0))*P in um, per unit share of free expansion
    return (drive.alpha_per_K * 1e3 * drive.base_rise * drive.positions_mm)[:, None]


def _reversal_columns(drive):
    if drive.direction is None:  # a unidirectional run carries no reversal information
        return np.zeros((drive.positions_mm.size, 1))
    return (0.5 * drive.direction.astype(float))[:, None]


CATALOG = {
    e.name: e
    for e in (
        CandidateEffect(
            "ambient_expansion", "output",
            "screw and base follow the base temperature: error += k*alpha*(T_base - T_base(t0))*P",
            (Param("share", "1", -3.0, 3.0, 0.0, "share k of the free expansion alpha*dT_base*P"),),
            columns=_ambient_columns, requires=("base_sensor",),
        ),
        CandidateEffect(
            "speed_dependent_heat", "heat",
            "friction energy per mm of nut travel q0 + q1*feed/feed_ref instead of a constant q0",
            (Param("q1_J_per_mm", "J/mm at feed_ref", -1.0, 1.0, 0.0, "feed-proportional part of the friction heat"),),
            unit_inputs=_speed_dependent_inputs, requires=("motion",),
        ),
        CandidateEffect(
            "bearing_heat", "heat",
            "heat source in the segment at the fixed-end support bearing: P_b*feed/feed_ref watts while moving",
            (Param("P_b_W", "W at feed_ref", 0.0, 100.0, 0.0, "bearing power at the reference speed"),),
            unit_inputs=_bearing_inputs, requires=("motion",),
        ),
        CandidateEffect(
            "moving_convection", "convection",
            "convection coefficient h*(1 + r*(feed/feed_ref)**0.8) while the screw turns, h at rest",
            (Param("rise", "1", -0.8, 10.0, 0.5, "relative rise r of h at the reference feed"),),
            convection=_moving_convection, requires=("motion",),
        ),
        CandidateEffect(
            "reversal_error", "output",
            "direction-dependent offset +B/2 approaching in +, -B/2 in -",
            (Param("B_um", "um", -100.0, 100.0, 0.0, "reversal value B"),),
            columns=_reversal_columns, requires=("direction",),
        ),
    )
}
