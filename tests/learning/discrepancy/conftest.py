"""Synthetic residual data and a small linear model family for testing the discrepancy machinery.

The toy family is deliberately not the screw model: it checks the statistics and
the loop (folds, scoring, significance, iteration, JSON) independently of the
physics. Effects are extra regression columns computed from the run.
"""
import numpy as np
import pytest

from host.data.runs import Errors, Motion, Run, Temperatures


def make_run(seed, name, ambient_um_per_K=0.0, reversal_um=0.0, noise_um=0.5, n_sweeps=30, positions=np.linspace(10, 690, 12), bidirectional=True):
    rng = np.random.default_rng(seed)
    t_sw = np.arange(n_sweeps) * 900.0
    t = np.arange(0, t_sw[-1] + 60, 60.0)
    amb = 20 + 1.5 * np.sin(2 * np.pi * t / (8 * 3600) + rng.uniform(0, 6)) + rng.normal(0, 0.02, t.size)
    heat_end = t_sw[-1] * 0.6
    nut = 20 + 8 * (1 - np.exp(-np.minimum(t, heat_end) / 3000)) * np.where(t > heat_end, np.exp(-(t - heat_end) / 4000), 1)
    temps = Temperatures(t, ["T1", "T3"], np.column_stack([nut, amb]))
    dirs = (1, -1) if bidirectional else (1,)
    rows = [(ts, p, d) for ts in t_sw for d in dirs for p in (positions if d > 0 else positions[::-1])]
    ts, p, d = (np.asarray(c, dtype=float) for c in zip(*rows))
    nut_at = np.interp(ts, t, nut) - 20
    amb_at = np.interp(ts, t, amb) - amb[0]
    err = 2 + 0.01 * p + 0.12 * nut_at * p / 100 + ambient_um_per_K * amb_at * p / 100 + reversal_um * d / 2 + rng.normal(0, noise_um, ts.size)
    errors = Errors(ts, p, err, d.astype(np.int8) if bidirectional else None, None)
    motion = Motion(np.array([0.0]), np.array([heat_end]), np.array([210.0]), np.array([490.0]), np.array([8000.0]))
    meta = {"format": "tcomp-run/1", "axis": "X", "stroke_mm": 700, "screw": {"length_mm": 800, "diameter_mm": 32, "lead_mm": 10, "fixed_end_mm": 0},
            "sensors": {"T1": {"role": "nut"}, "T3": {"role": "base"}}}
    return Run(meta, temps, errors, motion, None, name=name)


class ToyFamily:
    """Linear least squares: base columns [1, P, nut_rise*P], plus one column per effect."""

    candidates = ("ambient", "reversal", "cubic", "quartic")

    def applicable(self, runs, name):
        if name == "reversal" and any(r.errors.direction is None for r in runs):
            return "needs bidirectional sweeps"
        return None

    def columns(self, run, effects):
        e = run.errors
        p = e.position_mm / 100
        t = run.temperatures
        nut = t.at(e.time_s, ["T1"])[:, 0] - t.values[0, 0]
        cols = [np.ones(len(e)), p, nut * p]
        for name in effects:
            if name == "ambient":
                cols.append((t.at(e.time_s, ["T3"])[:, 0] - t.values[0, 1]) * p)
            elif name == "reversal":
                cols.append(e.direction.astype(float))
            elif name == "cubic":
                cols.append(p ** 3)
            elif name == "quartic":
                cols.append(np.sin(3 * p))
        return np.column_stack(cols)

    def fit(self, runs, masks, effects, start):
        X = np.vstack([self.columns(r, effects)[m] for r, m in zip(runs, masks) if m is not None])
        y = np.concatenate([r.errors.error_um[m] for r, m in zip(runs, masks) if m is not None])
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        return (tuple(effects), coef)

    def predict(self, fitted, run):
        effects, coef = fitted
        return self.columns(run, effects) @ coef


@pytest.fixture
def make():
    """The synthetic run factory ``make_run`` (conftest modules cannot be imported from tests)."""
    return make_run


@pytest.fixture
def toy_family():
    return ToyFamily()
