"""tcomp predict MODEL.json RUN --out PRED.csv"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model document (tcomp-model/1 JSON)")
    p.add_argument("run", help="run folder")
    p.add_argument("--out", required=True, help="CSV: time_s,position_mm[,direction][,channel],predicted_um")
    p.add_argument("--json", help="also write summary statistics (RMSE, max and min residual against the measured errors) as JSON")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="predict with a model whose recorded provenance.sha256 does not match its content (edited "
                        "after it was saved), as tcomp export --allow-edited does; the JSON records it")


def run(args: argparse.Namespace) -> int:
    from host.outputs import Outputs

    with Outputs([args.model, args.run]) as out:
        out.file(args.out, "--out")
        if args.json:
            out.file(args.json, "--json")
        _predict(args, out)
        out.commit()
    return 0


def _predict(args, out):
    import json

    import numpy as np

    import sys

    from host.errors import UserError
    from host.learning.documents import ModelFormatError, load_model, read_document
    from host.data.runs import RunFormatError, load_run
    from models_export.document import edited_reason, provenance

    try:
        doc = read_document(args.model)
        try:
            model = load_model(doc)
        except ModelFormatError as exc:
            raise ModelFormatError("%s: %s" % (args.model, exc))
        actual, declared = provenance(doc)
        edited = declared is not None and declared != actual
        if edited and not args.allow_edited:
            # the check tcomp export makes, after the fields' own checks (which name the field), with its words
            raise UserError("%s: %s" % (args.model, edited_reason(declared, actual)))
        run_ = load_run(args.run)
    except (ModelFormatError, RunFormatError) as exc:
        raise UserError(str(exc))
    if edited:
        print("tcomp predict: warning: %s was edited after it was saved (provenance.sha256 does not match); "
              "predicting with it as asked (--allow-edited)" % args.model, file=sys.stderr)
    e = run_.errors
    rows = np.arange(len(e))
    if getattr(model, "channel", None) and e.channel is not None:
        rows = np.flatnonzero(e.channel == model.channel)
    try:
        pred = np.asarray(model.predict(run_), dtype=float)
    except ValueError as exc:  # the run lacks what the model needs (a sensor, motion, a channel)
        raise UserError("%s cannot be predicted with %s: %s" % (args.run, args.model, exc))
    if pred.shape != (len(e),):
        raise UserError("model returned %s predictions for %d rows of %s" % (pred.shape, len(e), args.run))
    header = ["time_s", "position_mm"] + (["direction"] if e.direction is not None else []) + (["channel"] if e.channel is not None else []) + ["predicted_um"]
    with out.open(args.out) as fh:
        fh.write(",".join(header) + "\n")
        for i in range(len(e)):
            cells = ["%.3f" % e.time_s[i], "%.4f" % e.position_mm[i]]
            if e.direction is not None:
                cells.append("%+d" % e.direction[i])
            if e.channel is not None:
                cells.append(str(e.channel[i]))
            cells.append("nan" if np.isnan(pred[i]) else "%.4f" % pred[i])
            fh.write(",".join(cells) + "\n")
    resid = e.error_um[rows] - pred[rows]
    resid = resid[np.isfinite(resid)]
    rmse = float(np.sqrt(np.mean(resid ** 2))) if resid.size else float("nan")
    # residual = measured - predicted; Li 2021's MAXR/MINR, Fan & Guo's maximum residual
    rmax = float(resid.max()) if resid.size else float("nan")
    rmin = float(resid.min()) if resid.size else float("nan")
    print("%s on %s: %d rows, RMSE %.3f um, max residual %.3f um, min residual %.3f um (measured - predicted)"
          % (args.model, args.run, len(e), rmse, rmax, rmin))
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"model": args.model, "run": args.run, "rows": int(len(e)), "rmse_um": rmse,
                       "provenance": "edited" if edited else "verified" if declared is not None else "none",
                       "max_residual_um": rmax, "min_residual_um": rmin}, fh, indent=2)
