"""Model documents for tests and benchmarks, in realistic coefficient ranges.

``poly_slope_doc``/``linear_direct_doc``/``screw_doc`` build tcomp-model/1
documents from a ``random.Random``; ``screw_doc`` builds its reduced recurrence
with the screw model's own physics (host.screw.heat) and state bound
(host.screw.reduced.state_bound), so the matrices look like fitted ones.
"""
import random as _random

from host.models import document_hash


def restamp(doc):
    """Record the document's hash again after a test edited it (as saving it would)."""
    return _finish(doc)


def _finish(doc):
    doc["provenance"] = {"tcomp_version": "test", "created_utc": "2026-01-01T00:00:00Z", "sha256": document_hash(doc)}
    return doc


def _sensors(rng, n, wide=True):
    names = ["T%d" % i for i in range(n)]
    env, ref = {}, {}
    for s in names:
        lo = rng.choice([-20.0, -10.0, 0.0, 10.0]) if wide else rng.uniform(10, 20)
        hi = rng.choice([40.0, 60.0, 80.0]) if wide else lo + rng.uniform(5, 30)
        env[s] = [lo, hi]
        ref[s] = round(rng.uniform(lo, hi), rng.choice([1, 3, 6]))
    return names, env, ref


def poly_slope_doc(rng=None, n_sensors=None, stroke_mm=None, degree=None):
    rng = rng or _random.Random(0)
    n = n_sensors if n_sensors is not None else rng.randint(1, 11)
    names, env, ref = _sensors(rng, n)
    stroke = stroke_mm if stroke_mm is not None else rng.choice([300.0, 800.0, 1500.0, 2000.0])
    d = degree if degree is not None else rng.randint(0, 4)
    geo = [rng.uniform(-10, 10)] + [rng.uniform(-20, 20) / stroke ** j for j in range(1, d + 1)]
    return _finish({
        "format": "tcomp-model/1", "kind": "poly_slope", "method": "mlr", "axis": "X", "channel": None,
        "sensors": names, "reference_C": ref,
        "geometric": {"degree": d, "coefficients_um": geo},
        "thermal": {"intercept_um_per_mm": rng.uniform(-2e-3, 2e-3),
                    "coefficients_um_per_mm_per_K": {s: rng.uniform(-0.03, 0.03) for s in names},
                    "reference": "fixed"},
        "envelope": {"temperature_C": env, "position_mm": [0.0, stroke]},
    })


def linear_direct_doc(rng=None, n_sensors=None):
    rng = rng or _random.Random(0)
    n = n_sensors if n_sensors is not None else rng.randint(1, 11)
    names, env, ref = _sensors(rng, n)
    return _finish({
        "format": "tcomp-model/1", "kind": "linear_direct", "method": "mlr", "axis": "Z", "channel": "spindle",
        "sensors": names, "reference_C": ref, "geometric": None,
        "thermal": {"intercept_um": rng.uniform(-5, 5), "coefficients_um_per_K": {s: rng.uniform(-3, 3) for s in names},
                    "reference": "fixed"},
        "envelope": {"temperature_C": env, "position_mm": [250.0, 250.0]},
    })


def screw_doc(rng=None, segments=None, dt_s=None, length_mm=None, feed_max_mm_min=None, base=True, degree=None, air=True):
    import numpy as np

    from host.screw import heat
    from host.screw.reduced import state_bound

    rng = rng or _random.Random(0)
    M = segments or rng.randint(8, 16)
    L = length_mm or rng.choice([500.0, 800.0, 1200.0])
    dt = dt_s or rng.choice([1.0, 5.0, 10.0])
    fmax = feed_max_mm_min or rng.choice([6000.0, 12000.0, 30000.0])
    diameter = rng.choice([25.0, 32.0, 40.0])
    params = heat.ScrewParams(q_J_per_mm=rng.uniform(0.02, 0.1), h_W_m2K=rng.uniform(8.0, 30.0))
    edges = [L * i / M for i in range(M + 1)]
    C, G, H = heat.segment_properties(edges, diameter, params)
    prop = heat.Propagator(C, G, H)
    A, _ = prop.step(dt, 1.0)
    A = np.clip(A, 0.0, None)
    c0, c1 = (np.clip(c, 0.0, None) for c in prop.air_step(dt, 1.0)) if air else (np.zeros(M), np.zeros(M))
    B = params.q_J_per_mm / C
    fixed = rng.choice([-20.0, 0.0, 15.5])
    red = {
        "segments": M, "dt_s": dt, "edges_mm": edges, "fixed_end_mm": fixed,
        "A": [[float(v) for v in row] for row in A], "B_K_per_mm": [float(b) for b in B],
        "alpha_um_per_mm_per_K": 1e3 * params.alpha_per_K,
        "base_sensor": "T_base" if base else None, "base_ref_C": 20.0 if base else None,
        "feed_max_mm_min": fmax, "state_max_K": state_bound(A, B, fmax / 60.0 * dt),
        "air_sensor": "T_air" if air else None, "air_ref_C": 21.0 if air else None,
        "air_K0": [float(c) for c in c0], "air_K1": [float(c) for c in c1],
    }
    d = degree if degree is not None else rng.randint(0, 3)
    stroke = L + fixed - 10.0
    geo = [rng.uniform(-5, 5)] + [rng.uniform(-10, 10) / stroke ** j for j in range(1, d + 1)]
    sensors = (["T_base"] if base else []) + (["T_air"] if air else [])
    refs = dict([("T_base", 20.0)] * bool(base) + [("T_air", 21.0)] * bool(air))
    doc = {
        "format": "tcomp-model/1", "kind": "screw", "method": "screw", "axis": "Y", "channel": None,
        "sensors": sensors, "reference_C": refs,
        "geometric": {"degree": d, "coefficients_um": geo},
        "thermal": {"reduced": red},
        "envelope": {"position_mm": [max(fixed, 0.0), stroke], "state_K": [0.0, red["state_max_K"]]},
    }
    if base or air:
        doc["envelope"]["temperature_C"] = dict([("T_base", [10.0, 40.0])] * bool(base) + [("T_air", [12.0, 32.0])] * bool(air))
    return _finish(doc)
