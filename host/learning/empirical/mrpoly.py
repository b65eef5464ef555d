"""S004's multiple-regression model (Eq. 12) as an estimator and a model document (kind ``mr_poly``).

    E = (a_m·ΔTn^m + … + a_2·ΔTn² + a_1·ΔTn + b_1·ΔTb + c)·P        (slope target, µm)

Tn is the nut sensor, Tb the base sensor (roles in the run's meta.json, overridable), m the degree (exact,
default 4 as in the paper; S004: "the maximum degree m ≤ 4"). S004 notes that rises ΔT give the same fit as
absolute temperatures (only the coefficients change); tcomp uses rises, as every other empirical model, so the
board's latched references apply. The coefficients come from ordinary least squares on the powers of the nut
rise (scaled to unit RMS for conditioning, mapped back exactly) and the base rise.

On the board the model is a ``dynamic`` table whose filters all have τ = 0 (they pass their input through)
and read the nut rise, its powers and the base rise (models_export/exact.py; docs/table-format.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.kinds import _Base, _geometric_from_document, _is_number, document_target
from host.learning.empirical.checks import check_predict_x, check_xy, finite_or_none as _f
from host.learning.documents import ModelFormatError

if TYPE_CHECKING:
    from host.data.runs import Run

MAX_DEGREE = 4  # S004 (m <= 4); the board's power inputs go to the fourth


def features(R: np.ndarray, degree: int) -> np.ndarray:
    """(n, degree + 1) design: nut rise, its powers 2..degree, base rise (columns of R: nut, base)."""
    R = np.asarray(R, dtype=float).reshape(-1, 2)
    d = R[:, 0]
    return np.column_stack([d ** j for j in range(1, degree + 1)] + [R[:, 1]])


class MRPoly:
    """Least squares of y on [ΔTn, ΔTn², …, ΔTn^degree, ΔTb] (+ intercept).

    Parameters (keyword-only): ``degree`` (1..4, exact), ``fit_intercept``. ``fit(X, y, names)`` takes the
    two columns nut, base in that order. Learned: ``nut_coef_`` (a_1..a_m), ``base_coef_`` (b_1),
    ``intercept_``, ``rsquared_``, ``rmse_``, ``n_samples_``, ``names_``.
    """

    method = "mr-poly"

    def __init__(self, *, degree: int = MAX_DEGREE, fit_intercept: bool = True) -> None:
        self.degree = degree
        self.fit_intercept = fit_intercept

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> MRPoly:
        if isinstance(self.degree, bool) or not isinstance(self.degree, (int, np.integer)) or not 1 <= self.degree <= MAX_DEGREE:
            raise EmpiricalDataError("mr-poly: degree must be an integer 1..%d (S004: m <= 4), got %r" % (MAX_DEGREE, self.degree))
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != 2:
            raise EmpiricalDataError("mr-poly: needs exactly two sensors, the nut's then the base's; got %d column(s)"
                                     % (X.shape[1] if X.ndim == 2 else 1))
        k = self.degree + 1 + int(bool(self.fit_intercept))
        X, y, names = check_xy(X, y, names, k, "mr-poly")
        A = features(X, self.degree)
        scale = np.sqrt(np.mean(A ** 2, axis=0))
        scale[scale == 0] = 1.0
        Z = A / scale
        if self.fit_intercept:
            Z = np.column_stack([np.ones(len(y)), Z])
        beta, _, rank, _ = np.linalg.lstsq(Z, y, rcond=None)
        if rank < Z.shape[1]:
            raise EmpiricalDataError("mr-poly: the powers of %s and %s are collinear on these samples (rank %d of %d); "
                                     "lower the degree" % (names[0], names[1], rank, Z.shape[1]))
        b0 = float(beta[0]) if self.fit_intercept else 0.0
        coef = beta[int(bool(self.fit_intercept)):] / scale
        self.names_ = list(names)
        self.nut_coef_ = coef[:-1].astype(float)
        self.base_coef_ = float(coef[-1])
        self.intercept_ = b0
        self.n_samples_ = int(y.size)
        res = y - self.predict(X)
        sst = float(((y - y.mean()) ** 2).sum()) if self.fit_intercept else float(y @ y)
        self.rsquared_ = 1.0 - float(res @ res) / sst if sst > 0 else float("nan")
        self.rmse_ = float(np.sqrt(np.mean(res ** 2)))
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = check_predict_x(self, X, "nut_coef_", lambda: 2)
        return self.intercept_ + features(X, self.nut_coef_.size) @ np.append(self.nut_coef_, self.base_coef_)

    def statistics(self) -> dict[str, Any]:
        return {"n_samples": self.n_samples_, "r2": _f(self.rsquared_), "rmse": _f(self.rmse_), "degree": int(self.nut_coef_.size),
                "nut_sensor": self.names_[0], "base_sensor": self.names_[1]}


class MRPolyModel(_Base):
    """δ = geometric(P) + s·P (target "slope") or δ = s (target "direct"), s = c + Σ a_j ΔTn^j + b_1 ΔTb."""

    kind = "mr_poly"

    def __init__(self, sensors: Sequence[str], nut_coefficients: ArrayLike, base_coefficient: float, intercept: float, reference_C: dict[str, float], target: str = "slope", geometric_coef: ArrayLike = (0.0,), **kw: Any) -> None:
        super().__init__(sensors, None, intercept, reference_C, **kw)
        if len(self.sensors) != 2:
            raise EmpiricalDataError("mr_poly: sensors must be [nut, base], got %r" % (self.sensors,))
        if target not in ("slope", "direct"):
            raise EmpiricalDataError("mr_poly: target must be slope or direct, got %r" % (target,))
        self.target = target
        self.nut_coefficients = np.asarray(nut_coefficients, dtype=float)
        if not 1 <= self.nut_coefficients.size <= MAX_DEGREE:
            raise EmpiricalDataError("mr_poly: 1..%d nut coefficients (degree), got %d" % (MAX_DEGREE, self.nut_coefficients.size))
        self.base_coefficient = float(base_coefficient)
        self.geometric_coef = np.asarray(geometric_coef, dtype=float)

    @property
    def degree(self) -> int:
        return int(self.nut_coefficients.size)

    def thermal(self, R: np.ndarray) -> np.ndarray:
        return self.intercept + features(R, self.degree) @ np.append(self.nut_coefficients, self.base_coefficient)

    def geometric(self, P: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(P, dtype=float), self.geometric_coef)

    def to_document(self) -> dict[str, Any]:
        doc = self._common_doc()
        doc["geometric"] = self._geometric_doc()
        doc["thermal"] = {
            "target": self.target,
            "unit": "um_per_mm" if self.target == "slope" else "um",
            "reference": self.reference,
            "nut_sensor": self.sensors[0],
            "base_sensor": self.sensors[1],
            "degree": self.degree,
            "intercept": self.intercept,
            "nut_coefficients": [float(c) for c in self.nut_coefficients],
            "base_coefficient": self.base_coefficient,
        }
        return doc

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> MRPolyModel:
        thermal, sensors, ref, kw = cls._common_args(doc)
        target = document_target(thermal, "mr_poly")
        if len(sensors) != 2 or thermal.get("nut_sensor") != sensors[0] or thermal.get("base_sensor") != sensors[1]:
            raise ModelFormatError("mr_poly model document: sensors must be [thermal.nut_sensor, thermal.base_sensor], found %r with %r, %r"
                                   % (sensors, thermal.get("nut_sensor"), thermal.get("base_sensor")))
        a = thermal.get("nut_coefficients")
        if not isinstance(a, list) or not 1 <= len(a) <= MAX_DEGREE or not all(_is_number(v) for v in a):
            raise ModelFormatError("mr_poly model document: thermal.nut_coefficients must be a list of 1..%d finite numbers (a_1..a_m)"
                                   % MAX_DEGREE)
        if thermal.get("degree") != len(a):
            raise ModelFormatError("mr_poly model document: thermal.degree is %r but thermal.nut_coefficients holds %d"
                                   % (thermal.get("degree"), len(a)))
        for key in ("intercept", "base_coefficient"):
            if not _is_number(thermal.get(key)):
                raise ModelFormatError("mr_poly model document: thermal.%s must be a finite number, found %r" % (key, thermal.get(key)))
        geo = _geometric_from_document(doc, "mr_poly") if target == "slope" else (0.0,)
        return cls(sensors, a, thermal["base_coefficient"], thermal["intercept"], ref, target=target, geometric_coef=geo, **kw)


def role_sensors(runs: Sequence[Run], nut: str | None = None, base: str | None = None) -> list[str]:
    """[nut, base] sensor names: given, else the first sensor with role "nut" / "base" in the first run's meta.json."""
    out = []
    for role, given in (("nut", nut), ("base", base)):
        if given is None:
            have = [s for s in runs[0].sensors_with_role(role) if s in runs[0].temperatures.names]
            if not have:
                raise EmpiricalDataError("mr-poly: %s has no sensor with role %r in meta.json; name one with --option %s=SENSOR"
                                         % (runs[0].name, role, role))
            given = have[0]
        for r in runs:
            if given not in r.temperatures.names:
                raise EmpiricalDataError("mr-poly: %s sensor %r is not in %s's temperatures.csv" % (role, given, r.name))
        out.append(str(given))
    if out[0] == out[1]:
        raise EmpiricalDataError("mr-poly: the nut and base sensors must differ, both are %r" % out[0])
    return out
