"""The cold geometric error δ_G(P): a polynomial in position fitted to the cold sweeps.

The cold sweep of a run is its first sweep (per direction, see targets.py).
Repeats (both directions, several runs) are averaged point-wise at equal
positions first, so each measured position has one weight. The degree is
chosen, not fixed: every degree 1..max_degree that leaves at least two residual
degrees of freedom is fitted, and the one with the smallest leave-one-out
cross-validation error (PRESS, exact via the hat matrix) is kept (``criterion="aic"``:
smallest AIC = m·ln(RSS/m) + 2(d+1)). Ties go to the lower degree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.targets import sweep_slopes

if TYPE_CHECKING:
    from host.data.runs import Run

MAX_DEGREE = 6  # the table's geometric polynomial holds at most degree 6 (firmware/table.py)


class GeometricPolynomial:
    """Cold geometric error polynomial; ``coef_`` ascending powers of P (µm, mm).

    ``degree=N`` fixes the degree (Li 2021 uses 5, S004 4) instead of choosing one up to ``max_degree``."""

    def __init__(self, max_degree: int = 5, criterion: str = "cv", degree: int | None = None) -> None:
        self.max_degree = max_degree
        self.criterion = criterion
        self.degree = degree

    def fit(self, position_mm: ArrayLike, error_um: ArrayLike) -> GeometricPolynomial:
        if self.degree is not None and (isinstance(self.degree, bool) or not isinstance(self.degree, (int, np.integer))
                                        or not 1 <= self.degree <= MAX_DEGREE):
            raise EmpiricalDataError("geometric: geometric_degree must be an integer 1..%d (the table holds degree %d), got %r"
                                     % (MAX_DEGREE, MAX_DEGREE, self.degree))
        if self.criterion not in ("cv", "aic"):
            raise EmpiricalDataError("geometric: criterion must be 'cv' or 'aic', got %r" % self.criterion)
        P = np.asarray(position_mm, dtype=float)
        e = np.asarray(error_um, dtype=float)
        if P.shape != e.shape or P.ndim != 1:
            raise EmpiricalDataError("geometric: positions and errors must be 1-D of equal length")
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(e))):
            raise EmpiricalDataError("geometric: NaN in the cold sweep")
        # average repeats at equal positions
        pos, inv = np.unique(P, return_inverse=True)
        err = np.bincount(inv, weights=e) / np.bincount(inv)
        m = pos.size
        if self.degree is not None:
            if m < self.degree + 2:
                raise EmpiricalDataError("geometric: geometric_degree=%d needs at least %d distinct positions in the cold sweep, it has %d"
                                         % (self.degree, self.degree + 2, m))
            low, top = int(self.degree), int(self.degree)
        else:
            if int(self.max_degree) < 1:
                raise EmpiricalDataError("geometric: max_degree must be >= 1 (degrees 1..max_degree are compared), got %r" % self.max_degree)
            if m < 4:
                raise EmpiricalDataError("geometric: the cold sweep has %d distinct positions; at least 4 are needed to choose a degree" % m)
            low, top = 1, min(int(self.max_degree), m - 3)
        # scale positions to [-1, 1] for conditioning; coefficients converted back below
        c0, half = (pos.max() + pos.min()) / 2, (pos.max() - pos.min()) / 2
        u = (pos - c0) / half
        scores = []
        for d in range(low, top + 1):
            V = np.vander(u, d + 1, increasing=True)
            beta, *_ = np.linalg.lstsq(V, err, rcond=None)
            r = err - V @ beta
            H = V @ np.linalg.pinv(V)
            h = np.clip(np.diag(H), 0, 1 - 1e-12)
            press = float(np.sum((r / (1 - h)) ** 2))
            rss = float(r @ r)
            aic = m * np.log(max(rss, 1e-300) / m) + 2 * (d + 1)
            scores.append({"degree": d, "press": press, "cv_rmse_um": float(np.sqrt(press / m)), "rss": rss, "aic": float(aic)})
        key = "press" if self.criterion == "cv" else "aic"
        best = min(scores, key=lambda s: (round(s[key], 12), s["degree"]))
        d = best["degree"]
        beta, *_ = np.linalg.lstsq(np.vander(u, d + 1, increasing=True), err, rcond=None)
        # expand Σ β_j ((P − c0)/half)^j into ascending powers of P
        poly = np.polynomial.Polynomial(beta)
        lin = np.polynomial.Polynomial([-c0 / half, 1.0 / half])
        self.coef_ = np.asarray(poly(lin).coef, dtype=float)
        if self.coef_.size < d + 1:
            self.coef_ = np.pad(self.coef_, (0, d + 1 - self.coef_.size))
        self.degree_ = d
        self.scores_ = scores
        self.positions_ = pos
        self.mean_error_ = err
        self.rmse_ = float(np.sqrt(np.mean((err - self.predict(pos)) ** 2)))
        return self

    def predict(self, position_mm: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(position_mm, dtype=float), self.coef_)

    def to_document(self) -> dict[str, Any]:
        return {"degree": int(self.degree_), "coefficients_um": [float(c) for c in self.coef_]}


def cold_points(runs: Sequence[Run], channel: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions and errors of every run's cold sweep(s) (first sweep of each direction)."""
    P, e = [], []
    for r in runs:
        s = sweep_slopes(r, channel)
        seen = set()
        for d, rows in zip(s.direction, s.rows):
            if int(d) in seen:
                continue
            seen.add(int(d))
            P.append(r.errors.position_mm[rows])
            e.append(r.errors.error_um[rows])
    return np.concatenate(P), np.concatenate(e)


def fit_geometric(runs: Sequence[Run], channel: str | None = None, max_degree: int = 5, criterion: str = "cv", degree: int | None = None) -> GeometricPolynomial:
    """GeometricPolynomial fitted to the cold sweeps of ``runs`` (``degree``: exactly that degree)."""
    P, e = cold_points(runs, channel)
    return GeometricPolynomial(max_degree, criterion, degree).fit(P, e)
