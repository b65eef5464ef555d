"""The model document (docs/model-format.md): save, load by kind, predict.

Each kind's class lives with the code that fits it; this module only maps
``kind`` to that class so ``tcomp predict`` and ``tcomp export`` work on any model.
Every class has ``from_document(doc)``, ``to_document()`` and ``predict(run)``
(one predicted error in µm per row of ``run.errors``, in file order).
"""
import importlib
import json
import math
import time

from host import __version__
from models_export.document import document_hash

FORMAT = "tcomp-model/1"
KINDS = {
    "poly_slope": "host.empirical.model:PolySlopeModel",
    "linear_direct": "host.empirical.model:LinearDirectModel",
    "screw": "host.screw.model:ScrewModel",
    "ann": "host.empirical.model:NetworkModel",
    "dynamic": "host.empirical.dynamic:DynamicModel",
    "mr_poly": "host.empirical.mrpoly:MRPolyModel",
}


class ModelFormatError(ValueError):
    pass


def save_model(doc, path):
    doc = dict(doc)
    doc["format"] = FORMAT
    doc["provenance"] = {
        "tcomp_version": __version__,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "sha256": document_hash(doc),
    }
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=2)
        fh.write("\n")
    return doc


def read_document(path):
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except FileNotFoundError:
        raise ModelFormatError("%s: file is missing" % path)
    except IsADirectoryError:
        raise ModelFormatError("%s: is a folder, expected a model document (tcomp-model/1 JSON)" % path)
    except UnicodeDecodeError:
        raise ModelFormatError("%s: not a text file (a binary file? expected a model document, tcomp-model/1 JSON)" % path)
    except OSError as exc:
        raise ModelFormatError("%s: cannot be read (%s)" % (path, exc.strerror or exc))
    except json.JSONDecodeError as exc:
        raise ModelFormatError("%s line %d column %d: invalid JSON (%s)" % (path, exc.lineno, exc.colno, exc.msg))
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelFormatError("%s: not a tcomp model document (key 'format' must be %r)" % (path, FORMAT))
    if not isinstance(doc.get("kind"), str) or doc["kind"] not in KINDS:
        raise ModelFormatError("%s: unknown model kind %r (known: %s)" % (path, doc.get("kind"), ", ".join(KINDS)))
    problem = document_problem(doc)
    if problem:
        raise ModelFormatError("%s: %s" % (path, problem))
    return doc


# Blocks that define what a model predicts (statistics and training may hold NaN, e.g. an undefined p-value).
_DEFINING = ("sensors", "reference_C", "envelope", "geometric", "thermal")
_COEFFICIENTS = {"poly_slope": "coefficients_um_per_mm_per_K", "linear_direct": "coefficients_um_per_K"}


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


def document_problem(doc):
    """What makes ``doc`` say something other than what predict and export would use, or None.

    Checked for every kind before either reads it: a sensor listed twice, a coefficient of no listed sensor
    (it would be dropped without a word), a geometric degree its coefficients do not have, NaN/Infinity.
    """
    for key in _DEFINING:
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


def model_class(kind):
    module, _, name = KINDS[kind].partition(":")
    return getattr(importlib.import_module(module), name)


def load_model(path_or_doc):
    """Model object from a document path (or an already read document); errors name the path."""
    if isinstance(path_or_doc, str):
        path, doc = path_or_doc, read_document(path_or_doc)
    else:
        path, doc = None, path_or_doc
        problem = document_problem(doc) if isinstance(doc, dict) else None
        if problem:
            raise ModelFormatError(problem)
    try:
        return model_class(doc["kind"]).from_document(doc)
    except (ModelFormatError, ValueError) as exc:
        # from_document names the field; the file name is only known here.
        msg = str(exc)
        if path and not msg.startswith(path):
            msg = "%s: %s" % (path, msg)
        raise ModelFormatError(msg) from exc
