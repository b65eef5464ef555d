"""tcomp check --model MODEL --run CHECK_RUN [--board-log LOG.csv --board-t0-ms MS] --limit-um L [--json OUT]
            [--t-min S] [--t-max S]

A production check (docs/check.md): the errors measured on a check run, uncompensated (as measured) against
compensated (measured − the board's offsets from its log, or − the host model's prediction when there is no
log), RMSE and max per channel, pass when every compensated |residual| of the model's channel(s) is within
the limit. Exit 0 pass, 1 fail.
"""
from __future__ import annotations

import argparse


DEFAULT_MAX_DT_S = 60.0  # a laser sweep stamps its rows with one time; the board logs every cycle (100 ms)
DEFAULT_POSITION_TOL_MM = 0.05  # the board's position (µm, from the controller) against the laser's target


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, help="the model document the board's table was exported from")
    p.add_argument("--run", required=True, help="the check run folder (measured errors and temperatures)")
    p.add_argument("--board-log", dest="board_log", metavar="LOG.csv",
                   help="the board's offsets during the check: tcomp monitor --csv output (needs --board-t0-ms), a CSV "
                        "time_s,position_mm,offset_um on the run's clock, or tcomp hil --json output (.json); without it "
                        "the host model's predictions are used")
    p.add_argument("--board-t0-ms", dest="board_t0_ms", type=int, metavar="MS",
                   help="the board's t_ms at the run's time 0 (a tcomp monitor log only)")
    p.add_argument("--max-dt-s", dest="max_dt_s", type=float, default=DEFAULT_MAX_DT_S,
                   help="a board offset counts for a measured row when it is at most this far in time (default %g s)" % DEFAULT_MAX_DT_S)
    p.add_argument("--position-tol-mm", dest="position_tol_mm", type=float, default=DEFAULT_POSITION_TOL_MM,
                   help="... and its position within this of the row's (default %g mm)" % DEFAULT_POSITION_TOL_MM)
    p.add_argument("--limit-um", dest="limit_um", type=float, required=True,
                   help="the stated limit: pass when every compensated |measured - offset| is at most this (µm)")
    p.add_argument("--t-min", dest="t_min", type=float, metavar="S",
                   help="check only the errors.csv rows with time_s >= S (as tcomp fit --t-min): e.g. the sweeps "
                        "measured after the board's log began; the rows left out are counted in the output")
    p.add_argument("--t-max", dest="t_max", type=float, metavar="S",
                   help="check only the errors.csv rows with time_s < S")
    p.add_argument("--json", help="write the figures and the verdict as JSON")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="check with a model whose provenance.sha256 does not match its content, as tcomp predict does")


def run(args: argparse.Namespace) -> int:
    import math

    from host.errors import UserError
    from host.outputs import Outputs

    if not (math.isfinite(args.limit_um) and args.limit_um > 0):
        raise UserError("--limit-um %s: must be a positive number of µm" % args.limit_um)
    for flag, v in (("--max-dt-s", args.max_dt_s), ("--position-tol-mm", args.position_tol_mm)):
        if not (math.isfinite(v) and v >= 0):
            raise UserError("%s %s: must be a finite number >= 0" % (flag, v))
    for flag, v in (("--t-min", args.t_min), ("--t-max", args.t_max)):
        if v is not None and not math.isfinite(v):
            raise UserError("%s %s: must be a finite number of seconds (run time)" % (flag, v))
    if args.t_min is not None and args.t_max is not None and not args.t_min < args.t_max:
        raise UserError("--t-min %g, --t-max %g: the window is empty (--t-min must be < --t-max)" % (args.t_min, args.t_max))
    if args.board_t0_ms is not None and not args.board_log:
        raise UserError("--board-t0-ms is the board log's time 0: give --board-log too")
    with Outputs([args.model, args.run, args.board_log]) as out:
        if args.json:
            out.file(args.json, "--json")
        passed = _check(args, out)
        out.commit()
    return 0 if passed else 1


