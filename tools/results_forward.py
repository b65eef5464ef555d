"""Held-out figures of issue 21 on FL_THERMAL: the dynamic model fitted with `tcomp fit` defaults, predicting the future.

    .venv/bin/python tools/results_forward.py [--run data/fl_thermal] [--split-h 32.129 --split-h 24.129]
        [--channels ch1,...] [--option KEY=VALUE ...] [--variants continuous,static] [--loco] [--no-splits] [--no-static]
        [--json OUT]

For each split and channel, every model is fitted on t < split with the defaults
of `tcomp fit` (no setting tuned to the split; ``--option`` passes dynamic
settings, to measure a variant), and scored on t >= split. Printed, as a
Markdown table, the held-out RMSE and its ratio to MLR-16 (plain MLR on all 16
temperatures) for:

(a) the dynamic model switched on at the split: its ``predict`` on the run cut
    at the split (host/data/runs.py slice_run), a board with no history. This
    figure changes when the model's state handling (issue 21's observer) changes:
    re-run the script after merging it;
(b) the same model with its filters running since 0 h (``predict`` on the whole
    run, scored after the split);
(c) the best static model with <= 5 sensors among cv-subset and stepwise (picked
    on the held-out part, as in the issue's table: an upper bound of what a
    user's choice gets), switched on at the split (a fixed temperature
    reference, so (a) and (b) are the same for it);

With ``--option average_structures=K`` (structure averaging, host/learning/empirical/averaging.py) two more rows,
(a1) and (b1): the single best structure the average replaces, from the same search (so the fit without averaging,
measured in the same run), and per channel the members and weights or why the single structure stays.
docs/results.md ("Issue 21: structure averaging") was made with ``--option average_structures=3``.

With ``--option observer_sensors=N`` (sensors only the observer reads, docs/empirical.md "Observer-only sensors") one
more row where the option chose any, (a0): the same model with the observer of its terms' signals only, refitted on
the same samples (the option acts after the selection, so this is the model without it, measured in the same run).
docs/results.md ("Observer-only sensors") was made with ``--split-h 32.129166666666666 --split-h 24.129166666666666
--split-h 28.0 --split-h 36.5 --option observer_sensors=5``.

``--variants continuous,static`` also fits the dynamic model with ``forward_state=continuous`` (the selection scored
with filters running since the run start) and with ``taus_s=[0]`` (the static search the default's static fallback
compares with), and prints their rows and every model's forward-chaining pooled score beside the baseline MLR on all
sensors (``statistics.forward_chaining.baseline_mlr_all``). docs/results.md ("Issue 21, second half") was made with
``--split-h 32.129166666666666 --split-h 24.129166666666666 --split-h 28.0 --variants continuous,static``;

the settle-bounded choice (docs/empirical.md "Settle bound") was measured with the same splits and
``--option settle_max_s=1800`` against the same command without it (docs/results.md, "Settle bound");

the phase blocks (docs/empirical.md, ``forward_blocks=phases``) with ``--split-h H --option 'forward_blocks="phases"'
--no-static``, one split per run, against the same without the option (docs/results.md, "forward-chaining blocks per
spindle phase"; ``--no-static`` skips row (c), which such a comparison does not need);

and, with ``--loco``, the leave-one-cycle-out ratios (every choice made inside
each fold) of cv-subset and the dynamic model. Every number printed comes from
this run of the script.
"""
import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from host.data.runs import load_run, slice_run  # noqa: E402
from host.learning.empirical.compare import leave_one_cycle_out  # noqa: E402
from host.learning.empirical.fitting import fit_model  # noqa: E402
from host.learning.empirical.forward import block_residuals  # noqa: E402
from host.learning.empirical.observer import reads_controller  # noqa: E402
from host.options import parse_options  # noqa: E402

STATIC = ("cv-subset", "stepwise")


def _rmse(pair):
    m, p = pair
    return float(np.sqrt(np.mean((m - p) ** 2)))


