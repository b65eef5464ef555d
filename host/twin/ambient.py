"""Workshop air temperature: a seeded warming drift, an HVAC ripple and a slow wander.

T_air(t) = ambient_mean_C + drift(t) + ripple(t) + wander(t) [+ optional daily cosine]

* drift: the shop warms by a seeded amount dT in [ambient_rise_min_K,
  ambient_rise_max_K] over the first min(ambient_rise_hours, run) hours (half-cosine
  ramp), holds ambient_hold_hours, then cools back over ambient_fall_hours (long runs);
* ripple: the HVAC thermostat cycle, a triangle wave of amplitude hvac_ripple_K with
  a seeded period in [hvac_period_min_min, hvac_period_max_min] and a seeded phase;
* wander: five sinusoids with periods 30-150 min and seeded phases, scaled to a
  standard deviation of ambient_wander_K (doors, people);
* ambient_day_amplitude_K * cos(2*pi*(hour - ambient_peak_hour)/24), off by default.
"""

from __future__ import annotations

from numpy.typing import ArrayLike
from typing import TYPE_CHECKING
from dataclasses import dataclass

import numpy as np

if TYPE_CHECKING:
    from host.twin.axis import AxisParams


# parameter overrides that hold the air constant at ambient_mean_C (no drift, ripple, wander or daily
# cycle): simulate(..., **STILL_AIR) isolates the response to the axis's own heat
STILL_AIR = {"ambient_rise_min_K": 0.0, "ambient_rise_max_K": 0.0, "hvac_ripple_K": 0.0, "ambient_wander_K": 0.0,
             "ambient_day_amplitude_K": 0.0}


@dataclass(frozen=True)
class Air:
    """The drawn air of one run: temperatures at the sample times and the seeded figures."""

    C: np.ndarray
    rise_K: float
    hvac_period_min: float


def _ramp(u):
    """Half-cosine from 0 (u <= 0) to 1 (u >= 1)."""
    u = np.clip(u, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(np.pi * u))


def air_C(t_s: ArrayLike, start_hour: float, params: AxisParams, rng: np.random.Generator) -> Air:
    """The air of a run starting at wall-clock ``start_hour``, sampled at ``t_s``: an :class:`Air`."""
    t_s = np.asarray(t_s, dtype=float)
    # draws in a fixed order: the same seed gives the same air whatever the parameters
    rise = rng.uniform(params.ambient_rise_min_K, params.ambient_rise_max_K)
    period = rng.uniform(params.hvac_period_min_min, params.hvac_period_max_min) * 60.0
    hvac_phase = rng.uniform(0.0, 1.0)
    periods = rng.uniform(30.0, 150.0, 5) * 60.0
    phases = rng.uniform(0.0, 2 * np.pi, 5)
    amps = rng.uniform(0.5, 1.0, 5)

    run_h = t_s[-1] / 3600.0 if t_s.size else 0.0
    hours = t_s / 3600.0
    up = max(min(params.ambient_rise_hours, run_h), 1e-9)
    fall_start = up + params.ambient_hold_hours
    down = _ramp((hours - fall_start) / params.ambient_fall_hours) if params.ambient_fall_hours > 0 else 0.0 * hours
    drift = rise * (_ramp(hours / up) - down)

    cycle = (t_s / period + hvac_phase) % 1.0
    ripple = params.hvac_ripple_K * (4.0 * np.abs(cycle - 0.5) - 1.0)  # triangle wave in [-1, 1]

    wander = (amps[None, :] * np.sin(2 * np.pi * t_s[:, None] / periods[None, :] + phases[None, :])).sum(axis=1)
    wander *= params.ambient_wander_K / np.sqrt(0.5 * np.sum(amps**2))

    day = params.ambient_day_amplitude_K * np.cos(2 * np.pi * (start_hour + hours - params.ambient_peak_hour) / 24.0)
    return Air(params.ambient_mean_C + drift + ripple + wander + day, float(rise), float(period / 60.0))
