"""The declared error reference in the screw physics (docs/screw-model.md, "Error reference").

A run's errors are either raw (``"start"``: relative to the machine at the run's start) or corrected to a
sensor's temperature T_R (a laser's material-temperature compensation; S004 Eq. 9 writes
E_m = Σ α (T_Li − T_f) L_i). The screw model holds its segments' temperatures over its reference, so under a
sensor reference E_m loses the expansion of the measured length at T_R:

    E_m,R(P, t) = α Σ_i T_i(t) overlap_i(P) − α (T_R(t) − T_R,ref) P

P is the distance from the laser's datum (axis 0): the laser scales the displacement it measured from there
(docs/data-format.md). T_R,ref is R's reading at the run's start (``base_ref="run_start"``, like E_e's base
sensor: each run's cold error is measured then) or a fixed training value. It is linear in T_R, so the board
evaluates it as one more temperature-linear coefficient (−α on R).

This module is the one place that term and E_e's default per reference are written; the screw model
(screwmodel.py) and the discrepancy workflow's base model use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING
from numpy.typing import ArrayLike

import numpy as np

if TYPE_CHECKING:
    from host.data.runs import Run


def ambient_default(error_reference: str) -> bool:
    """Whether E_e (α·(T_base − T_base,ref)·P) is in the default structure under ``error_reference``.

    Off under both. Under "start" E_m holds the screw at its own absolute temperature, which follows the air:
    E_e on top counts the air's expansion twice (α −42 %, q +70 % on effect-free runs,
    tools/bench_reference.py). Under a sensor reference the laser has already taken the expansion at T_R out
    of the errors and E_m is over T_R: E_e would put an air-driven expansion back that the data no longer
    hold. In both conventions a frame that really drifts with the base is a catalog effect
    (``ambient_expansion``) that the discrepancy workflow names when the data show it, or ``ambient=on``."""
    return False


def check_reference_sensor(runs: Sequence[Run], sensor: str) -> None:
    """ValueError naming the runs whose temperatures.csv lacks the reference sensor."""
    missing = [r.path or r.name for r in runs if sensor not in r.temperatures.names]
    if missing:
        raise ValueError("error reference %r (meta.json error_reference) is not a column of temperatures.csv of %s"
                         % (sensor, ", ".join(missing)))


def reference_K(run: Run, sensor: str, times_s: ArrayLike, ref_C: float | None = None) -> np.ndarray:
    """T_R(t) − T_R,ref at ``times_s`` (K): over the run's first reading (``ref_C`` None) or ``ref_C``."""
    tt = run.temperatures
    col = tt.column(sensor)
    return np.interp(np.asarray(times_s, dtype=float), tt.time_s, col) - (float(col[0]) if ref_C is None else ref_C)


def reference_um(alpha_per_K: float, rise_K: ArrayLike, positions_mm: ArrayLike) -> np.ndarray:
    """The term a sensor-referenced error lacks: α (T_R − T_R,ref) P in µm (subtract it from E_m)."""
    return 1e3 * alpha_per_K * np.asarray(rise_K) * np.asarray(positions_mm)