def _check(args, out):
    import json

    import numpy as np

    from host.cli.predicting import load_checked_model, load_run_or_fail, predict_rows
    from host.data.boardlog import BoardLogError, offsets_at, read_board_log
    from host.errors import UserError
    from host.learning.residuals import NO_CHANNEL, channel_rows, figures

    model, provenance = load_checked_model(args.model, args.allow_edited, "tcomp check")
    run_ = load_run_or_fail(args.run)
    e = run_.errors
    wanted = getattr(model, "channel", None)
    if wanted is not None and e.channel is not None and wanted not in e.channels():
        raise UserError("%s: errors.csv has no channel %r, the channel of %s (its channels: %s)"
                        % (args.run, wanted, args.model, ", ".join(e.channels())))
    predicted = predict_rows(model, args.model, run_, args.run)
    rows_of = channel_rows(e, predicted)
    if not rows_of:
        raise UserError("%s: no errors.csv row the model %s predicts" % (args.run, args.model))
    window = np.ones(len(e), dtype=bool)  # --t-min/--t-max: [S, S') of the run's time, as tcomp fit's window
    if args.t_min is not None:
        window &= e.time_s >= args.t_min
    if args.t_max is not None:
        window &= e.time_s < args.t_max
    outside = int(sum(int((~window[r]).sum()) for r in rows_of.values()))
    rows_of = {c: r[window[r]] for c, r in rows_of.items() if window[r].any()}
    if not rows_of:
        raise UserError("%s: no errors.csv row of the model's channel in the window %s..%s s (time_s from %g to %g)"
                        % (args.run, "-" if args.t_min is None else "%g" % args.t_min,
                           "-" if args.t_max is None else "%g" % args.t_max, e.time_s.min(), e.time_s.max()))
    used = np.sort(np.concatenate(list(rows_of.values())))
    if args.board_log:
        try:
            log = read_board_log(args.board_log, args.board_t0_ms)
            offset = np.full(len(e), np.nan)
            offset[used] = offsets_at(log, e.time_s[used], e.position_mm[used], args.max_dt_s, args.position_tol_mm,
                                      "%s errors.csv" % args.run)
        except BoardLogError as exc:
            raise UserError(str(exc))
        source = "board log %s (%s layout, %d offsets)" % (args.board_log, log.layout, len(log))
    else:
        offset = predicted
        source = "host model %s (no board log)" % args.model
    channels = {}
    for name, rows in rows_of.items():
        before = figures(e.error_um[rows], np.zeros(rows.size))
        before.pop("r2")  # of "predicting zero": not a figure of anything
        after = figures(e.error_um[rows], offset[rows])
        channels[name] = {"rows": int(rows.size), "uncompensated": before, "compensated": after,
                          # the board's offset against the host model's prediction: quantisation, sensor noise, or a
                          # table that is not this model's (rmse_um etc. of board offset - host prediction)
                          "board_vs_model": figures(offset[rows], predicted[rows]) if args.board_log else None,
                          "reduction_percent": 100.0 * (1.0 - after["rmse_um"] / before["rmse_um"]) if before["rmse_um"] > 0 else None,
                          "pass": bool(after["max_abs_residual_um"] <= args.limit_um)}
    for c in channels.values():
        if c["board_vs_model"]:
            c["board_vs_model"].pop("r2")
    not_checked = [c for c in e.channels() if c not in channels] if e.channel is not None else []
    passed = all(c["pass"] for c in channels.values())
    print("tcomp check: %s against %s; limit %g µm on max |measured - offset|" % (args.run, source, args.limit_um))
    if args.t_min is not None or args.t_max is not None:
        print("  window: rows with %s; %d rows of the model's channel outside it not checked" % (
            " and ".join(t for t in ("time_s >= %g" % args.t_min if args.t_min is not None else "",
                                    "time_s < %g" % args.t_max if args.t_max is not None else "") if t), outside))
    for name, c in channels.items():
        b, a = c["uncompensated"], c["compensated"]
        print("  %s: %d rows; uncompensated RMSE %.3f µm, max |e| %.3f µm; compensated RMSE %.3f µm, max |r| %.3f µm: %s"
              % (name if name != NO_CHANNEL else "errors", c["rows"], b["rmse_um"], b["max_abs_residual_um"], a["rmse_um"],
                 a["max_abs_residual_um"], "pass" if c["pass"] else "FAIL"))
        if c["board_vs_model"]:
            print("    board offset - host model: RMSE %.3f µm, max |d| %.3f µm" % (
                c["board_vs_model"]["rmse_um"], c["board_vs_model"]["max_abs_residual_um"]))
    if not_checked:
        print("  not checked (the model compensates %s only): %s" % (wanted, ", ".join(not_checked)))
    print("tcomp check: %s" % ("PASS" if passed else "FAIL"))
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"model": args.model, "run": args.run, "provenance": provenance,
                       "compensation": "board_log" if args.board_log else "host_model",
                       "board_log": args.board_log, "board_t0_ms": args.board_t0_ms,
                       "t_min_s": args.t_min, "t_max_s": args.t_max, "rows_outside_window": outside,
                       "max_dt_s": args.max_dt_s, "position_tol_mm": args.position_tol_mm,
                       "limit_um": args.limit_um, "criterion": "max_abs_compensated_residual_um <= limit_um per channel",
                       "channels": channels, "not_checked": not_checked, "pass": passed}, fh, indent=2)
            fh.write("\n")
    return passed
