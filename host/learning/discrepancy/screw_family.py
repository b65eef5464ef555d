"""The screw heat-transfer model as a family for the discrepancy loop: base E_m plus catalog effects.

Physics: host/learning/screw/heat.py (segments, exact exponential integrator, nut travel,
E_m). The screw exchanges heat with the measured air (role ``ambient``; the base
sensor as a fallback, else a constant air: ``Drive.air_source``), so E_m holds the
screw's lagged expansion with the air; that response does not scale with q and
enters the linear solve as a fixed offset. The base model is
E = geometric(P) + E_m with the friction heat per mm q,
the convection coefficient h and the axial conductivity lambda identified; c, rho
and alpha are the material values from meta.json (steel by default; q, c and rho
only enter as q/(c rho) and alpha scales q, so they cannot be identified apart).

Identification is by variable projection: the segment equations are linear in
their heat inputs and the output is linear in the geometric coefficients and the
output-hook parameters, so for given nonlinear parameters (log h, log lambda
and any convection-hook parameters) all linear amplitudes (q, extra heat sources,
geometric polynomial, output columns) come from one bounded linear least-squares
solve. The outer optimiser (scipy least_squares, 1-3 dimensions) starts from the
previous fit. This is what makes scoring every candidate with leave-one-run-out
cheap enough to run the whole loop in seconds.
"""
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from host.learning.discrepancy.catalog import CATALOG, FEED_REF_MM_MIN
from host.data.runs import START, common_error_reference
from host.learning.screw import heat
from host.learning.screw import reference as errref

SEGMENTS = 20
GEOMETRIC_DEGREE = 3
H_BOUNDS = (1.0, 300.0)  # W/(m^2 K): still air to strong forced convection
Q_BOUNDS = (0.0, 10.0)  # J/mm
PRIOR_WEIGHT_UM = 1.0
LAMBDA_BOUNDS = (5.0, 200.0)  # W/(m K): the axial conduction of the screw (steel ~46)
LOG_PARAMS = ("h_W_m2K", "lambda_W_mK")
# Longest simulation step: the air enters linearly between grid points, and the shop's HVAC ripple
# (periods of 20-45 min) needs about ten points per period; 120 s keeps the hold error below 1 % of it.
MAX_STEP_S = 120.0