# the dynamic variants measured beside the defaults: how the selection scores a block, and the static structure (τ = 0 only)
VARIANTS = {"switched_on": {"forward_state": "switched_on"}, "continuous": {"forward_state": "continuous"}, "static": {"taus_s": [0]}}


def own_observer(dyn, runs):
    """``dyn`` (fitted with observer_sensors) with the observer refitted on its terms' signals only, on the same samples."""
    from host.learning.empirical.dynamic import DynamicModel
    from host.learning.empirical.observer import fit_observer

    own = DynamicModel(dyn.terms, dyn.term_coefficients, dyn.intercept, dyn.target, dyn.channel, dyn.geometric_coef, "dynamic",
                       dyn.axis, {s: dyn.reference_C[s] for s in dyn.term_sensors}, training=dyn.training, dt_s=dyn.dt_s)
    own.observer = fit_observer(own, runs, spans=[(a.time_s.min(), a.time_s.max()) for a in dyn.arrays_], scale=dyn.observer.scale)
    return own


def held_out(run, split_s, channel, dyn_options, variants=(), static=True):
    """{figure: RMSE µm} of one channel on t >= split_s, and the fitted models' descriptions."""
    block = {"block": 1, "run": 0, "t_start_s": split_s, "t_end_s": float(run.errors.time_s.max())}
    cut = slice_run(run, split_s)
    out, info = {}, {}
    mlr = fit_model([run], "mlr", "direct", channel, window=(None, split_s), reference="fixed")
    out["mlr16"] = _rmse(block_residuals(mlr, run, block))
    for name in ("",) + tuple(variants):
        key = "dynamic" + ("_" + name if name else "")
        t0 = time.perf_counter()
        dyn = fit_model([run], "dynamic", "direct", channel, window=(None, split_s), **{**dyn_options, **VARIANTS.get(name, {})})
        info[key + "_fit_s"] = time.perf_counter() - t0
        # the controller's record before the split (its spindle/feed log): used only by states the controller supplies
        out[key + "_switched_on"] = _rmse(block_residuals(dyn, cut, block, [slice_run(run, float(run.temperatures.time_s[0]), split_s)]))
        if reads_controller(dyn):
            # the same board without the controller's record (no --controller-history; on the board: no `Y` within
            # 10 s): the supplied states start at the observer's estimate (the gains the fit writes for them since
            # stop 32; before, at the steady state of the first speed: docs/results.md keeps both measurements)
            out[key + "_switched_on_no_record"] = _rmse(block_residuals(dyn, cut, block))
        out[key + "_continuous"] = _rmse(block_residuals(dyn, run, block))
        st = dyn.statistics
        if "structure_average" in st:
            # the single best structure the average would replace (the model itself when averaging kept it): the same search,
            # so this row is the fit without averaging, measured in the same run
            single = getattr(dyn, "single_", dyn)
            out[key + "_single_switched_on"] = _rmse(block_residuals(single, cut, block))
            out[key + "_single_continuous"] = _rmse(block_residuals(single, run, block))
            info[key + "_single_terms"] = [[n, tau, float(c)] for (n, tau), c in zip(single.terms, single.term_coefficients)]
            sa = st["structure_average"]
            info[key + "_average"] = sa
        if st.get("observer_sensors", {}).get("chosen"):
            # the same model with the observer of its own signals only (what it is without observer_sensors: the
            # option acts after the selection), measured in the same run
            own = own_observer(dyn, [run])
            out[key + "_own_observer_switched_on"] = _rmse(block_residuals(own, cut, block))
            info[key + "_own_observer_settle_s"] = own.observer.settle_s
        if "observer_sensors" in st:
            info[key + "_observer_sensors"] = {k: v for k, v in st["observer_sensors"].items() if k != "rule"}
        info[key + "_terms"] = [[n, tau, float(c)] for (n, tau), c in zip(dyn.terms, dyn.term_coefficients)]
        info[key + "_sensors"] = list(dyn.sensors)
        info[key + "_ridge"] = st.get("ridge")
        info[key + "_forward_state"] = st.get("forward_state")
        info[key + "_settle_s"] = dyn.observer.settle_s if dyn.observer is not None else None
        if dyn.observer is not None and dyn.observer.settle_without_record_s is not None:
            info[key + "_settle_without_record_s"] = dyn.observer.settle_without_record_s
        if "record_structure_start" in st:  # controller_scoring=worse: its search from record scoring's structure
            info[key + "_record_structure_start"] = {k: v for k, v in st["record_structure_start"].items() if k != "rule"}
        if "settle_bound" in st:  # --option settle_max_s=...: what the bound refused
            info[key + "_settle_bound"] = {k: v for k, v in st["settle_bound"].items() if k not in ("rule", "observer")}
        fc = st["forward_chaining"]
        info[key + "_forward_pooled_um"] = fc.get("pooled_um")
        if "baseline_mlr_all" in fc:
            info["baseline_mlr_all_forward_pooled_um"] = fc["baseline_mlr_all"]["pooled_um"]
    best = None
    for m in STATIC if static else ():
        try:
            s = fit_model([run], m, "direct", channel, window=(None, split_s), reference="fixed")
        except Exception as exc:  # a method that fails on this split is reported, not hidden
            info["%s_error" % m] = str(exc)
            continue
        if len(s.sensors) > 5:
            continue
        r = _rmse(block_residuals(s, cut, block))
        if best is None or r < best[0]:
            best = (r, m, list(s.sensors))
    if best:
        out["static_le5"] = best[0]
        info["static_le5"] = {"method": best[1], "sensors": best[2]}
    return out, info


