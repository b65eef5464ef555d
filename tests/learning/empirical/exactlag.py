"""Test-side physics for the dynamic-model tests, written here from the exact solution (not the model's code)."""
import numpy as np


def exact_lag(u, tau, dt, y0=0.0):
    """First-order lag (time constant ``tau`` s) of a signal sampled every ``dt`` s and held between samples."""
    y = np.empty(u.size)
    y[0] = y0
    decay = np.exp(-dt / tau)
    for k in range(1, u.size):
        y[k] = u[k - 1] + (y[k - 1] - u[k - 1]) * decay
    return y
