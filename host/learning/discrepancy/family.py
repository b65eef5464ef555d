"""The discrepancy workflow's model family: configurations of host/learning/screw's ScrewModel.

A candidate set of effects is the ScrewModel with those effects (host/learning/screw/effects.py, where each
effect is defined once: its parameters, bounds, hooks and reduced firmware form). The base model is the
screw model with E_m only (``ambient=False``: the catalog's ``ambient_expansion`` is the term that names the
expansion with the machine's surroundings), exchanging heat with the measured air (``air``). Every fold fit
is a ``ScrewModel.fit`` on the fold's rows, started from the fold's previous fit; the final fit on all runs
is the same configuration with its reduced form and reduction certificate, and its document is the model
the workflow writes (host/learning/discrepancy/report.py): the model the workflow validated is the model
that is exported.

What stays here is workflow logic: which candidates the runs can test (``applicable``), caveats
(``note``) and which temperature columns the model reads (``used_sensors``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import dataclasses
import warnings

import numpy as np

from host.data.runs import START
from host.learning.screw.effects import EFFECTS, make_effect
from host.learning.screw.screwmodel import ScrewModel

if TYPE_CHECKING:
    from host.data.runs import Run

# 20 segments and 60 s steps (the air linear within a step, the heat of a step's exact travel): the held-out
# RMSEs within 0.01 um of 20 s steps on the twin's scenarios (bearing_heat: 0.647 vs 0.646 um) at a quarter of
# the identification time; every candidate is fitted once per fold
SEGMENTS = 12
DT_S = 60.0
GEOMETRIC_DEGREE = 3
# The candidates in the order the workflow tests them (ties go to the earlier one)
CANDIDATES = ("ambient_expansion", "speed_dependent_heat", "bearing_heat", "moving_convection", "reversal_error")
FOLD_MAX_NFEV = 60  # fold fits start from the previous fit of the same fold
# Fold fits stop when the cost changes by less than 1e-7 relative: a held-out RMSE moves by < 1e-7 of itself,
# far below what the significance test resolves (the final fit uses the screw model's default)
FOLD_FTOL = 1e-7


class ScrewFamily:
    """The screw model (E_m over the measured air, no E_e) plus effects from host/learning/screw/effects.py."""

    def __init__(self, segments: int = SEGMENTS, dt_s: float = DT_S, geometric_degree: int = GEOMETRIC_DEGREE, air: bool = True, candidates: Sequence[str] = CANDIDATES, error_reference: str | None = None) -> None:
        unknown = [n for n in candidates if n not in EFFECTS]
        if unknown:
            raise ValueError("unknown effect(s) %s (the screw model's effects: %s)" % (", ".join(unknown), ", ".join(EFFECTS)))
        self.segments = segments
        self.dt_s = dt_s
        self.geometric_degree = geometric_degree
        self.air = air
        self.candidates = tuple(candidates)
        # None: each run's declaration (meta.json error_reference); else the runs are read as if they declared it
        # (host/learning/discrepancy/reference.py tries the other conventions this way)
        self.error_reference = error_reference

    @property
    def catalog(self) -> dict[str, type]:
        """The effects the workflow can name: the screw model's own (effects.EFFECTS)."""
        return {n: EFFECTS[n] for n in self.candidates}

    def model(self, effects: Iterable[str]) -> ScrewModel:
        """The ScrewModel configuration for the effect names ``effects`` (not fitted)."""
        return ScrewModel(segments=self.segments, dt_s=self.dt_s, ambient=False, geometric_degree=self.geometric_degree,
                          effects=[make_effect(n) for n in effects], air="auto" if self.air else "off", max_nfev=FOLD_MAX_NFEV,
                          ftol=FOLD_FTOL)

    def _declared(self, run):
        """``run`` as the family reads it: with the overriding error reference in its meta, if one is set."""
        if self.error_reference is None or run.error_reference == self.error_reference:
            return run
        return dataclasses.replace(run, meta=dict(run.meta, error_reference=self.error_reference))

    def _moving(self, runs, masks):
        # the screw model is driven by the axis motion; a run without it carries no screw information
        return [(self._declared(r), m) for r, m in zip(runs, masks)
                if m is not None and np.any(m) and r.motion is not None and len(r.motion)]

    def fit(self, runs: Sequence[Run], masks: Sequence[np.ndarray | None], effects: Iterable[str], start: ScrewModel | None = None) -> ScrewModel:
        sel = self._moving(runs, masks)
        if not sel:
            raise ValueError("no rows of a run with motion to fit on")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return self.model(effects).fit([r for r, _ in sel], row_masks=[m for _, m in sel],
                                           start=None if start is None else start.values_, reduce=False)

    def fit_final(self, runs: Sequence[Run], effects: Iterable[str], start: ScrewModel | None = None) -> ScrewModel:
        """The configuration fitted on every row of every run with motion, with its reduced form: the model written."""
        sel = self._moving(runs, [np.ones(len(r.errors), bool) for r in runs])
        if not sel:
            raise ValueError("no run with motion to fit on")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = self.model(effects)
            model.max_nfev = 200
            model.ftol = 1e-12
            return model.fit([r for r, _ in sel], start=None if start is None else start.values_)

    def predict(self, fitted: ScrewModel, run: Run) -> np.ndarray:
        if run.motion is None or not len(run.motion):
            raise ValueError("run %s has no motion: the screw model cannot predict it" % run.name)
        return fitted.predict(self._declared(run))

    def used_sensors(self, run: Run, effects: Iterable[str] = ()) -> set[str]:
        """The temperature columns the model with ``effects`` reads for ``run``."""
        names = run.temperatures.names
        used = set()
        if self.air:
            amb = [n for n in run.sensors_with_role("ambient") if n in names]
            base = [n for n in run.sensors_with_role("base") if n in names]
            used.update((amb or base)[:1])
        if "ambient_expansion" in effects:
            used.update(run.sensors_with_role("base")[:1])
        ref = self._declared(run).error_reference
        if ref != START:
            used.add(ref)
        return used

    def applicable(self, runs: Sequence[Run], name: str) -> str | None:
        """None, or why the effect cannot be tested on ``runs``."""
        if name in ("speed_dependent_heat", "bearing_heat", "moving_convection"):
            if not any(r.motion is not None and len(r.motion) for r in runs):
                return "no run has motion.csv"
        if name == "reversal_error" and not any(r.errors.direction is not None and np.any(r.errors.direction > 0)
                                                and np.any(r.errors.direction < 0) for r in runs):
            return "no run has bidirectional sweeps (errors.csv 'direction')"
        if name == "ambient_expansion":
            missing = [r.name for r in runs if not r.sensors_with_role("base")]
            if missing:
                return "run %s has no temperature sensor with role 'base'" % ", ".join(missing)
        if name == "speed_dependent_heat":
            feeds = set()
            for r in runs:
                if r.motion is not None:
                    feeds.update(np.round(r.motion.feed_mm_min, 6).tolist())
            if len(feeds) < 2:
                return "all runs move at one feed; a feed-dependent heat is not identifiable"
        return None

    def note(self, runs: Sequence[Run], name: str) -> str | None:
        """A caveat about testing ``name`` on these runs with leave-one-run-out, or None."""
        if name != "speed_dependent_heat" or len(runs) < 2:
            return None
        feeds = [set(np.round(r.motion.feed_mm_min, 6).tolist()) if r.motion is not None else set() for r in runs]
        alone = []
        for i, r in enumerate(runs):
            others = set().union(*(f for j, f in enumerate(feeds) if j != i))
            if len(others) < 2:
                alone.append(r.name)
        if alone:
            return ("the other runs move at a single feed when %s is held out, so the feed dependence "
                    "cannot be learnt for its prediction; add runs at more feeds" % ", ".join(alone))
        return None
