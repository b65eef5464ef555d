"""Synthetic runs with known truth for the empirical-model tests; puts this folder on sys.path for exactlag.py."""
import os
import sys

import numpy as np
import pytest

from host.data.runs import Errors, Run, Spindle, Temperatures

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)


def make_slope_run(name="run", seed=0, n_sweeps=12, n_sensors=4, coef=(0.004, -0.002), geo=(1.0, 0.01, -2e-5),
                   stroke=500.0, bidirectional=False, noise_um=0.0, offset_C=20.0, duration_s=14400.0):
    """A run whose sweep slopes are exactly k0 + Σ coef_j·rise_j of the first sensors.

    Temperature rises are smooth, distinct curves (independent enough for regression).
    """
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration_s + 600.0, 251)
    taus = rng.uniform(1500, 9000, n_sensors)
    amps = rng.uniform(2.0, 12.0, n_sensors)
    rises = amps * (1 - np.exp(-t[:, None] / taus)) + 0.3 * np.sin(t[:, None] / rng.uniform(900, 4000, n_sensors) + rng.uniform(0, 6, n_sensors))
    rises -= rises[0]
    values = offset_C + rng.uniform(-1, 1, n_sensors) + rises
    names = ["T%d" % (j + 1) for j in range(n_sensors)]
    temps = Temperatures(t, names, values)
    sweep_t = np.linspace(0.0, duration_s, n_sweeps)
    pos = np.linspace(0.0, stroke, 11)
    rows_t, rows_p, rows_e, rows_d = [], [], [], []
    dirs = (1, -1) if bidirectional else (1,)
    for ts in sweep_t:
        for d in dirs:
            tt = ts if d == 1 else ts + 60.0
            rise = np.array([np.interp(tt, t, rises[:, j]) for j in range(n_sensors)])
            s = float(np.dot(coef, rise[: len(coef)]))
            pp = pos if d == 1 else pos[::-1]
            gg = np.polynomial.polynomial.polyval(pp, geo) + (1.5 if d == -1 else 0.0)
            err = gg + s * pp + rng.normal(0, noise_um, pp.size)
            rows_t += [tt] * pp.size
            rows_p += list(pp)
            rows_e += list(err)
            rows_d += [d] * pp.size
    errors = Errors(np.array(rows_t), np.array(rows_p), np.array(rows_e), np.array(rows_d, dtype=np.int8) if bidirectional else None, None)
    meta = {"format": "tcomp-run/1", "axis": "X", "stroke_mm": stroke, "sensors": {n: {"role": "structure"} for n in names}}
    return Run(meta, temps, errors, name=name)


def make_direct_run(name="drun", seed=0, n_sensors=5, coef=(-3.0, 1.5), intercept=0.4, channels=("ch1", "ch2"), noise_um=0.0, spindle=False):
    """A multi-channel fixed-point run: ch1 = intercept + Σ coef·rise, ch2 = −ch1 + 2.

    ``spindle=True`` adds a schedule of five 2 h cycles (1 h running, 1 h stopped):
    1000, 2000, 3000 rpm, then 4000 rpm, then mixed 1500/2500 rpm.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 36000.0, 60.0)
    taus = rng.uniform(1500, 9000, n_sensors)
    rises = rng.uniform(2, 10, n_sensors) * (1 - np.exp(-t[:, None] / taus)) + 0.5 * np.sin(t[:, None] / rng.uniform(800, 5000, n_sensors))
    rises -= rises[0]
    names = ["t%d" % (j + 1) for j in range(n_sensors)]
    temps = Temperatures(t, names, 22.0 + rises)
    y1 = intercept + rises[:, : len(coef)] @ np.asarray(coef) + rng.normal(0, noise_um, t.size)
    ys = {"ch1": y1, "ch2": -y1 + 2.0}
    rt, rp, re, rc = [], [], [], []
    for i in range(t.size):
        for c in channels:
            rt.append(t[i])
            rp.append(0.0)
            re.append(ys[c][i])
            rc.append(c)
    errors = Errors(np.array(rt), np.array(rp), np.array(re), None, np.array(rc, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {n: {"role": "structure"} for n in names}}
    sp = None
    if spindle:
        rpm = np.zeros(t.size)
        for k, speed in enumerate((1000, 2000, 3000, 4000)):
            rpm[(t >= 7200 * k + 600) & (t < 7200 * k + 4200)] = speed
        rpm[(t >= 29400) & (t < 31200)] = 1500
        rpm[(t >= 31200) & (t < 33000)] = 2500
        sp = Spindle(t.copy(), rpm)
    return Run(meta, temps, errors, spindle=sp, name=name)


@pytest.fixture
def slope_run():
    return make_slope_run()


@pytest.fixture
def direct_run():
    return make_direct_run()


@pytest.fixture
def make_slope():
    """Factory: make_slope(**kw) -> synthetic slope run (see make_slope_run)."""
    return make_slope_run


@pytest.fixture
def make_direct():
    """Factory: make_direct(**kw) -> synthetic multi-channel fixed-point run (see make_direct_run)."""
    return make_direct_run


@pytest.fixture(scope="module")
def bidirectional_run():
    """One bidirectional slope run shared by a module (hypothesis tests cannot use function-scoped fixtures)."""
    return make_slope_run(bidirectional=True)
