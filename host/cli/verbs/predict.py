"""tcomp predict MODEL.json RUN [--history EARLIER_RUN] [--controller-history EARLIER_RUN] --out PRED.csv"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model document (tcomp-model/1 JSON)")
    p.add_argument("run", help="run folder")
    p.add_argument("--history", metavar="EARLIER_RUN",
                   help="dynamic models: a run folder logged before RUN on the same clock (it ends at or before RUN's first "
                        "temperature sample); the model's states run through it first, as on a board that was not restarted. "
                        "Without it the board starts at RUN's first sample (with the model's observer, if it has one)")
    p.add_argument("--controller-history", dest="controller_history", metavar="EARLIER_RUN",
                   help="dynamic models fitted with spindle_states=controller: a run folder logged before RUN on the same "
                        "clock whose spindle.csv / motion.csv are the controller's record; the lag states the controller "
                        "supplies start from it (the board still starts at RUN's first sample, its temperatures unread). "
                        "Without it they start at the steady state of RUN's first speed")
    p.add_argument("--out", required=True,
                   help="CSV: time_s,position_mm[,direction][,channel],predicted_um,measured_um,residual_um (residual = "
                        "measured - predicted), one line per errors.csv row the model predicts (rows of other channels "
                        "are left out)")
    p.add_argument("--json", help="also write summary statistics (RMSE, max and min residual against the measured errors, "
                                  "R², and the same per channel) as JSON")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="predict with a model whose recorded provenance.sha256 does not match its content (edited "
                        "after it was saved), as tcomp export --allow-edited does; the JSON records it")


def run(args: argparse.Namespace) -> int:
    from host.outputs import Outputs

    with Outputs([args.model, args.run] + [p for p in (args.history, args.controller_history) if p]) as out:
        out.file(args.out, "--out")
        if args.json:
            out.file(args.json, "--json")
        _predict(args, out)
        out.commit()
    return 0


def _predict(args, out):
    import json

    import numpy as np

    from host.cli.predicting import load_checked_model, load_run_or_fail, predict_rows
    from host.learning.residuals import NO_CHANNEL, channel_rows, figures

    model, provenance = load_checked_model(args.model, args.allow_edited, "tcomp predict")
    run_ = load_run_or_fail(args.run)
    history = load_run_or_fail(args.history) if args.history else None
    record = load_run_or_fail(args.controller_history) if args.controller_history else None
    e = run_.errors
    pred = predict_rows(model, args.model, run_, args.run, history, args.history, record, args.controller_history)
    rows_of = channel_rows(e, pred)
    used = np.sort(np.concatenate(list(rows_of.values()))) if rows_of else np.array([], dtype=int)
    header = (["time_s", "position_mm"] + (["direction"] if e.direction is not None else [])
              + (["channel"] if e.channel is not None else []) + ["predicted_um", "measured_um", "residual_um"])
    with out.open(args.out) as fh:
        fh.write(",".join(header) + "\n")
        for i in used:
            cells = ["%.3f" % e.time_s[i], "%.4f" % e.position_mm[i]]
            if e.direction is not None:
                cells.append("%+d" % e.direction[i])
            if e.channel is not None:
                cells.append(str(e.channel[i]))
            cells += ["%.4f" % pred[i], "%.4f" % e.error_um[i], "%.4f" % (e.error_um[i] - pred[i])]
            fh.write(",".join(cells) + "\n")
    # residual = measured - predicted; Li 2021's MAXR/MINR, Fan & Guo's maximum residual
    overall = figures(e.error_um[used], pred[used])
    channels = {c: figures(e.error_um[rows], pred[rows]) for c, rows in rows_of.items()}
    print("%s on %s: %d rows, RMSE %.3f um, max residual %.3f um, min residual %.3f um, R2 %.4f (measured - predicted)"
          % (args.model, args.run, used.size, overall["rmse_um"], overall["max_residual_um"], overall["min_residual_um"], overall["r2"]))
    if len(channels) > 1 or (e.channel is not None and NO_CHANNEL not in channels):
        for c, f in channels.items():
            print("  channel %s: %d rows, RMSE %.3f um, max %.3f um, min %.3f um, R2 %.4f"
                  % (c, f["rows"], f["rmse_um"], f["max_residual_um"], f["min_residual_um"], f["r2"]))
    if len(used) < len(e):
        print("  %d rows of other channels left out (the model predicts %s)" % (len(e) - len(used), getattr(model, "channel", None)))
    split = _training_split(model, args.run, e, used, pred)
    if split:
        print("  " + split["note"])
    compare_view = _compare_view(model, run_)
    if compare_view:
        print("  " + compare_view["note"])
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"model": args.model, "run": args.run, **({"history": args.history} if history is not None else {}),
                       **({"controller_history": args.controller_history} if record is not None else {}),
                       "rows": int(len(e)), "predicted_rows": int(used.size),
                       "rmse_um": overall["rmse_um"], "provenance": provenance,
                       "max_residual_um": overall["max_residual_um"], "min_residual_um": overall["min_residual_um"],
                       "max_abs_residual_um": overall["max_abs_residual_um"], "r2": overall["r2"],
                       "channels": channels, "training_split": split, "compare_view": compare_view}, fh, indent=2)


def _training_split(model, run_path, e, used, pred):
    """Figures of the rows the model was fitted on and of the held-out rest, when the run is one of its training
    runs and the fit had a time window (tcomp fit --t-min/--t-max): an RMSE over both mixes fit and prediction,
    and `tcomp compare --split-h` scores only the held-out part. None otherwise."""
    import os

    from host.learning.empirical.targets import in_window
    from host.learning.residuals import figures

    training = getattr(model, "training", None) or getattr(model, "training_", None) or {}
    window = training.get("window_s") or training.get("fit_window_s")
    runs = [os.path.realpath(r) for r in training.get("runs") or [] if isinstance(r, str)]
    if not window or os.path.realpath(run_path) not in runs:
        return None
    inside = in_window(e.time_s[used], tuple(window))
    fitted, held = used[inside], used[~inside]
    out = {"window_s": list(window), "fitted": figures(e.error_um[fitted], pred[fitted]),
           "held_out": figures(e.error_um[held], pred[held])}
    lo = "the start" if window[0] is None else "%g s" % window[0]
    hi = "the end" if window[1] is None else "%g s" % window[1]
    out["note"] = ("%s is a training run, fitted on %s..%s: the %d rows fitted on RMSE %.3f um, the %d held-out rows "
                   "RMSE %.3f um (tcomp compare --split-h scores the held-out part)"
                   % (run_path, lo, hi, fitted.size, out["fitted"]["rmse_um"], held.size, out["held_out"]["rmse_um"]))
    return out


def _compare_view(model, run_):
    """How `tcomp compare` scores this model on this run, and why its figure differs from predict's (None for
    models compare does not score: screw). The two verbs differ in two declared ways, never silently:

    - what is scored: compare scores a slope model's thermal part only, on the rows after the run's cold sweep,
      against the measured error minus that cold sweep (host/learning/empirical/scoring.py); predict scores the
      whole error (geometric + thermal) of every row the model predicts;
    - the rise reference: compare refits with ``--reference run_start`` by default (each run's rises from its
      own first sample); `tcomp fit` saves ``fixed`` (the training runs' mean start, what the board uses), which
      predict applies. ``tcomp compare --reference fixed`` scores the model as saved: its RMSE is ``thermal``'s."""
    from host.learning.empirical import EmpiricalDataError
    from host.learning.empirical.scoring import score_model

    if getattr(model, "target", None) not in ("slope", "direct") or not hasattr(model, "thermal_at"):
        return None
    reference = getattr(model, "reference", "fixed")
    try:
        s = score_model(model, run_)
    except EmpiricalDataError as exc:
        return {"reference": reference, "thermal": None, "note": "tcomp compare could not score this run: %s" % exc}
    what = ("the thermal part on the %d rows after the cold sweep (measured minus the run's own cold sweep); predict "
            "scores the whole error of every row" % s["n"] if model.target == "slope"
            else "the %d rows of the model's channel, as predict does" % s["n"])
    note = ("tcomp compare --reference %s scores this model RMSE %.3f um on %s.%s" % (reference, s["rmse_um"], what,
                        " compare's default --reference run_start takes each run's rises from its own first sample, not "
                        "this model's saved reference_C: its figure differs by that too" if reference == "fixed" else ""))
    return {"reference": reference, "thermal": {k: s[k] for k in ("n", "rmse_um", "max_residual_um", "min_residual_um")},
            "note": note}