class Drive:
    """Everything about one run the fits need, computed once: time grid, nut travel, row mapping."""

    def __init__(self, run, segments=SEGMENTS, geometric_degree=GEOMETRIC_DEGREE, air=True, error_reference=None):
        if run.screw is None:
            raise ValueError("run %s: meta.json has no 'screw' block; the screw model needs the screw geometry" % run.name)
        e = run.errors
        if len(e) == 0:
            raise ValueError("run %s: errors.csv has no rows" % run.name)
        self.name = run.name
        self.geometry = heat.ScrewGeometry.from_meta(run.meta, segments)
        self.material = heat.ScrewParams.from_meta(run.meta, q_J_per_mm=1.0)
        self.alpha_per_K = self.material.alpha_per_K
        edges = self.geometry.edges_mm
        self.edges = edges
        m = run.motion
        times = [np.array([0.0]), e.time_s]
        if m is not None and len(m):
            times += [m.t_start_s, m.t_end_s]
        t_end = max(float(np.max(np.concatenate(times))), 0.0)
        times.append(np.arange(0.0, t_end, MAX_STEP_S))
        t = np.unique(np.concatenate(times))
        t = t[t >= 0]
        self.t = t
        n = t.size - 1
        M = self.geometry.segments
        if n < 1:
            raise ValueError("run %s: all error rows are at t = 0; nothing to simulate" % run.name)
        dt = np.diff(t)
        self.travel = np.zeros((n, M))
        self.travel_feed = np.zeros((n, M))
        self.speed = np.zeros(n)
        self.speed08 = np.zeros(n)
        if m is not None and len(m):
            duty = np.clip(np.minimum(t[1:, None], m.t_end_s[None, :]) - np.maximum(t[:-1, None], m.t_start_s[None, :]), 0, None) / dt[:, None]
            rel = m.feed_mm_min / FEED_REF_MM_MIN
            self.speed = duty @ rel
            self.speed08 = duty @ rel ** 0.8
            for f in np.unique(m.feed_mm_min):
                sel = m.feed_mm_min == f
                tr = heat.nut_travel_per_segment(_Rows(m, sel), edges, self.geometry.fixed_end_mm, t)
                self.travel += tr
                self.travel_feed += tr * (f / FEED_REF_MM_MIN)
        self.row_step = np.searchsorted(t, e.time_s)
        self.positions_mm = e.position_mm
        self.overlap = heat.overlap_mm(edges, e.position_mm - self.geometry.fixed_end_mm)  # (rows, M)
        stroke = float(run.stroke_mm or max(1.0, float(np.max(np.abs(e.position_mm)))))
        u = e.position_mm / stroke
        self.geometric = np.column_stack([u ** k for k in range(geometric_degree + 1)])
        self.direction = e.direction
        base = run.sensors_with_role("base")
        self.base_rise = None
        if base:
            tt = run.temperatures
            col = tt.column(base[0])
            t0 = np.interp(0.0, tt.time_s, col)
            self.base_rise = np.interp(e.time_s, tt.time_s, col) - t0
        self.error_um = e.error_um
        self.air_K, self.air_source, self.air_sensor = None, "off", None
        if air:
            names = run.temperatures.names
            amb = [n for n in run.sensors_with_role("ambient") if n in names]
            fallback = [n for n in run.sensors_with_role("base") if n in names]
            name = (amb or fallback or [None])[0]
            self.air_source = ("ambient %s" % name if amb else "base %s (no ambient sensor)" % name) if name else \
                "constant (no ambient or base sensor)"
            self.air_sensor = name
            if name is not None:
                tt = run.temperatures
                col = tt.column(name)
                self.air_K = np.interp(t, tt.time_s, col) - np.interp(0.0, tt.time_s, col)

        # the declared error reference (or the one a check tries instead): under a sensor reference the errors lack
        # alpha*(T_R - T_R(0))*P, a fixed offset of the linear solve (host/learning/screw/reference.py)
        self.error_reference = run.error_reference if error_reference is None else error_reference
        self.reference_um = 0.0
        if self.error_reference != START:
            errref.check_reference_sensor([run], self.error_reference)
            self.reference_um = errref.reference_um(self.alpha_per_K, errref.reference_K(run, self.error_reference, e.time_s),
                                                    e.position_mm)

    def response(self, h, conv, heat_J=None, source_W=None, lam=None, air_K=None):
        """E_m (um) at the error rows for one heat input (or the air ``air_K`` on the grid), convection h
        (and conductivity lam) and multiplier conv."""
        lam = self.material.lambda_W_mK if lam is None else lam
        mat = heat.ScrewParams(1.0, self.material.c_J_kgK, self.material.density_kg_m3, lam, h, self.alpha_per_K)
        rises = heat.simulate_segments(self.geometry, mat, self.t, heat_J=heat_J, convection_mult=conv, source_W=source_W,
                                       air_K=air_K)
        return 1e3 * self.alpha_per_K * np.einsum("rm,rm->r", rises[self.row_step], self.overlap)


class _Rows:
    def __init__(self, m, sel):
        self.t_start_s, self.t_end_s, self.from_mm, self.to_mm, self.feed_mm_min = (
            np.asarray(getattr(m, k))[sel] for k in ("t_start_s", "t_end_s", "from_mm", "to_mm", "feed_mm_min"))


@dataclass
class ScrewFit:
    effects: tuple
    nonlinear: dict  # name -> value (h_W_m2K, "<effect>.<param>")
    linear: dict  # name -> value (q_J_per_mm, g0.., "<effect>.<param>")
    rmse_um: float
    nfev: int

    def values(self):
        return {**self.nonlinear, **self.linear}


