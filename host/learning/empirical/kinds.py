"""The empirical model documents ``poly_slope`` and ``linear_direct`` (docs/model-format.md).

Both are plain linear functions of temperature rises ``T_s − ref_s``:

* ``poly_slope``: δ(P, T) = Σ_j g_j·P^j + s(T)·P, s(T) = b0 + Σ_s b_s·(T_s − ref_s) (µm/mm);
* ``linear_direct``: δ(T) = b0 + Σ_s b_s·(T_s − ref_s) (µm), one channel at a fixed point.

The rise reference is declared in ``thermal.reference`` (an additive key of
the document; absent means ``"fixed"``): ``"fixed"`` (ref_s = ``reference_C``,
the contract of docs/model-format.md that the exporter and firmware implement;
the default of ``tcomp fit``) or ``"run_start"`` (ref_s is the evaluated run's
first temperature sample, i.e. a controller that latches temperatures at the
cold start; the literature's ΔT, used by ``tcomp compare`` by default).
``reference_C`` always holds the mean cold-start temperature of the training
runs, so a consumer that only supports a fixed reference still gets the
training runs' typical start state.

``predict(run)`` returns one value per row of ``run.errors`` in file order;
rows of other channels than the model's are NaN.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from numpy.typing import ArrayLike

import math
from typing import Any

import numpy as np

from host.data.runs import START, check_model_reference
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.targets import _channel_rows
from host.learning.documents import ModelFormatError
from models_export.document import FORMAT

REFERENCES = ("run_start", "fixed")


def document_target(thermal: dict[str, Any], kind: str) -> str:
    """``thermal.target`` of a ``kind`` document whose thermal part is 'slope' or 'direct'; else ModelFormatError."""
    target = thermal.get("target")
    if target not in ("slope", "direct"):
        raise ModelFormatError("%s model document: thermal.target must be 'slope' or 'direct', found %r" % (kind, target))
    return target


class DocumentFields:
    """The document fields every empirical kind writes alike (_Base's models here, dynamic.py's DynamicModel): the
    model's identity (format .. reference_C), the fit's record (envelope, statistics, training), a slope model's
    geometric part; the attributes below are what they read."""

    kind: str | None
    method: str
    axis: str | None
    channel: str | None
    sensors: list[str]
    reference_C: dict[str, float]
    envelope: dict[str, Any]
    statistics: dict[str, Any]
    training: dict[str, Any]
    target: str | None
    geometric_coef: np.ndarray

    @property
    def error_reference(self) -> str:
        """The convention of the training errors ("start" for documents written before it was recorded)."""
        return self.training.get("error_reference", START)

    def _identity_doc(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "kind": self.kind,
            "method": self.method,
            "axis": self.axis,
            "channel": self.channel,
            "sensors": list(self.sensors),
            "error_reference": self.error_reference,
            "reference_C": dict(self.reference_C),
        }

    def _record_doc(self) -> dict[str, Any]:
        return {"envelope": self.envelope, "statistics": self.statistics, "training": self.training}

    def _geometric_doc(self) -> dict[str, Any] | None:
        """The document's ``geometric`` part: the polynomial of a slope model, none for a direct one."""
        if self.target == "direct":
            return None
        return {"degree": int(self.geometric_coef.size - 1), "coefficients_um": [float(c) for c in self.geometric_coef]}


