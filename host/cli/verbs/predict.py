"""tcomp predict MODEL.json RUN [--history EARLIER_RUN] --out PRED.csv"""


def add_arguments(p):
    p.add_argument("model", help="model document (tcomp-model/1 JSON)")
    p.add_argument("run", help="run folder")
    p.add_argument("--history", metavar="EARLIER_RUN",
                   help="dynamic models: a run folder logged before RUN on the same clock (it ends at or before RUN's first "
                        "temperature sample); the model's states run through it first, as on a board that was not restarted. "
                        "Without it the board starts at RUN's first sample (with the model's observer, if it has one)")
    p.add_argument("--out", required=True, help="CSV: time_s,position_mm[,direction][,channel],predicted_um")
    p.add_argument("--json", help="also write summary statistics (RMSE, max and min residual against the measured errors) as JSON")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="predict with a model whose recorded provenance.sha256 does not match its content (edited "
                        "after it was saved), as tcomp export --allow-edited does; the JSON records it")


def run(args):
    from host.outputs import Outputs

    with Outputs([args.model, args.run] + ([args.history] if args.history else [])) as out:
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
        history = load_run(args.history) if args.history else None
    except (ModelFormatError, RunFormatError) as exc:
        raise UserError(str(exc))
    if edited:
        print("tcomp predict: warning: %s was edited after it was saved (provenance.sha256 does not match); "
              "predicting with it as asked (--allow-edited)" % args.model, file=sys.stderr)
    e = run_.errors
    rows = np.arange(len(e))
    if getattr(model, "channel", None) and e.channel is not None:
        rows = np.flatnonzero(e.channel == model.channel)
    if history is not None and getattr(model, "kind", None) != "dynamic":
        raise UserError("--history %s: only a dynamic model carries a state from one run into the next; %s is a %s model"
                        % (args.history, args.model, getattr(model, "kind", "static")))
    try:
        pred = np.asarray(model.predict(run_) if history is None else model.predict(run_, history=history), dtype=float)
    except ValueError as exc:  # the run lacks what the model needs (a sensor, motion, a channel), or the history does not precede it
        raise UserError("%s cannot be predicted with %s%s: %s" % (args.run, args.model, " after %s" % args.history if history is not None else "", exc))
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
            json.dump({"model": args.model, "run": args.run, **({"history": args.history} if history is not None else {}),
                       "rows": int(len(e)), "rmse_um": rmse,
                       "provenance": "edited" if edited else "verified" if declared is not None else "none",
                       "max_residual_um": rmax, "min_residual_um": rmin}, fh, indent=2)
