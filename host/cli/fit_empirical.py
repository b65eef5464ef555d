"""``tcomp fit --model`` for the empirical methods (host/learning/empirical/methods.py FIT_METHODS; arguments
defined in host/cli/verbs/fit.py)."""
from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any
from typing import TYPE_CHECKING
import json
import sys

from host import options
from host.learning.empirical import EmpiricalDataError
from host.options import boolean, number, number_or_choice, number_or_none, numbers

if TYPE_CHECKING:
    from host.outputs import Outputs

# --option KEY=VALUE settings understood by fit_command, with their converters (host/options.py); a
# minimum is the smallest meaningful value, below which the estimator would fail obscurely or accept nonsense.
# Which method a key belongs to is not written here: it is the method's estimator parameters and candidate
# options (host/learning/empirical/methods.py method_options); the keys no method owns go to fit_model.
OPTIONS = {
    "variance_threshold": number(float),  # PCR
    "n_components": number(int, 1),  # PCR
    "f_enter": number(float),  # stepwise
    "f_remove": number(float),  # stepwise
    "envelope_margin_K": number(float, 0.0),
    "reference": str,  # run_start | fixed
    "geometric_max_degree": number(int, 1),
    "geometric_degree": number(int, 1),  # exact degree of the cold polynomial (Li 2021: 5, S004: 4)
    "geometric_criterion": str,  # cv | aic
    "t_min_s": number(float),  # training window on target time
    "t_max_s": number(float),
    "max_sensors": number(int, 1),  # cv-subset, dynamic
    "cv_blocks": number(int, 2),  # cv-subset on one run; ann's validation group
    "hidden_sizes": numbers(int, 1),  # ann: candidate sizes, e.g. 3/4/5
    "seed": number(int, 0),  # ann
    "max_epochs": number(int, 1),  # ann
    "patience": number(int, 1),  # ann
    "validation_fraction": number(float),  # ann, random validation
    "validation": str,  # ann: auto | random | last_group | loo
    "size_rule": str,  # ann: smallest_near_best | best
    "size_tolerance": number(float, 0.0),  # ann: relative MSE slack of smallest_near_best
    "learning_rate": number(float),  # ann
    "taus_s": numbers(float),  # dynamic: time-constant grid, e.g. 0/1800/7200
    "ridge": numbers(float),  # dynamic: penalty grid
    "max_terms": number(int, 1),  # dynamic
    "min_gain": number(float, 0.0),  # dynamic
    "cv_score": str,  # dynamic: worst | pooled
    "swaps": boolean,  # dynamic
    "use_spindle": boolean,  # dynamic
    "use_feed": boolean,  # dynamic
    "observer": boolean,  # dynamic: estimate the lag states from the sensors when a board starts (observer.py)
    "selection": str,  # dynamic: forward | loo (how sensors, lags and penalty are scored)
    # dynamic: forward chaining over N equal time blocks of one run, its spindle's running and stopped phases (the default
    # with a spindle log) or its spindle cycles
    "forward_blocks": number_or_choice(int, 3, "phases", "cycles"),
    "forward_state": str,  # dynamic: switched_on | continuous (how a scored block's filters start; switched_on: blocks >= 90 min)
    "spindle_states": str,  # dynamic: observer | controller (the controller's record supplies the spindle/feed lag states; default with the observer)
    "controller_scoring": str,  # dynamic, with spindle_states=controller: record | worse (each block by the worse of with and without the record; default)
    "static_fallback": boolean,  # dynamic: keep the static (tau 0) search's structure when it scores better
    "average_structures": number(int, 1),  # dynamic: average up to N structures, weights by forward chaining (1: the best one)
    "average_members": str,  # dynamic: ridge | path (where the averaged structures come from)
    "tau_max_fraction": number(float),  # dynamic: lags up to this fraction of the training span
    "settle_max_s": number_or_none(float, 0.0),  # dynamic: only structures whose observer settles within this (s; none/0: off; default 1800 with the observer)
    "settle_without_record_max_s": number_or_none(float, 0.0),  # dynamic: ... and whose board without the controller's record does (s; default off)
    "observer_sensors": number(int, 0),  # dynamic: sensors beyond the terms' the observer may read (0: none; observer.py)
    "degree": number(int, 1),  # mr-poly: the nut rise's polynomial degree (exact, 1..4)
    "nut": str,  # mr-poly: nut sensor (default: role "nut")
    "base": str,  # mr-poly: base sensor (default: role "base")
    "n_terms": number(int, 1),  # ppr: ridge terms
    "knots": number(int, 3),  # ppr: spline knots per ridge function
    "backfit_passes": number(int, 0),  # ppr
}