class _Base(DocumentFields):
    """Shared inputs and document fields. Subclasses give ``target`` ("slope": the thermal part
    is a slope in µm/mm multiplied by P; "direct": an error in µm) and ``thermal(R)`` of rises R."""

    kind = None
    target = None
    # set by host.learning.empirical.fitting.fit_model (the fitted estimator and its data), absent on loaded documents
    estimator_: Any = None
    arrays_: Any = None
    geometric_: Any = None
    # declared for the shared code here, set by the subclasses: thermal(R) as the docstring says; geometric_coef by
    # the slope models (the only ones whose _geometric_doc reads it)
    thermal: Callable[..., np.ndarray]  # ...: a method of the subclass (self, R), or a plain function of R
    geometric_coef: np.ndarray

    def __init__(self, sensors, coefficients, intercept, reference_C, reference="fixed", channel=None, method="mlr", axis=None,
                 envelope=None, statistics=None, training=None):
        self.sensors = list(sensors)
        # None: a model that is not a linear function of the rises (ann)
        self.coefficients = None if coefficients is None else np.asarray(coefficients, dtype=float)
        if self.coefficients is not None and self.coefficients.shape != (len(self.sensors),):
            raise EmpiricalDataError("%d coefficients for %d sensors" % (self.coefficients.size, len(self.sensors)))
        self.intercept = float(intercept)
        self.reference_C = {s: float(reference_C[s]) for s in self.sensors}
        if reference not in REFERENCES:
            raise EmpiricalDataError("thermal.reference must be one of %s, got %r" % (", ".join(REFERENCES), reference))
        self.reference = reference
        self.channel = channel
        self.method = method
        self.axis = axis
        self.envelope = envelope or {}
        self.statistics = statistics or {}
        self.training = training or {}

    # ------------------------------------------------------------ inputs
    def rises(self, run, times):
        """(len(times), n_sensors) temperature rises at ``times`` under this model's reference."""
        temps = run.temperatures
        missing = [s for s in self.sensors if s not in temps.names]
        if missing:
            raise EmpiricalDataError("%s: the model needs sensor(s) %s, not in temperatures.csv" % (run.name, ", ".join(missing)))
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if times.size and (times.min() < temps.time_s[0] or times.max() > temps.time_s[-1]):
            # np.interp would hold the end values: a prediction from temperatures nobody measured
            bad = times[(times < temps.time_s[0]) | (times > temps.time_s[-1])][0]
            raise EmpiricalDataError("%s: errors.csv time %g s is outside the temperature log %g..%g s (no extrapolation)"
                                     % (run.name, bad, temps.time_s[0], temps.time_s[-1]))
        T = temps.at(times, self.sensors)
        if self.reference == "run_start":
            ref = np.array([temps.column(s)[0] for s in self.sensors])
        else:
            ref = np.array([self.reference_C[s] for s in self.sensors])
        R = T - ref
        bad = np.argwhere(~np.isfinite(R))
        if bad.size:
            i, j = bad[0]
            raise EmpiricalDataError("%s: sensor %s reads NaN/inf at %g s (temperatures.csv); no prediction from it"
                                     % (run.name, self.sensors[j], times[i]))
        return R

    def thermal_at(self, run, times):
        """The thermal part at ``times`` of ``run``: slope in µm/mm (target "slope") or error in µm."""
        return self.thermal(self.rises(run, times))

    def geometric(self, P):
        return np.zeros(np.shape(P))

    def predict(self, run):
        try:
            check_model_reference(run, self.error_reference)
        except ValueError as exc:
            raise EmpiricalDataError(str(exc))
        e = run.errors
        out = np.full(len(e), np.nan)
        rows = self._rows(run)
        th = self.thermal_at(run, e.time_s[rows])
        if self.target == "slope":
            P = e.position_mm[rows]
            out[rows] = self.geometric(P) + th * P
        else:
            out[rows] = th
        return out

    def _rows(self, run):
        if self.channel is None and run.errors.channel is not None and len(run.errors.channels()) > 1:
            raise EmpiricalDataError("%s: errors.csv has channels %s but the model names none" % (run.name, ", ".join(run.errors.channels())))
        if self.channel is not None and run.errors.channel is None:
            return np.arange(len(run.errors))  # single-channel run: the model applies to all rows
        return _channel_rows(run, self.channel)

    def _common_doc(self):
        return {**self._identity_doc(), **self._record_doc()}

    @staticmethod
    def _common_args(doc):
        where = "%s model document" % doc.get("kind", "model")
        for key in ("thermal", "sensors", "reference_C"):
            if key not in doc:
                raise ModelFormatError("%s lacks the field '%s'" % (where, key))
        thermal, sensors, ref = doc["thermal"], doc["sensors"], doc["reference_C"]
        if not isinstance(thermal, dict):
            raise ModelFormatError("%s: field 'thermal' must be an object, found %s" % (where, type(thermal).__name__))
        if not isinstance(sensors, list) or not all(isinstance(s, str) for s in sensors):
            raise ModelFormatError("%s: field 'sensors' must be a list of sensor names" % where)
        if not isinstance(ref, dict):
            raise ModelFormatError("%s: field 'reference_C' must be an object {sensor: degC}, found %s" % (where, type(ref).__name__))
        missing = [s for s in sensors if s not in ref]
        if missing:
            raise ModelFormatError("%s: reference_C has no entry for %s" % (where, ", ".join(missing)))
        bad = [s for s in sensors if not _is_number(ref[s])]
        if bad:
            raise ModelFormatError("%s: reference_C.%s must be a finite number, found %r" % (where, bad[0], ref[bad[0]]))
        if doc.get("channel") is not None and not isinstance(doc.get("channel"), str):
            raise ModelFormatError("%s: field 'channel' must be a channel name (string) or null, found %r" % (where, doc.get("channel")))
        if thermal.get("reference", "fixed") not in REFERENCES:
            raise ModelFormatError("%s: thermal.reference must be one of %s, got %r" % (where, ", ".join(REFERENCES), thermal.get("reference")))
        return thermal, sensors, ref, dict(
            reference=thermal.get("reference", "fixed"), channel=doc.get("channel"), method=doc.get("method", "mlr"), axis=doc.get("axis"),
            envelope=doc.get("envelope"), statistics=doc.get("statistics"), training=doc.get("training"),
        )


