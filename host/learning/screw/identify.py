"""Parameter identification: bounded nonlinear least squares, Jacobian uncertainty,
flat-direction (non-identifiability) diagnosis.

Positive parameters are searched in log space (relative steps, and the reported
standard error is then a relative one); the others linearly.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import warnings

import numpy as np
from scipy.optimize import least_squares

if TYPE_CHECKING:
    from host.learning.screw.effects import ParamSpec


class IdentifiabilityWarning(UserWarning):
    """The data do not pin down a parameter (a flat direction of the cost)."""


def _to_x(values, specs):
    return np.array([np.log(v) if s.positive else v for v, s in zip(values, specs)], dtype=float)


def _from_x(x, specs):
    return np.array([np.exp(v) if s.positive else v for v, s in zip(x, specs)], dtype=float)


def fit_parameters(residual: Callable[[np.ndarray], np.ndarray], specs: Sequence[ParamSpec], start: ArrayLike | None = None, max_nfev: int = 200, flat_ratio: float = 1e-4, poor_rel_std: float = 0.5, n_linear: int = 0, ftol: float = 1e-12) -> dict[str, Any]:
    """Minimise ||residual(values)||² over the parameters described by ``specs``.

    residual: values (array, in spec order) -> residual vector; n_linear: linear
    parameters already profiled out of it (they use degrees of freedom too); ftol: relative change of the
    cost that ends the search (xtol is 100 times it, gtol as ftol).
    Returns dict: values, std (absolute), rel_std, cov_x (in search coordinates),
    rmse, n, dof, cost, nfev, status, message, flat (list of
    {"parameters": [...], "singular_ratio": r}), poor (names), warnings (strings).
    Emits IdentifiabilityWarning for every flat direction and poorly identified parameter."""
    start = np.array([s.start for s in specs], dtype=float) if start is None else np.asarray(start, dtype=float)
    lo = _to_x([max(s.lo, 1e-300) if s.positive else s.lo for s in specs], specs)
    hi = _to_x([s.hi for s in specs], specs)
    x0 = np.clip(_to_x(start, specs), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    def fun(x):
        return residual(_from_x(x, specs))

    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev, method="trf", xtol=100 * ftol, ftol=ftol, gtol=100 * ftol)
    values = _from_x(sol.x, specs)
    r = sol.fun
    n, p = r.size, len(specs)
    if n < p + int(n_linear):
        # least_squares returns a point, but the SVD below has fewer singular values than parameters.
        raise ValueError("%d residuals for %d parameters (%d linear): underdetermined, add data" % (n, p + int(n_linear), int(n_linear)))
    dof = max(n - p - int(n_linear), 1)
    s2 = float(r @ r) / dof
    J = sol.jac
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    smax = sv[0] if sv.size and sv[0] > 0 else 1.0
    ratio = sv / smax
    inv = np.where(ratio > 1e-12, 1.0 / np.where(sv > 0, sv, 1.0) ** 2, np.inf)
    cov_x = (Vt.T * inv) @ Vt * s2 if np.all(np.isfinite(inv)) else np.full((p, p), np.inf)
    var_x = np.diag(cov_x) if np.all(np.isfinite(cov_x)) else np.array([np.sum(Vt[:, j] ** 2 * inv) * s2 for j in range(p)])
    sd_x = np.sqrt(np.clip(var_x, 0, None))
    std = np.array([v * sd if s.positive else sd for v, sd, s in zip(values, sd_x, specs)])
    rel = np.array([sd if s.positive else (sd / abs(v) if v != 0 else np.inf) for v, sd, s in zip(values, sd_x, specs)])
    msgs, flat, poor = [], [], []
    for k in range(p):
        if ratio[k] < flat_ratio:
            comp = np.abs(Vt[k])
            names = [specs[j].name for j in np.argsort(-comp) if comp[j] > 0.2 * comp.max()]
            flat.append({"parameters": names, "singular_ratio": float(ratio[k])})
            if len(names) == 1:
                msgs.append("flat direction (singular value ratio %.2g): %s has no visible effect on these data; fix it "
                            "(--option free=...) or add runs that excite it" % (ratio[k], names[0]))
            else:
                msgs.append("flat direction (singular value ratio %.2g): %s cannot be told apart from the data; fix all but one of them "
                            "(--option free=...) or add runs with other moving states" % (ratio[k], " / ".join(names)))
    for j, s in enumerate(specs):
        if s.positive and rel[j] > poor_rel_std:
            poor.append(s.name)
            msgs.append("parameter %s is poorly identified (relative standard error %.0f %%)" % (s.name, 100 * rel[j]))
        at_bound = np.isclose(sol.x[j], lo[j], rtol=0, atol=1e-6 * max(1.0, abs(lo[j]))) or np.isclose(sol.x[j], hi[j], rtol=0, atol=1e-6 * max(1.0, abs(hi[j])))
        if at_bound:
            msgs.append("parameter %s ended at its bound (%g, bounds %g..%g): the best fit lies at or beyond it" % (s.name, values[j], s.lo, s.hi))
    for m in msgs:
        warnings.warn(m, IdentifiabilityWarning, stacklevel=2)
    return {
        "values": values, "std": std, "rel_std": rel, "cov_x": cov_x, "singular_ratios": ratio,
        "rmse": float(np.sqrt(np.mean(r ** 2))) if n else float("nan"), "n": int(n), "dof": int(dof),
        "cost": float(sol.cost), "nfev": int(sol.nfev), "status": int(sol.status), "message": sol.message,
        "flat": flat, "poor": poor, "warnings": msgs,
    }
