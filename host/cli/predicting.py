"""Load a model document and predict a run with it: the one path `tcomp predict`, `tcomp check` and
`tcomp report` take (the same provenance check, the same errors), so a model scores the same in each."""
from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy and the run format are imported where they are used
    import numpy as np

    from host.data.runs import Run


def load_checked_model(path: str, allow_edited: bool = False, verb: str = "tcomp") -> tuple[Any, str]:
    """(model, provenance word) of the document at ``path``; UserError when it is not a model or was edited
    after it was saved (unless ``allow_edited``, which warns on stderr)."""
    from host.errors import UserError
    from host.learning.documents import ModelFormatError, load_model, read_document
    from models_export.document import edited_reason, provenance

    try:
        doc = read_document(path)
        try:
            model = load_model(doc)
        except ModelFormatError as exc:
            raise ModelFormatError("%s: %s" % (path, exc))
    except ModelFormatError as exc:
        raise UserError(str(exc))
    actual, declared = provenance(doc)
    edited = declared is not None and declared != actual
    if edited and not allow_edited:
        # the check tcomp export makes, after the fields' own checks (which name the field), with its words
        raise UserError("%s: %s" % (path, edited_reason(declared, actual)))
    if edited:
        print("%s: warning: %s was edited after it was saved (provenance.sha256 does not match); "
              "predicting with it as asked (--allow-edited)" % (verb, path), file=sys.stderr)
    return model, "edited" if edited else "verified" if declared is not None else "none"


def load_run_or_fail(path: str) -> Run:
    from host.data.runs import RunFormatError, load_run
    from host.errors import UserError

    try:
        return load_run(path)
    except RunFormatError as exc:
        raise UserError(str(exc))


def predict_rows(model: Any, model_path: str, run_: Run, run_path: str, history: Run | None = None,
                 history_path: str | None = None, record: Run | None = None, record_path: str | None = None) -> np.ndarray:
    """The model's prediction at every errors.csv row of ``run_`` (NaN on rows of other channels); with ``history``
    (a run logged before ``run_``, dynamic models only) the model's states run through it first; with ``record``
    (the same, its spindle/feed logs only) the lag states the controller supplies start from it."""
    import numpy as np

    from host.errors import UserError

    for flag, given, path in (("--history", history, history_path), ("--controller-history", record, record_path)):
        if given is not None and getattr(model, "kind", None) != "dynamic":
            raise UserError("%s %s: only a dynamic model carries a state from one run into the next; %s is a %s model"
                            % (flag, path, model_path, getattr(model, "kind", "static")))
    from host.learning.empirical.observer import reads_controller

    if record is not None and not reads_controller(model):
        raise UserError("--controller-history %s: %s has no lag state the controller supplies (fitted without "
                        "spindle_states=controller), so the record would not be read" % (record_path, model_path))
    kw = {k: v for k, v in (("history", history), ("controller_history", record)) if v is not None}
    try:
        pred = np.asarray(model.predict(run_, **kw), dtype=float)
    except ValueError as exc:  # the run lacks what the model needs (a sensor, motion, a channel), or the history does not precede it
        raise UserError("%s cannot be predicted with %s%s: %s" % (run_path, model_path,
                                                                  " after %s" % history_path if history is not None else "", exc))
    if pred.shape != (len(run_.errors),):
        raise UserError("model returned %s predictions for %d rows of %s" % (pred.shape, len(run_.errors), run_path))
    return pred