def _is_number(v):
    # JSON may carry NaN/Infinity (Python's json writes them); a model with one predicts nothing useful
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _thermal_terms(doc, thermal, sensors, coef_key, intercept_key):
    """(coefficients in sensor order, intercept) from ``thermal``, each problem named by its field."""
    kind = doc.get("kind")
    if coef_key not in thermal:
        other = [k for k in ("coefficients_um_per_K", "coefficients_um_per_mm_per_K") if k != coef_key and k in thermal]
        hint = " (it has thermal.%s: is 'kind' wrong?)" % other[0] if other else ""
        raise ModelFormatError("%s model document lacks the field thermal.%s%s" % (kind, coef_key, hint))
    coefs = thermal[coef_key]
    if not isinstance(coefs, dict):
        raise ModelFormatError("%s model document: thermal.%s must be an object {sensor: number}, found %s"
                               % (kind, coef_key, type(coefs).__name__))
    missing = [s for s in sensors if s not in coefs]
    if missing:
        raise ModelFormatError("%s model document: thermal.%s has no entry for sensor(s) %s" % (kind, coef_key, ", ".join(missing)))
    for s in sensors:
        if not _is_number(coefs[s]):
            raise ModelFormatError("%s model document: thermal.%s.%s must be a finite number, found %r" % (kind, coef_key, s, coefs[s]))
    b0 = thermal.get(intercept_key, 0.0)
    if not _is_number(b0):
        raise ModelFormatError("%s model document: thermal.%s must be a finite number, found %r" % (kind, intercept_key, b0))
    return [coefs[s] for s in sensors], b0


class LinearDirectModel(_Base):
    """δ(T) = intercept + Σ coefficients·(T − ref), µm, for one channel at a fixed point."""

    kind = "linear_direct"
    target = "direct"

    def predict_rises(self, R: ArrayLike) -> np.ndarray:
        return self.intercept + np.asarray(R, dtype=float) @ self.coefficients

    thermal = predict_rises

    def to_document(self) -> dict[str, Any]:
        assert self.coefficients is not None  # a linear model always has them (None only for the ann's NetworkModel)
        doc = self._common_doc()
        doc["geometric"] = None
        doc["thermal"] = {
            "intercept_um": self.intercept,
            "coefficients_um_per_K": {s: float(c) for s, c in zip(self.sensors, self.coefficients)},
            "reference": self.reference,
        }
        return doc

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> LinearDirectModel:
        thermal, sensors, ref, kw = cls._common_args(doc)
        coefs, b0 = _thermal_terms(doc, thermal, sensors, "coefficients_um_per_K", "intercept_um")
        return cls(sensors, coefs, b0, ref, **kw)


