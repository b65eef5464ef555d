"""tcomp fit --model KIND RUN... --out MODEL.json"""

from host.learning.empirical.methods import FIT_METHODS as EMPIRICAL  # the empirical methods with a document form


def add_arguments(p):
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders to fit on")
    p.add_argument("--model", required=True, choices=EMPIRICAL + ("screw",))
    p.add_argument("--out", required=True, help="model document to write (docs/model-format.md)")
    p.add_argument("--sensors", help="comma-separated sensors to use (default: all, or the method's own selection)")
    p.add_argument("--channel", help="errors.csv channel to model (multi-channel runs)")
    p.add_argument("--direct", action="store_true", help="direct model of the error (linear_direct) instead of poly_slope")
    p.add_argument("--no-intercept", action="store_true", help="direct model without intercept")
    p.add_argument("--json", help="write the fit report as JSON")
    p.add_argument("--t-min", dest="t_min", type=float, metavar="S",
                   help="train only on errors.csv rows with time_s >= S (seconds of each run's clock); recorded in the "
                        "document's training window (empirical: --option t_min_s, screw: --option fit_window, the same)")
    p.add_argument("--t-max", dest="t_max", type=float, metavar="S", help="train only on errors.csv rows with time_s < S")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="method-specific setting (repeatable)")


def run(args):
    from host.cli import sensor_list
    from host.outputs import Outputs

    with Outputs(args.runs) as out:
        # Claimed before the fit, which can take minutes, so a typo in a path does not waste it.
        out.file(args.out, "--out")
        if args.json:
            out.file(args.json, "--json")
        sensor_list(args.sensors)
        _window_options(args)
        if args.model in EMPIRICAL:
            from host.cli.fit_empirical import fit_command
        else:
            from host.cli.fit_screw import fit_command
        rc = fit_command(args, out)
        out.commit()
    print("wrote %s" % args.out)  # after the commit: a failed --json leaves no model, so none is announced
    return rc


def _window_options(args):
    """--t-min/--t-max as the training-window option of the chosen model kind (one spelling each, never both)."""
    import math

    from host.errors import UserError

    if args.t_min is None and args.t_max is None:
        return
    for flag, v in (("--t-min", args.t_min), ("--t-max", args.t_max)):
        if v is not None and not math.isfinite(v):
            raise UserError("%s %s: must be a finite number of seconds" % (flag, v))
    if args.t_min is not None and args.t_max is not None and not args.t_min < args.t_max:
        raise UserError("--t-min %g, --t-max %g: the training window is empty (--t-min must be < --t-max)" % (args.t_min, args.t_max))
    keys = ("t_min_s", "t_max_s") if args.model in EMPIRICAL else ("fit_window",)
    given = [o for o in args.option if o.partition("=")[0].strip() in keys]
    if given:
        raise UserError("--t-min/--t-max and --option %s set the same training window: give one of them" % given[0])
    if args.model in EMPIRICAL:
        args.option = list(args.option) + ["%s=%r" % (k, v) for k, v in zip(keys, (args.t_min, args.t_max)) if v is not None]
    else:
        # the screw model's window keeps a row at exactly its upper end: the float just below --t-max keeps
        # "time_s < S" the one meaning of --t-max for every kind
        hi = "" if args.t_max is None else repr(math.nextafter(args.t_max, -math.inf))
        args.option = list(args.option) + ["fit_window=%s:%s" % ("" if args.t_min is None else repr(args.t_min), hi)]
