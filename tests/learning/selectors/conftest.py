"""Shared data for the selector tests: small collinear sensor sets with a known structure."""
import numpy as np
import pytest


def latent_arrays(seed=0, n_runs=3, n=40, p=6, noise=0.02):
    """Runs of ``p`` sensors mixing three first-order heat sources; y = 2*s0 - s2 (+ noise).

    Each run heats with different source amplitudes (like different feeds), so the
    sensors are collinear within a run but not identically across runs.
    """
    rng = np.random.default_rng(seed)
    W = rng.uniform(0.1, 1.0, size=(3, p))
    t = np.linspace(0.0, 1.0, n)
    out = []
    for r in range(n_runs):
        amp = rng.uniform(0.5, 1.5, size=3)
        src = np.column_stack([amp[m] * (1 - np.exp(-t * (m + 1) * 2.5)) + 0.05 * np.cumsum(rng.normal(size=n)) / np.sqrt(n) for m in range(3)]) * 10
        X = src @ W + noise * rng.normal(size=(n, p))
        y = 2.0 * src[:, 0] - src[:, 2] + 0.05 * rng.normal(size=n)
        out.append((X, y, ["S%d" % (j + 1) for j in range(p)]))
    return out


@pytest.fixture
def arrays3():
    return latent_arrays(seed=11, n_runs=3, n=40, p=6)


@pytest.fixture(scope="session")
def make_arrays():
    """The generator itself, for hypothesis tests (function-scoped fixtures do not mix with @given)."""
    return latent_arrays