class PolySlopeModel(_Base):
    """δ(P, T) = geometric(P) + (intercept + Σ coefficients·(T − ref))·P, µm."""

    kind = "poly_slope"
    target = "slope"

    def __init__(self, sensors: Sequence[str], coefficients: ArrayLike, intercept: float, reference_C: dict[str, float], geometric_coef: ArrayLike = (0.0,), **kw: Any) -> None:
        super().__init__(sensors, coefficients, intercept, reference_C, **kw)
        self.geometric_coef = np.asarray(geometric_coef, dtype=float)

    def slope(self, R: ArrayLike) -> np.ndarray:
        """Thermal slope s(T) in µm/mm for rises R (n, p)."""
        return self.intercept + np.asarray(R, dtype=float) @ self.coefficients

    thermal = slope

    def geometric(self, P: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(P, dtype=float), self.geometric_coef)

    def to_document(self) -> dict[str, Any]:
        assert self.coefficients is not None  # a linear model always has them (None only for the ann's NetworkModel)
        doc = self._common_doc()
        doc["geometric"] = self._geometric_doc()
        doc["thermal"] = {
            "intercept_um_per_mm": self.intercept,
            "coefficients_um_per_mm_per_K": {s: float(c) for s, c in zip(self.sensors, self.coefficients)},
            "reference": self.reference,
        }
        return doc

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> PolySlopeModel:
        thermal, sensors, ref, kw = cls._common_args(doc)
        coefs, b0 = _thermal_terms(doc, thermal, sensors, "coefficients_um_per_mm_per_K", "intercept_um_per_mm")
        return cls(sensors, coefs, b0, ref, geometric_coef=_geometric_from_document(doc, "poly_slope"), **kw)


def _geometric_from_document(doc, kind):
    geo = doc.get("geometric") or {"coefficients_um": [0.0]}
    if not isinstance(geo, dict) or not isinstance(geo.get("coefficients_um", [0.0]), list) \
            or not all(_is_number(c) for c in geo.get("coefficients_um", [0.0])):
        raise ModelFormatError("%s model document: geometric.coefficients_um must be a list of finite numbers" % kind)
    return geo.get("coefficients_um", [0.0])


class NetworkModel(_Base):
    """An estimator that is not linear in the rises (ann, ppr): thermal part = estimator.predict(R).

    ``target`` "slope": δ(P, T) = geometric(P) + f(R)·P; "direct": δ(T) = f(R).
    Its document is the ann's (kind ``ann``); PPRModel below is the ppr's.
    """

    kind = "ann"

    def __init__(self, sensors: Sequence[str], estimator: Any, reference_C: dict[str, float], target: str = "direct", geometric_coef: ArrayLike = (0.0,), **kw: Any) -> None:
        super().__init__(sensors, None, 0.0, reference_C, **kw)
        if target not in ("slope", "direct"):
            raise EmpiricalDataError("target must be slope or direct, got %r" % (target,))
        self.target = target
        self.estimator_ = estimator
        self.geometric_coef = np.asarray(geometric_coef, dtype=float)

    def thermal(self, R: ArrayLike) -> np.ndarray:
        return self.estimator_.predict(np.asarray(R, dtype=float).reshape(-1, len(self.sensors)))

    def geometric(self, P: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(P, dtype=float), self.geometric_coef)

    def _estimator_doc(self, key: str, block: dict[str, Any]) -> dict[str, Any]:
        """The document of a network-like model: ``thermal.<key>`` holds what its estimator predicts with."""
        doc = self._common_doc()
        doc["geometric"] = self._geometric_doc()
        doc["thermal"] = {"target": self.target, "unit": "um_per_mm" if self.target == "slope" else "um", "reference": self.reference,
                          key: block}
        return doc

    @classmethod
    def _estimator_args(cls, doc: dict[str, Any], key: str) -> tuple[list[str], dict[str, float], str, dict[str, Any], dict[str, Any]]:
        """(sensors, reference_C, target, the object thermal.<key>, the common keywords) of a ``cls.kind`` document."""
        thermal, sensors, ref, kw = cls._common_args(doc)
        target = document_target(thermal, str(cls.kind))
        block = thermal.get(key)
        if not isinstance(block, dict):
            raise ModelFormatError("%s model document lacks the object thermal.%s" % (cls.kind, key))
        return sensors, ref, target, block, kw

    def to_document(self) -> dict[str, Any]:
        if not hasattr(self.estimator_, "network"):
            raise ModelFormatError("a %s model has no document form (only ann networks are saved)" % self.method)
        return self._estimator_doc("network", self.estimator_.network())

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> NetworkModel:
        from host.learning.empirical.ann import ANN

        sensors, ref, target, net, kw = cls._estimator_args(doc, "network")
        if net.get("activation") != "tanh":
            raise ModelFormatError("ann model document: thermal.network.activation must be 'tanh', found %r" % (net.get("activation"),))
        p = len(sensors)
        vec = {"input_offset": p, "input_scale": p, "hidden_bias": None, "output_weights": None}
        for key, size in vec.items():
            v = net.get(key)
            if not isinstance(v, list) or not all(_is_number(x) for x in v) or (size is not None and len(v) != size):
                raise ModelFormatError("ann model document: thermal.network.%s must be a list of %s finite numbers"
                                       % (key, size if size is not None else "hidden-size"))
        h = len(net["hidden_bias"])
        W = net.get("hidden_weights")
        if not isinstance(W, list) or len(W) != h or not all(isinstance(r, list) and len(r) == p and all(_is_number(x) for x in r) for r in W):
            raise ModelFormatError("ann model document: thermal.network.hidden_weights must be %d rows of %d finite numbers" % (h, p))
        if len(net["output_weights"]) != h:
            raise ModelFormatError("ann model document: thermal.network.output_weights needs %d numbers (one per hidden node)" % h)
        if any(x <= 0 for x in net["input_scale"]):
            raise ModelFormatError("ann model document: thermal.network.input_scale values must be > 0")
        for key in ("output_bias", "output_offset", "output_scale"):
            if not _is_number(net.get(key)):
                raise ModelFormatError("ann model document: thermal.network.%s must be a finite number, found %r" % (key, net.get(key)))
        geo = _geometric_from_document(doc, "ann") if target == "slope" else (0.0,)
        return cls(sensors, ANN.from_network(net), ref, target=target, geometric_coef=geo, **kw)


