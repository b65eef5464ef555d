"""tcomp compare RUN... --json OUT [--plots DIR]"""


def add_arguments(p):
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders (fit on one, predict the others), or one run with --split-h")
    p.add_argument("--json", required=True, metavar="OUT", help="write every result (metrics, sensors, statistics) as JSON")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots (curves, residuals, scree, selections, summary)")
    p.add_argument("--channel", help="errors.csv channel to model (multi-channel runs)")
    p.add_argument("--direct", action="store_true", help="direct model of the error at a fixed point (default: slope of each sweep)")
    p.add_argument("--sensors", help="comma-separated candidate sensors (default: all common to the runs)")
    from host.learning.empirical.methods import COMPARE_DEFAULT

    p.add_argument("--methods", default=",".join(COMPARE_DEFAULT),
                   help="comma list of methods (default: all but maxtree-mlr, which is maxtree under the paper's name)")
    p.add_argument("--train", default="0", help="index of the training run, a comma list, or 'all' (each in turn); indices joined "
                                                "by + are pooled into one training set (0+1: Li 2017's two speeds); default 0")
    p.add_argument("--split-h", type=float, metavar="HOURS", help="one run: fit on t < HOURS, predict t >= HOURS")
    p.add_argument("--noise-C", type=float, default=0.2, help="robustness: temperature noise, standard deviation (default 0.2 °C)")
    p.add_argument("--offset-C", type=float, default=0.5, help="robustness: per-sensor offset up to ± this after the start (default 0.5 °C)")
    p.add_argument("--repeats", type=int, default=5, help="robustness: disturbance realisations averaged per test run (default 5)")
    p.add_argument("--reference", choices=("run_start", "fixed"), default="run_start",
                   help="temperature-rise reference when predicting a run: its own first sample (default, the literature's ΔT) or the training runs' mean start (as exported)")
    p.add_argument("--option", action="append", default=[], metavar="METHOD.KEY=VALUE",
                   help="method setting, e.g. pcr.variance_threshold=0.9, stepwise.f_enter=50, cv-subset.max_sensors=3, hclust-ga.seed=2 (repeatable)")
    p.add_argument("--no-intercept", action="store_true", help="fit without intercept")


def _method_options(items, methods):
    """--option METHOD.KEY=VALUE list -> (estimator options, selector parameters), values parsed as JSON when possible."""
    from host.errors import UserError
    from host.options import json_or_word, split_option
    from host.learning.empirical.compare import METHODS, PIPELINES, SELECTORS

    options, selector = {}, {}
    expected = "METHOD.KEY=VALUE, e.g. pcr.variance_threshold=0.9"
    for item in items:
        lhs, value = split_option(item, expected)
        method, dot, key = lhs.partition(".")
        if not dot or not key:
            raise UserError("--option %r: expected %s" % (item, expected))
        if method not in METHODS:
            raise UserError("--option %r: unknown method %r (known: %s)" % (item, method, ", ".join(METHODS)))
        if method in ("mlr", "maxtree-mlr"):
            raise UserError("--option %r: %s has no settings" % (item, method))
        v = json_or_word(value)
        if method not in SELECTORS:
            import inspect

            from host.learning.empirical.methods import estimator_class, method_options

            estimator = PIPELINES.get(method, (None, method))[1]
            params = inspect.signature(estimator_class(estimator).__init__).parameters
            known = list(method_options(estimator))
            if key not in known:
                raise UserError("--option %r: %s has no setting %r (settings: %s)" % (item, method, key, ", ".join(known)))
            default = params[key].default if key in params else None
            numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
            if numeric and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise UserError("--option %r: %s.%s must be a number, got %r" % (item, method, key, value))
        (selector if method in SELECTORS else options).setdefault(method, {})[key] = v
    return options, selector


def run(args):
    from host.errors import UserError
    from host.learning.empirical.compare import METHODS
    from host.outputs import Outputs

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise UserError("--methods: unknown %s (known: %s)" % (", ".join(bad), ", ".join(METHODS)))
    if not methods:
        raise UserError("--methods %r: empty method list (known: %s)" % (args.methods, ", ".join(METHODS)))
    _check_robustness(args)
    with Outputs(args.runs) as out:
        out.file(args.json, "--json")
        if args.plots:
            out.folder(args.plots, "--plots")
        return _compare(args, methods, out)


