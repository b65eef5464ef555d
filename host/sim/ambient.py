"""Workshop air temperature: a daily cycle (warmest mid-afternoon, cooling into the evening) plus a seeded slow wander."""
import numpy as np


def ambient_C(t_s, start_hour, params, rng):
    """Air temperature at times ``t_s`` of a run starting at wall-clock ``start_hour``.

    The wander is a sum of five sinusoids with periods 30-150 min and random
    phases, scaled to a standard deviation of ``ambient_wander_K``: smooth (HVAC
    cycling, doors) and reproducible for a seed.
    """
    t_s = np.asarray(t_s, dtype=float)
    hour = start_hour + t_s / 3600.0
    day = params.ambient_day_amplitude_K * np.cos(2 * np.pi * (hour - params.ambient_peak_hour) / 24.0)
    periods = rng.uniform(30.0, 150.0, 5) * 60.0
    phases = rng.uniform(0.0, 2 * np.pi, 5)
    amps = rng.uniform(0.5, 1.0, 5)
    wander = (amps[None, :] * np.sin(2 * np.pi * t_s[:, None] / periods[None, :] + phases[None, :])).sum(axis=1)
    scale = np.sqrt(0.5 * np.sum(amps**2))
    return params.ambient_mean_C + day + params.ambient_wander_K * wander / scale