class PPRModel(NetworkModel):
    """A projection pursuit regression (ppr.py) as a document (kind ``ppr``): thermal part = ȳ + Σ g_m(a_m·z).

    ``thermal.ridges`` holds what PPR.predict reads (ppr.py PPR.ridges): each term's unit direction on the
    standardised rises, its natural-spline knots and coefficients. Predict reads it back; export refuses it:
    a ridge function is a spline of a projection, which no table kind of the firmware evaluates.
    """

    kind = "ppr"

    def to_document(self) -> dict[str, Any]:
        return self._estimator_doc("ridges", self.estimator_.ridges())

    @classmethod
    def from_document(cls, doc: dict[str, Any]) -> PPRModel:
        from host.learning.empirical.ppr import PPR

        sensors, ref, target, ridges, kw = cls._estimator_args(doc, "ridges")
        p = len(sensors)

        def numbers(v, size, where):
            if not isinstance(v, list) or not all(_is_number(x) for x in v) or (size is not None and len(v) != size):
                raise ModelFormatError("ppr model document: thermal.ridges.%s must be a list of %s finite numbers"
                                       % (where, size if size is not None else "at least 3"))
            return v

        numbers(ridges.get("input_offset"), p, "input_offset")
        if any(x <= 0 for x in numbers(ridges.get("input_scale"), p, "input_scale")):
            raise ModelFormatError("ppr model document: thermal.ridges.input_scale values must be > 0")
        if not _is_number(ridges.get("output_offset")):
            raise ModelFormatError("ppr model document: thermal.ridges.output_offset must be a finite number, found %r"
                                   % (ridges.get("output_offset"),))
        terms = ridges.get("terms")
        if not isinstance(terms, list) or not terms or not all(isinstance(t, dict) for t in terms):
            raise ModelFormatError("ppr model document: thermal.ridges.terms must be a non-empty list of objects")
        for m, t in enumerate(terms):
            numbers(t.get("direction"), p, "terms[%d].direction" % m)
            knots = numbers(t.get("knots"), None, "terms[%d].knots" % m)
            if len(knots) < 3 or any(b <= a for a, b in zip(knots, knots[1:])):
                # the natural spline basis divides by the distance of each knot to the last
                raise ModelFormatError("ppr model document: thermal.ridges.terms[%d].knots must be at least 3 increasing numbers" % m)
            numbers(t.get("coefficients"), len(knots), "terms[%d].coefficients" % m)
        geo = _geometric_from_document(doc, "ppr") if target == "slope" else (0.0,)
        return cls(sensors, PPR.from_ridges(ridges), ref, target=target, geometric_coef=geo, **kw)
