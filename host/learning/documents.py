"""The model document (docs/model-format.md): save, load by kind, predict.

Each kind's class lives with the code that fits it; this module only maps
``kind`` to that class so ``tcomp predict`` and ``tcomp export`` work on any model.
Every class has ``from_document(doc)``, ``to_document()`` and ``predict(run)``
(one predicted error in µm per row of ``run.errors``, in file order).
"""

from __future__ import annotations

from typing import Any
import importlib
import json
import time

from host import __version__
from models_export.document import DOCUMENT_KINDS, FORMAT, document_hash, document_problem

# the class of each document kind (models_export/document.py DOCUMENT_KINDS names the kinds;
# tests/learning/empirical/test_emp_contract.py checks the two agree)
KIND_CLASSES = {
    "poly_slope": "host.learning.empirical.kinds:PolySlopeModel",
    "linear_direct": "host.learning.empirical.kinds:LinearDirectModel",
    "screw": "host.learning.screw.screwmodel:ScrewModel",
    "ann": "host.learning.empirical.kinds:NetworkModel",
    "ppr": "host.learning.empirical.kinds:PPRModel",
    "dynamic": "host.learning.empirical.dynamic:DynamicModel",
    "mr_poly": "host.learning.empirical.mrpoly:MRPolyModel",
}


class ModelFormatError(ValueError):
    pass


def save_model(doc: dict[str, Any], path: str) -> dict[str, Any]:
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


def read_document(path: str) -> dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except FileNotFoundError:
        raise ModelFormatError("%s: file is missing" % path)
    except IsADirectoryError:
        raise ModelFormatError("%s: is a folder, expected a model document (%s JSON)" % (path, FORMAT))
    except UnicodeDecodeError:
        raise ModelFormatError("%s: not a text file (a binary file? expected a model document, %s JSON)" % (path, FORMAT))
    except OSError as exc:
        raise ModelFormatError("%s: cannot be read (%s)" % (path, exc.strerror or exc))
    except json.JSONDecodeError as exc:
        raise ModelFormatError("%s line %d column %d: invalid JSON (%s)" % (path, exc.lineno, exc.colno, exc.msg))
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelFormatError("%s: not a tcomp model document (key 'format' must be %r)" % (path, FORMAT))
    if not isinstance(doc.get("kind"), str) or doc["kind"] not in DOCUMENT_KINDS:
        raise ModelFormatError("%s: unknown model kind %r (known: %s)" % (path, doc.get("kind"), ", ".join(DOCUMENT_KINDS)))
    problem = document_problem(doc)
    if problem:
        raise ModelFormatError("%s: %s" % (path, problem))
    return doc


def model_class(kind: str) -> type:
    module, _, name = KIND_CLASSES[kind].partition(":")
    return getattr(importlib.import_module(module), name)


def load_model(path_or_doc: str | dict[str, Any]) -> Any:
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