def _compare(args, methods, out):
    import json

    from host.cli import sensor_list
    from host.errors import UserError
    from host.learning.empirical import EmpiricalDataError
    from host.learning.empirical.compare import case_split, cases_runs, findings, public, run_case, table, write_plots
    from host.data.runs import RunFormatError, load_runs

    try:
        runs = load_runs(args.runs)
    except RunFormatError as exc:
        raise UserError(str(exc))
    if args.split_h is not None:
        _check_split(args.split_h, runs)
    options, selector_params = _method_options(args.option, methods)
    target = "direct" if args.direct else "slope"
    sensors = sensor_list(args.sensors)
    try:
        if args.split_h is not None:
            if len(runs) != 1:
                raise UserError("--split-h takes exactly one run (got %d)" % len(runs))
            cases = [case_split(runs[0], args.split_h * 3600.0, target, args.channel, sensors)]
        else:
            if args.train == "all":
                idx = list(range(len(runs)))
            else:
                try:
                    idx = [tuple(int(u) for u in v.split("+")) if "+" in v else int(v) for v in args.train.split(",")]
                except ValueError:
                    raise UserError("--train: expected an index, a comma list, indices joined by + (pooled) or 'all', got %r" % args.train)
            cases = cases_runs(runs, idx)
        results = []
        for case in cases:
            results += run_case(case, methods, target, args.channel, sensors, not args.no_intercept, options=options,
                                selector_params=selector_params,
                                robustness={"noise_C": args.noise_C, "offset_C": args.offset_C, "repeats": args.repeats}, keep_models=bool(args.plots), reference=args.reference)
    except EmpiricalDataError as exc:
        raise UserError(str(exc))
    print(table(results))
    notes = findings(results) + [_scoring_note(args.reference, target)]
    for line in notes:
        print(line)
    doc = {"target": target, "channel": args.channel, "reference": args.reference, "runs": [r.path for r in runs], "methods": methods,
           "robustness": {"noise_C": args.noise_C, "offset_C": args.offset_C, "repeats": args.repeats}, "results": public(results), "findings": notes}
    if args.plots:
        doc["plots"] = [out.shown(p) for p in write_plots(results, cases, out.path(args.plots), target, args.channel)]
        print("wrote %d plots to %s" % (len(doc["plots"]), args.plots))
    with out.open(args.json) as fh:
        json.dump(doc, fh, indent=2, default=float)
        fh.write("\n")
    out.commit()
    print("wrote %s" % args.json)
    failed = [r for r in results if r.get("error")]
    if results and len(failed) == len(results):
        raise UserError("every method failed (first: %s: %s); details in %s" % (failed[0]["method"], failed[0]["error"], args.json))
    return 0


def _scoring_note(reference, target):
    """Why a model's compare figure is not the RMSE tcomp predict prints for it (host/cli/verbs/predict.py
    _compare_view says the same from the other side)."""
    what = ("the thermal part, on the rows after each test run's cold sweep, against the measured error minus that "
            "sweep (tests.*.comprehensive: the whole error of the same rows)" if target == "slope" else "the model's channel")
    ref = ("--reference run_start: rises from each run's own first sample, while tcomp fit saves reference 'fixed' (the "
           "training runs' mean start, as the board uses) and tcomp predict applies it; --reference fixed scores models "
           "as fit saves them" if reference == "run_start" else "--reference fixed: models as tcomp fit saves them")
    return "note: RMSE here is of %s; tcomp predict's is of the whole error of every row. %s." % (what, ref)


def _check_robustness(args):
    import math

    from host.errors import UserError

    if args.repeats < 1:
        raise UserError("--repeats %d: must be >= 1 (disturbance realisations per test run)" % args.repeats)
    for flag, v in (("--noise-C", args.noise_C), ("--offset-C", args.offset_C)):
        if not (math.isfinite(v) and v >= 0):
            raise UserError("%s %s: must be a finite number >= 0 (degC)" % (flag, v))


def _check_split(split_h, runs):
    """--split-h must cut the one run's measured span into a training and a test part."""
    import math

    from host.errors import UserError

    if len(runs) != 1:
        raise UserError("--split-h takes exactly one run (got %d)" % len(runs))
    if not math.isfinite(split_h) or split_h <= 0:
        raise UserError("--split-h %s: must be a positive number of hours" % split_h)
    t = runs[0].errors.time_s
    lo, hi = float(t.min()) / 3600.0, float(t.max()) / 3600.0
    if not lo < split_h < hi:
        raise UserError("--split-h %s: must lie inside the measured span of %s, %.4g..%.4g h (errors.csv), "
                        "so that there is data to fit before it and to test after it" % (split_h, runs[0].path, lo, hi))