def _loco_folds(loco):
    """One channel's leave-one-cycle-out, fold by fold: a pooled ratio can be one fold's doing (docs/results.md, stop 34)."""
    mlr, dyn = loco["methods"]["mlr"], loco["methods"]["dynamic"]
    return [{"cycle": k + 1, "speeds_rpm": c[2], "mlr_rmse_um": fm["rmse_um"], "dynamic_rmse_um": fd["rmse_um"],
             "dynamic_terms": terms, "forward_pooled_um": (fc or {}).get("pooled_um"),
             # controller_scoring=worse's criterion; a structure without supplied states: its pooled score
             "worse_of_starts_pooled_um": (fc or {}).get("worse_of_starts_pooled_um", (fc or {}).get("pooled_um"))}
            for k, (c, fm, fd, terms, fc) in enumerate(zip(loco["cycles"], mlr["folds"], dyn["folds"], dyn["terms"],
                                                           dyn["forward_chaining"]))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default=os.path.join(ROOT, "data", "fl_thermal"))
    ap.add_argument("--split-h", type=float, action="append", help="split times in hours (default 32.129 and 24.129: cycle starts)")
    ap.add_argument("--channels", default="ch1,ch2,ch3,ch4,ch5")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="a dynamic setting (JSON value), e.g. selection=\"loo\"")
    ap.add_argument("--variants", default="", help="also fit these dynamic variants (comma list of %s) and print them" % ", ".join(VARIANTS))
    ap.add_argument("--no-splits", action="store_true", help="only the leave-one-cycle-out figures (with --loco)")
    ap.add_argument("--loco", action="store_true", help="also leave-one-cycle-out (5 channels x 6 folds: about 20 min more on the loaded 2-core machine)")
    ap.add_argument("--no-static", action="store_true", help="skip row (c), the static models (cv-subset, stepwise): "
                    "a measurement of a dynamic option does not need them, and they cost minutes per channel")
    ap.add_argument("--json", help="write every figure as JSON")
    args = ap.parse_args(argv)
    opts = parse_options(args.option)  # JSON values or words, any key: fit_model's own settings (host/options.py)
    run = load_run(args.run)
    channels = args.channels.split(",")
    splits = [] if args.no_splits else (args.split_h or [32.129166666666666, 24.129166666666666])
    variants = [v for v in args.variants.split(",") if v]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        ap.error("unknown variant(s) %s (known: %s)" % (", ".join(unknown), ", ".join(VARIANTS)))
    report = {"run": args.run, "dynamic_options": opts, "splits": {}}
    for h in splits:
        split_s = round(h * 3600 / 15) * 15.0  # on the 15 s sample grid
        rows = {}
        for ch in channels:
            rows[ch] = held_out(run, split_s, ch, opts, variants, static=not args.no_static)
            print("split %.2f h %s done" % (h, ch), file=sys.stderr, flush=True)
        report["splits"]["%.2f" % h] = rows
        print("\nSplit at %.2f h (fit on t < %.2f h, score t >= %.2f h); dynamic settings: %s\n" % (h, h, h, opts or "tcomp fit defaults"))
        print("| figure | %s |" % " | ".join(channels))
        print("|---|%s" % ("---|" * len(channels)))
        print("| MLR-16 held-out RMSE µm | %s |" % " | ".join("%.2f" % rows[c][0]["mlr16"] for c in channels))
        figures = [("dynamic_switched_on", "(a) dynamic (tcomp fit defaults), switched on at the split"),
                   ("dynamic_switched_on_no_record", "(a'') the same, switched on without the controller's record (its states at the observer's estimate)"),
                   ("dynamic_own_observer_switched_on", "(a0) the same model, its observer reading the terms' sensors only"),
                   ("dynamic_continuous", "(b) the same model, filters since 0 h"),
                   ("dynamic_single_switched_on", "(a1) the single best structure (no averaging), switched on at the split"),
                   ("dynamic_single_continuous", "(b1) the single best structure, filters since 0 h")]
        for v in variants:
            figures += [("dynamic_%s_switched_on" % v, "dynamic %s, switched on at the split" % v),
                         ("dynamic_%s_continuous" % v, "dynamic %s, filters since 0 h" % v)]
        figures.append(("static_le5", "(c) best static ≤ 5 sensors"))
        for key, label in figures:
            print("| %s, ratio to MLR-16 | %s |" % (label, " | ".join(
                "%.2f (%.2f µm)" % (rows[c][0][key] / rows[c][0]["mlr16"], rows[c][0][key]) if key in rows[c][0] else "–" for c in channels)))
        # the forward-chaining scores (training blocks only) the fit reports: what a user sees before any held-out data
        print("| forward-chaining pooled µm: baseline MLR on all sensors | %s |" % " | ".join(
            "%.2f" % rows[c][1]["baseline_mlr_all_forward_pooled_um"] if "baseline_mlr_all_forward_pooled_um" in rows[c][1] else "–"
            for c in channels))
        for key in ["dynamic"] + ["dynamic_" + v for v in variants]:
            print("| forward-chaining pooled µm: %s | %s |" % (key, " | ".join("%.2f" % rows[c][1][key + "_forward_pooled_um"] for c in channels)))
        print("\n| channel | model | terms (signal, τ s, coefficient) | ridge | fit s |")
        print("|---|---|---|---|---|")
        for c in channels:
            i = rows[c][1]
            for key in ["dynamic"] + ["dynamic_" + v for v in variants]:
                print("| %s | %s | %s | %s | %.0f |" % (c, key, ", ".join("%s %g s %.3g" % tuple(t) for t in i[key + "_terms"]),
                                                  i[key + "_ridge"], i[key + "_fit_s"]))
            for key in ["dynamic"] + ["dynamic_" + v for v in variants]:
                if key + "_observer_sensors" in i:
                    o = i[key + "_observer_sensors"]
                    print("| %s | %s observer_sensors | chosen %s: settle_s %.0f min, without %.0f min (bound at start %.2f µm, without %.2f) | | |" % (
                        c, key, ", ".join(o["chosen"]) or "none", o["settle_s"] / 60, o["settle_s_without"] / 60,
                        o["steps"][-1]["bound_um"] if o["steps"] else o["bound_um_without"], o["bound_um_without"]))
                if i.get(key + "_settle_s") is not None:
                    sb = i.get(key + "_settle_bound")
                    nr = i.get(key + "_settle_without_record_s")
                    print("| %s | %s observer | settle_s %.0f min%s%s | | |" % (c, key, i[key + "_settle_s"] / 60,
                          "" if nr is None else " (without the controller's record %.0f min)" % (nr / 60), "" if sb is None else
                          "; settle bound %.0f min: %d of %d structures with lags refused, chosen %s" % (
                              sb["settle_max_s"] / 60, sb["structures_refused"], sb["structures_checked"], sb["chosen"])))
            if "dynamic_average" in i:
                a = i["dynamic_average"]
                print("| %s | structure average: %s | %s | forward score %s µm (single %s µm) | |" % (
                    c, "averaged" if a["members"] else "single kept: %s; best weights %s" % (a.get("why_single"), a.get("best_weights")),
                    "; ".join("w %.1f: %s (ridge %g, score %.3g)" % (m["weight"], ", ".join("%s %g s" % tuple(t) for t in m["terms"]),
                                                                   m["ridge"], m["score_um"]) for m in a["members"] or []),
                    "–" if a.get("best_score_um") is None else "%.3g" % a["best_score_um"],
                    "–" if a.get("single_score_um") is None else "%.3g" % a["single_score_um"]))
                print("| %s | single structure | %s | | |" % (c, ", ".join("%s %g s %.3g" % tuple(t) for t in i["dynamic_single_terms"])))
            print("| %s | static ≤ 5 | %s | | |" % (c, "%s: %s" % (i["static_le5"]["method"], ", ".join(i["static_le5"]["sensors"]))
                                                   if "static_le5" in i else "–"))
    if args.loco:
        loco = {}
        for ch in channels:
            loco[ch] = leave_one_cycle_out(run, ch, methods=("mlr", "cv-subset", "dynamic"), options={"dynamic": opts})
            print("leave-one-cycle-out %s done" % ch, file=sys.stderr, flush=True)
        report["leave_one_cycle_out"] = {ch: {"ratio_to_mlr": v["ratio_to_mlr"], "rmse_um": {m: r["rmse_um"] for m, r in v["methods"].items()},
                                              "folds": _loco_folds(v)}
                                         for ch, v in loco.items()}
        print("\nLeave-one-cycle-out (6 cycles), pooled held-out RMSE ratio to MLR-16\n")
        print("| method | %s |" % " | ".join(channels))
        print("|---|%s" % ("---|" * len(channels)))
        for m in ("cv-subset", "dynamic"):
            print("| %s | %s |" % (m, " | ".join("%.2f" % loco[c]["ratio_to_mlr"][m] for c in channels)))
        print("\nPer fold: held-out RMSE (um) of MLR-16 and the dynamic model, the dynamic model's forward-chaining score on "
              "its training blocks (pooled; and the worse of the two starts per block, pooled, where the controller "
              "supplies states) and its terms\n")
        print("| channel | held-out cycle (rpm) | MLR-16 | dynamic | forward pooled | worse of starts | dynamic terms (signal tau_s coefficient) |")
        print("|---|---|---|---|---|---|---|")
        num = lambda v: "–" if v is None else "%.2f" % v  # noqa: E731
        for c in channels:
            for f in report["leave_one_cycle_out"][c]["folds"]:
                print("| %s | %d (%s) | %.2f | %.2f | %s | %s | %s |" % (
                    c, f["cycle"], "/".join("%g" % r for r in f["speeds_rpm"]), f["mlr_rmse_um"], f["dynamic_rmse_um"],
                    num(f["forward_pooled_um"]), num(f["worse_of_starts_pooled_um"]),
                    ", ".join("%s %g %.3g" % tuple(t) for t in f["dynamic_terms"])))
    if args.json:
        write_json(args.json, args.run, report)
    return 0


def write_json(path, run_folder, report):
    """``report`` as JSON at ``path`` (--json), written atomically and never over the run it was measured on."""
    from host.outputs import Outputs

    with Outputs([run_folder]) as out:
        out.file(path, "--json")
        with out.open(path) as fh:
            json.dump(report, fh, indent=1)
        out.commit()


if __name__ == "__main__":
    sys.exit(main())