def parse_options(pairs: Iterable[str] | None, method: str) -> dict[str, Any]:
    """--option KEY=VALUE list -> dict, rejecting unknown keys and options of other methods."""
    from host.errors import UserError
    from host.learning.empirical.methods import FIT_METHODS, method_options

    out = options.parse_options(pairs, OPTIONS)
    for key in out:
        owner = [m for m in FIT_METHODS if key in method_options(m)]
        if owner and method not in owner:
            raise UserError("--option %s applies to --model %s, not %s" % (key, owner[0], method))
    lo, hi = out.get("t_min_s"), out.get("t_max_s")
    if lo is not None and hi is not None and not lo < hi:
        raise UserError("--option t_min_s=%g, t_max_s=%g: the training window is empty (t_min_s must be < t_max_s)" % (lo, hi))
    return out


def fit_command(args: argparse.Namespace, out: Outputs) -> int:
    """Fit, print the report, write ``args.out`` (and ``args.json``) through ``out`` (host.outputs.Outputs)."""
    from host.errors import UserError
    from host.learning.empirical.fitting import fit_model
    from host.learning.documents import save_model
    from host.data.runs import RunFormatError, load_runs

    opts = parse_options(args.option, args.model)
    try:
        runs = load_runs(args.runs)
    except RunFormatError as exc:
        raise UserError(str(exc))
    sensors = [s.strip() for s in args.sensors.split(",") if s.strip()] if args.sensors else None
    lo, hi = opts.pop("t_min_s", None), opts.pop("t_max_s", None)
    window = (lo, hi) if lo is not None or hi is not None else None
    target = "direct" if args.direct else "slope"
    try:
        model = fit_model(runs, method=args.model, target=target, channel=args.channel, sensors=sensors,
                          fit_intercept=not args.no_intercept, window=window, **opts)
    except EmpiricalDataError as exc:
        raise UserError(str(exc))
    except TypeError as exc:
        raise UserError("bad --option for %s: %s" % (args.model, exc))
    doc = save_model(model.to_document(), out.path(args.out))
    # DynamicModel's fitted attributes are set by fitting.fit_model but not declared in dynamic.py (being changed
    # by others; declared there later)
    est = model.estimator_  # pyright: ignore[reportAttributeAccessIssue]
    print("%s %s model of %s on %d run(s), %d samples: sensors %s" % (
        args.model, model.kind, args.channel or "the error", len(runs), est.n_samples_, ",".join(model.sensors)))
    if args.model == "mlr":
        print(est.summary())
    elif args.model == "stepwise":
        for h in est.history_:
            print("  step %d: %s %s (partial F %.4g, threshold %g)" % (h["step"], h["action"], h["sensor"], h["F"], h["threshold"]))
        print(est.mlr_.summary())
    elif args.model == "cv-subset":
        print("  %s; cross-validation over %d groups" % (est.search_, est.n_groups_))
        for k, v in sorted(est.cv_rmse_.items()):
            print("  best %d-sensor subset %s: CV RMSE %.4g" % (k, ",".join(v["sensors"]), v["cv_rmse"]))
        print(est.mlr_.summary())
    elif args.model == "dynamic":
        how = "forward chaining over %d time blocks" if est.selection == "forward" else "leave-one-group-out over %d groups"
        print("  terms and ridge %g chosen by %s (%s score %.4g); fit R2=%.4f RMSE=%.4g" % (
            est.ridge_, how % est.n_groups_, est.cv_score_, est.cv_rmse_, est.rsquared_, est.rmse_))
        scored_as = model.statistics.get("forward_scored_as")
        if scored_as and scored_as["continuous_blocks"]:
            print("  blocks %s scored with the filters running since the run start: shorter than %.0f min (a board switched on "
                  "may settle for 30 min)" % (",".join(str(k) for k in scored_as["continuous_blocks"]), scored_as["switched_on_min_s"] / 60))
        for (sig, tau), c in zip(est.terms_, est.coef_):
            print("  %+.5g x lag(%s, tau %g s)" % (c, sig, tau))
        obs = getattr(model, "observer", None)
        if obs is not None:
            worst = max(obs.states, key=lambda st: abs(model.term_coefficients[st["term"]]) * st["bound"], default=None)
            print("  observer: lag states estimated from the inputs at a start; start-error bound %.3g um, within %.3g um after "
                  "%.0f min (SETTLING)%s" % (obs.start_error_bound(model), obs.tolerance, obs.settle_s / 60,
                                             "" if worst is None else "; largest share: lag(%s, tau %g s)" % model.terms[worst["term"]]))
        from host.learning.empirical.observer import CONTROLLER

        supplied = [model.terms[st["term"]] for st in (obs.states if obs is not None else []) if st.get("source") == CONTROLLER]
        if supplied and obs is not None and obs.settle_without_record_s is not None:
            # what the start-error bound settles in when the controller's values do not come (the states at their estimate)
            print("  lag states the controller supplies from its record at a start (spindle_states=controller): %s; on the "
                  "machine `tcomp linuxcnc --spindle --signal-record FILE` sends them (table format 7 and later), `tcomp predict "
                  "--controller-history` reads the record; without it they start at the observer's estimate, which settles "
                  "in %.0f min (the board's SETTLING then)" % (", ".join("lag(%s, tau %g s)" % t for t in supplied),
                                                              obs.settle_without_record_s / 60))
        ob = model.statistics.get("observer_sensors")
        if ob:
            print("  observer-only sensors (up to %d, the model's sensors within %d): %s; settle_s %.0f min, %.0f min without" % (
                ob["allowed"], ob["max_sensors"], ", ".join(ob["chosen"]) or "none lowered settle_s", ob["settle_s"] / 60,
                ob["settle_s_without"] / 60))
        sb = model.statistics.get("settle_bound")
        if sb:
            print("  settle bound: only structures with settle_s <= %.0f min admitted; %d of %d structures with lags checked were "
                  "refused%s; the model's settle_s %.0f min" % (
                      sb["settle_max_s"] / 60, sb["structures_refused"], sb["structures_checked"],
                      "" if sb["best_refused_score_um"] is None else " (best refused score %.4g)" % sb["best_refused_score_um"],
                      (sb["settle_s"] or 0.0) / 60))
            if sb.get("without_record_max_s") is not None:
                print("  and without the controller's record settle_without_record_s <= %.0f min: %d structures refused for "
                      "that alone" % (sb["without_record_max_s"] / 60, sb["refused_without_record"]))
        fb = model.statistics.get("static_fallback")
        if fb:
            print("  static fallback: search over every term scored %.4g, over the static terms (tau 0) alone %s: the %s structure "
                  "is the model" % (fb["dynamic_score_um"], "no structure" if fb["static_score_um"] is None else "%.4g" % fb["static_score_um"],
                                    fb["chosen"]))
        rs = model.statistics.get("record_structure_start")
        if rs and rs["record_structure"] is None:
            print("  search from record scoring's structure: none (%s); the search from empty is the model" % rs["record_error"])
        elif rs:
            print("  search from record scoring's structure (%s, worse of starts %.4g) ended at %.4g, from empty %.4g: the search "
                  "%s is the model" % (", ".join("lag(%s, tau %g s)" % tuple(t) for t in rs["record_structure"]),
                                       rs["record_structure_score_um"], rs["from_record_structure_score_um"], rs["from_empty_score_um"],
                                       "from record scoring's structure" if rs["chosen"] == "from_record_structure" else "from empty"))
        sa = model.statistics.get("structure_average")
        if sa and sa.get("members"):
            print("  structure average of %d structures (forward-chaining score %.4g against %.4g for the single best):" % (
                len(sa["members"]), sa["averaged_score_um"], sa["single_score_um"]))
            for m in sa["members"]:
                print("    weight %.2f: %s (ridge %g, score %.4g)" % (m["weight"], ", ".join("lag(%s, tau %g s)" % tuple(t) for t in m["terms"]),
                                                                   m["ridge"], m["score_um"]))
        elif sa:
            print("  structure average: the single best structure kept (%s)" % sa["why_single"])
        lb = model.statistics.get("lag_bound", {})
        if lb.get("excluded_taus_s"):
            print("  lags %s s left out: longer than %g x the training span (%.0f s)" % (
                "/".join("%g" % v for v in lb["excluded_taus_s"]), lb["fraction"], lb["training_span_s"]))
    elif args.model == "mr-poly":
        terms = " ".join("%+.5g*dTn^%d" % (a, j + 1) for j, a in enumerate(est.nut_coef_))
        print("  S004 Eq. 12, nut %s, base %s, degree %d: s = %.5g %s %+.5g*dTb; fit R2=%.4f RMSE=%.4g" % (
            model.sensors[0], model.sensors[1], est.nut_coef_.size, est.intercept_, terms, est.base_coef_, est.rsquared_, est.rmse_))
    elif args.model == "ann":
        print("  %d hidden nodes chosen by validation (%s), rule %s; validation MSE / R2 by size: %s" % (
            est.hidden_size_, est.validation_, est.size_rule,
            ", ".join("%d: %.4g / %.4f" % (h, v ** 2, est.validation_r2_[h]) for h, v in sorted(est.validation_rmse_.items()))))
        print("  fit on all training samples: R2=%.4f RMSE=%.4g; best epoch %d" % (est.rsquared_, est.rmse_, est.best_epoch_))
    elif args.model == "ppr":
        print("  %d ridge terms, %d knots each, %d backfit pass(es); fit R2=%.4f RMSE=%.4g" % (
            len(est.terms_), est.knots, est.backfit_passes, est.rsquared_, est.rmse_))
        for m, t in enumerate(est.terms_):
            print("  term %d direction (standardised rises): %s" % (m + 1, " ".join("%s %+.3f" % (s, a) for s, a in zip(est.names_, t.a))))
    else:
        print("  %d of %d components kept (cumulative explained variance %.1f %%, threshold %.0f %%)" % (
            est.n_components_, est.eigenvalues_.size, 100 * est.cumulative_variance_ratio_[est.n_components_ - 1], 100 * est.variance_threshold))
        print("  R2=%.4f adj R2=%.4f F=%.4g (p=%.3g) residual std error=%.4g" % (est.rsquared_, est.rsquared_adj_, est.fvalue_, est.f_pvalue_, est.resid_std_err_))
    fc = model.statistics.get("forward_chaining")
    if fc and "rmse_um" in fc:
        print("  forward chaining (fit on the past, predict the next of %d blocks switched on at its start): RMSE %s um; worst %.4g, "
              "pooled %.4g" % (fc["blocks"], " ".join("%.4g" % v for v in fc["rmse_um"]), fc["worst_um"], fc["pooled_um"]))
        if "largest_share" in fc:
            print("  block %d carries %.0f %% of the pooled squared error (with one block near 100 %%, the choice rests on how "
                  "that period resembles the future)" % (fc["largest_share"]["block"], 100 * fc["largest_share"]["share"]))
        if "without_record_rmse_um" in fc:  # states the controller supplies: the same blocks without its record
            print("  the same without the controller's record (its states at the observer's estimate): RMSE %s um; pooled %.4g; "
                  "the worse of the two per block, pooled %.4g (controller_scoring=worse's criterion)" % (
                      " ".join("%.4g" % v for v in fc["without_record_rmse_um"]), fc["without_record_pooled_um"],
                      fc["worse_of_starts_pooled_um"]))
        base = fc.get("baseline_mlr_all")
        if base and "error" in base:
            print("  baseline (MLR on all %d candidate sensors) not scored: %s" % (len(base["sensors"]), base["error"]))
        elif base:
            print("  baseline on the same blocks, MLR on all %d candidate sensors: RMSE %s um; worst %.4g, pooled %.4g" % (
                len(base["sensors"]), " ".join("%.4g" % v for v in base["rmse_um"]), base["worst_um"], base["pooled_um"]))
            if fc["pooled_um"] > base["pooled_um"] * (1 + 1e-9):  # worse, not a tie (a static structure can be the MLR)
                # not silent: the user asked for a dynamic model and this one predicted the past blocks worse
                print("tcomp fit: warning: the dynamic model predicts the next block worse than MLR on all %d candidate sensors "
                      "(forward chaining, pooled %.4g um against %.4g um): fit --model mlr or compare them on held-out data "
                      "before using it" % (len(base["sensors"]), fc["pooled_um"], base["pooled_um"]), file=sys.stderr)
    elif fc:
        print("  forward chaining not scored: %s" % fc["error"])
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"model": args.out, "kind": doc["kind"], "method": args.model, "sensors": model.sensors,
                       "statistics": doc["statistics"], "training": doc["training"]}, fh, indent=2)
    return 0
