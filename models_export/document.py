"""The model document's schema (docs/model-format.md), one source: its format tag, its kinds, the
blocks that define what a model predicts, the checks every kind passes before it is read, and its hash.

The exporter depends on the document format only, never on the host classes that fit models;
host/learning/documents.py (save, load by kind), the fitting code that writes documents and the
HIL fixtures all take the format tag, the kinds and the hash from here.
"""

from __future__ import annotations

from typing import Any
import hashlib
import json
import math

FORMAT = "tcomp-model/1"  # the value of a document's "format" key
DOCUMENT_KINDS = ("poly_slope", "linear_direct", "screw", "ann", "dynamic", "mr_poly", "ppr")  # the values of its "kind" key


def canonical(doc: dict[str, Any]) -> bytes:
    """The document without its provenance block as canonical JSON bytes (sorted keys, no spaces)."""
    body = {k: v for k, v in doc.items() if k != "provenance"}
    return json.dumps(body, sort_keys=True, separators=(",", ":")).encode()


def document_hash(doc: dict[str, Any]) -> str:
    """sha256 hex of the document without its provenance block."""
    return hashlib.sha256(canonical(doc)).hexdigest()


def provenance(doc: dict[str, Any]) -> tuple[str, str | None]:
    """(actual sha256, the recorded provenance.sha256 or None). A recorded hash that differs from the actual one
    means the document was edited after it was saved: export refuses it and predict refuses it alike, unless
    told (``--allow-edited``)."""
    prov = doc.get("provenance")
    declared = prov.get("sha256") if isinstance(prov, dict) else None
    return document_hash(doc), declared


def edited_reason(declared: str | None, actual: str) -> str:
    """The one sentence both export and predict give for an edited document."""
    return ("provenance.sha256 %.16s... does not match the document (actual %.16s...): it was edited after it was "
            "saved; re-save it, or use it marked as edited (--allow-edited)" % (declared, actual))
# Blocks that define what a model predicts (statistics and training may hold NaN, e.g. an undefined p-value).
DEFINING_BLOCKS = ("sensors", "reference_C", "envelope", "geometric", "thermal")
_COEFFICIENTS: dict[str | None, str] = {"poly_slope": "coefficients_um_per_mm_per_K", "linear_direct": "coefficients_um_per_K"}


def _non_finite(value, where):
    """JSON path of the first NaN/Infinity in ``value`` (Python's json reads both, and 1e400 as Infinity), or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        found = _non_finite(v, "%s[%d]" % (where, k) if isinstance(k, int) else "%s.%s" % (where, k))
        if found:
            return found
    return None


def document_problem(doc: dict[str, Any]) -> str | None:
    """What makes ``doc`` say something other than what predict and export would use, or None.

    Checked for every kind before either reads it: a sensor listed twice, a coefficient of no listed sensor
    (it would be dropped without a word), a geometric degree its coefficients do not have, NaN/Infinity.
    """
    for key in DEFINING_BLOCKS:
        where = _non_finite(doc.get(key), key)
        if where:
            return "%s must be a finite number, found NaN or Infinity (a model cannot predict with it)" % where
    sensors = doc.get("sensors")
    if isinstance(sensors, list) and all(isinstance(s, str) for s in sensors):
        twice = sorted({s for s in sensors if sensors.count(s) > 1})
        if twice:
            return "sensors lists %s more than once (each sensor has one coefficient and one table channel)" % ", ".join(twice)
        thermal = doc.get("thermal")
        key = _COEFFICIENTS.get(doc.get("kind"))
        coefs = thermal.get(key) if key and isinstance(thermal, dict) else None
        if isinstance(coefs, dict):
            extra = [s for s in coefs if s not in sensors]
            if extra:
                return ("thermal.%s has %s, which %s not in sensors (%s); the coefficient would be dropped without a word"
                        % (key, ", ".join(map(str, extra)), "is" if len(extra) == 1 else "are", ", ".join(map(str, sensors))))
    prov = doc.get("provenance")
    if prov is not None and (not isinstance(prov, dict) or not isinstance(prov.get("sha256", ""), (str, type(None)))):
        return "provenance must be an object whose sha256 is a hex string, found %r" % (prov,)
    geo = doc.get("geometric")
    if isinstance(geo, dict) and isinstance(geo.get("coefficients_um"), list):
        n = len(geo["coefficients_um"])
        if n == 0 and doc.get("kind") != "screw":
            return "geometric.coefficients_um is empty (it holds at least the constant term; [0.0] for none)"
        degree = geo.get("degree")
        if degree is not None and n and (isinstance(degree, bool) or not isinstance(degree, int) or degree != n - 1):
            return "geometric.degree is %r but geometric.coefficients_um has %d coefficient%s (degree %d)" % (
                degree, n, "" if n == 1 else "s", n - 1)
    return None