def _bounded_lstsq(X, y, lo, hi):
    """min ||X b - y|| with lo <= b <= hi, through the k x k Gram matrix.

    X is tall and thin (thousands of rows, < 15 columns, columns scaled to unit
    norm): the Gram product is a single cheap BLAS call, whereas a LAPACK
    least-squares or QR on the tall matrix is two orders of magnitude slower on a
    busy machine (threading overhead). The bounds are rarely active; when they
    are, the same problem is solved exactly in its k x k Cholesky form.
    """
    G = X.T @ X
    c = X.T @ y
    k = G.shape[0]
    try:
        L = np.linalg.cholesky(G)
    except np.linalg.LinAlgError:
        L = np.linalg.cholesky(G + 1e-10 * np.trace(G) / k * np.eye(k))
    z = np.linalg.solve(L, c)
    b = np.linalg.solve(L.T, z)
    if np.all(b >= lo) and np.all(b <= hi):
        return b
    # ||X b - y||^2 = ||L^T b - z||^2 + const
    return lsq_linear(L.T, z, bounds=(lo, hi), method="bvls").x


class ScrewFamily:
    """Base screw model (E_m, no ambient term) plus effects from ``catalog``."""

    def __init__(self, catalog=None, segments=SEGMENTS, geometric_degree=GEOMETRIC_DEGREE, free_lambda=True, air=True,
                 error_reference=None):
        self.free_lambda = free_lambda
        self.error_reference = error_reference  # None: each run's declaration (meta.json error_reference)
        self.air = air
        self.catalog = dict(CATALOG if catalog is None else catalog)
        self.candidates = tuple(self.catalog)
        self.segments = segments
        self.geometric_degree = geometric_degree
        self._drives = {}

    def drive(self, run):
        key = id(run)
        if key not in self._drives:
            self._drives[key] = (run, Drive(run, self.segments, self.geometric_degree, air=self.air,
                                            error_reference=self.error_reference))
        return self._drives[key][1]

    def used_sensors(self, run, effects=()):
        """The temperature columns the model with ``effects`` reads for ``run``."""
        d = self.drive(run)
        used = {d.air_sensor, None if d.error_reference == START else d.error_reference} - {None}
        if "ambient_expansion" in effects:
            used.update(run.sensors_with_role("base")[:1])
        return used

    def applicable(self, runs, name):
        why = self.catalog[name].applicable(runs)
        if why:
            return why
        if name == "speed_dependent_heat":
            feeds = set()
            for r in runs:
                if r.motion is not None:
                    feeds.update(np.round(r.motion.feed_mm_min, 6).tolist())
            if len(feeds) < 2:
                return "all runs move at one feed; a feed-dependent heat is not identifiable"
        return None

    def note(self, runs, name):
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

    # ------------------------------------------------------------ parameter layout

    def _layout(self, effects):
        nl = [("h_W_m2K", np.log(H_BOUNDS[0]), np.log(H_BOUNDS[1]), np.log(15.0))]
        if self.free_lambda:
            nl.append(("lambda_W_mK", np.log(LAMBDA_BOUNDS[0]), np.log(LAMBDA_BOUNDS[1]), np.log(45.0)))
        for name in effects:
            eff = self.catalog[name]
            if eff.hook == "convection":
                for p in eff.params:
                    nl.append(("%s.%s" % (name, p.name), p.lo, p.hi, p.start))
        lin = [("q_J_per_mm",) + Q_BOUNDS]
        lin += [("g%d_um" % k, -np.inf, np.inf) for k in range(self.geometric_degree + 1)]
        for name in effects:
            eff = self.catalog[name]
            if eff.hook in ("heat", "output"):
                for p in eff.params:
                    lin.append(("%s.%s" % (name, p.name), p.lo, p.hi))
        return nl, lin

    def _design(self, drive, effects, x, nl_names):
        """(columns (rows, n_linear), fixed offset (rows,)) for nonlinear parameter vector x (h in log space).

        The offset is the screw's response to the air, which no linear amplitude scales."""
        vals = dict(zip(nl_names, x))
        h = float(np.exp(vals["h_W_m2K"]))
        lam = float(np.exp(vals["lambda_W_mK"])) if "lambda_W_mK" in vals else None
        conv = None
        for name in effects:
            eff = self.catalog[name]
            if eff.hook == "convection" and eff.convection is not None:
                v = {p.name: vals["%s.%s" % (name, p.name)] for p in eff.params}
                c = eff.convection(drive, v)
                conv = c if conv is None else conv * c
        cols = [drive.response(h, conv, heat_J=drive.travel, lam=lam)]
        cols += list(drive.geometric.T)
        for name in effects:
            eff = self.catalog[name]
            if eff.hook == "heat" and eff.unit_inputs is not None:
                for hj, src in eff.unit_inputs(drive):
                    cols.append(drive.response(h, conv, heat_J=hj, source_W=src, lam=lam))
            elif eff.hook == "output" and eff.columns is not None:
                cols += list(np.asarray(eff.columns(drive), dtype=float).T)
        offset = 0.0 if drive.air_K is None else drive.response(h, conv, air_K=drive.air_K, lam=lam)
        return np.column_stack(cols), offset - drive.reference_um

    # ------------------------------------------------------------ fit / predict

    def fit(self, runs, masks, effects, start=None):
        effects = tuple(effects)
        for name in effects:
            if name not in self.catalog:
                raise ValueError("unknown effect %r (catalog: %s)" % (name, ", ".join(self.catalog)))
        nl, lin = self._layout(effects)
        nl_names = [p[0] for p in nl]
        lo = np.array([p[1] for p in nl])
        hi = np.array([p[2] for p in nl])
        x0 = np.array([p[3] for p in nl], dtype=float)
        if start is not None:
            for i, name in enumerate(nl_names):
                if name in start.nonlinear:
                    v = start.nonlinear[name]
                    x0[i] = np.log(v) if name in LOG_PARAMS else v
        x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        if self.error_reference is None:
            common_error_reference(runs)  # one convention per fit: names the runs of each reference otherwise
        used = [(self.drive(r), m) for r, m in zip(runs, masks) if m is not None and np.any(m)]
        if not used:
            raise ValueError("no rows to fit on")
        y = np.concatenate([d.error_um[m] for d, m in used])
        blo = np.array([p[1] for p in lin])
        bhi = np.array([p[2] for p in lin])
        # weak prior on effect amplitudes (zero-mean, sd = the prior half-range, worth
        # PRIOR_WEIGHT_UM^2 of squared error): negligible where the data identify the
        # amplitude, and it pins amplitudes the training rows cannot see (one feed
        # only, say) to zero instead of to an arbitrary point of a flat direction
        n_base = 2 + self.geometric_degree
        prior = np.zeros(len(lin))
        for j, p in enumerate(lin[n_base:], start=n_base):
            prior[j] = PRIOR_WEIGHT_UM / (0.5 * (p[2] - p[1]))
        P = np.diag(prior)[prior > 0]
        cache = {}

        def solve(x):
            key = tuple(np.round(x, 12))
            if key not in cache:
                parts = [(self._design(d, effects, x, nl_names), m) for d, m in used]
                X = np.vstack([Xd[m] for (Xd, _), m in parts] + [P])
                off = np.concatenate([np.broadcast_to(o, m.shape)[m] for (_, o), m in parts])
                yy = np.concatenate([y - off, np.zeros(P.shape[0])])
                # scale columns so the bounded solver sees a well-conditioned problem
                s = np.sqrt(np.sum(X ** 2, axis=0))
                s[s == 0] = 1.0
                beta = _bounded_lstsq(X / s, yy, blo * s, bhi * s) / s
                cache.clear()
                cache[key] = (beta, yy - X @ beta)
            return cache[key]

        opt = least_squares(lambda x: solve(x)[1], x0, bounds=(lo, hi), x_scale=1.0, diff_step=1e-4, xtol=1e-6, ftol=1e-8, max_nfev=60)
        beta, r = solve(opt.x)
        r = r[: y.size]
        nonlinear = {n: float(np.exp(v) if n in LOG_PARAMS else v) for n, v in zip(nl_names, opt.x)}
        linear = {p[0]: float(b) for p, b in zip(lin, beta)}
        return ScrewFit(effects, nonlinear, linear, float(np.sqrt(np.mean(r ** 2))), int(opt.nfev))

    def predict(self, fitted, run):
        nl, lin = self._layout(fitted.effects)
        nl_names = [p[0] for p in nl]
        x = np.array([np.log(fitted.nonlinear[n]) if n in LOG_PARAMS else fitted.nonlinear[n] for n in nl_names])
        X, offset = self._design(self.drive(run), fitted.effects, x, nl_names)
        beta = np.array([fitted.linear[p[0]] for p in lin])
        return X @ beta + offset
