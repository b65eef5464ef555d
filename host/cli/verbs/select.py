"""tcomp select --method maxtree|stepwise|hclust-ga RUN... --json OUT  |  tcomp select --method maxtree --corr CORR.csv --json OUT"""

from __future__ import annotations

import argparse

from host.learning.empirical.methods import SELECTORS as METHODS


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="*", metavar="RUN", help="run folders (not with --corr)")
    p.add_argument("--method", required=True, choices=METHODS)
    p.add_argument("--json", required=True, metavar="OUT", help="write the selection (sensors, method, reason) as JSON")
    p.add_argument("--plot", metavar="PNG", help="also draw the plot explaining the choice")
    p.add_argument("--channel", help="errors.csv channel to model (multi-channel runs)")
    p.add_argument("--target", choices=("slope", "direct"), default="slope", help="slope of each sweep (default) or the error itself")
    p.add_argument("--sensors", help="comma-separated candidate sensors (default: all common to the runs)")
    p.add_argument("--split", type=int, default=1, metavar="N",
                   help="cut each run into N equal time windows used as separate runs (one long record for hclust-ga)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="method parameter, e.g. seed=3, f_enter=50, alpha=0.01 (repeatable)")
    p.add_argument("--corr", metavar="CORR.csv", help="maxtree on a precomputed correlation matrix (header of names, square matrix)")
    p.add_argument("--target-corr", metavar="TCORR.csv", help="with --corr: sensor,r rows (optional header line) for the representatives")


def run(args: argparse.Namespace) -> int:
    import json

    from host.errors import UserError
    from host.learning.empirical import EmpiricalDataError
    from host.outputs import Outputs

    with Outputs(list(args.runs) + [args.corr, args.target_corr]) as out:
        out.file(args.json, "--json")
        if args.plot:
            out.file(args.plot, "--plot")
            _check_plot_format(args.plot)
        try:
            if args.corr:
                doc = _run_corr(args, out)
            else:
                doc = _run_data(args, out)
        except EmpiricalDataError as exc:
            raise UserError(str(exc))
        with out.open(args.json) as fh:
            json.dump(doc, fh, indent=2, allow_nan=False)
            fh.write("\n")
        out.commit()
    return 0


def _check_plot_format(path):
    import os

    from matplotlib.backend_bases import FigureCanvasBase

    from host.errors import UserError

    ext = os.path.splitext(path)[1].lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if not ext:
        # matplotlib would add .png to the name it is given: the image would land beside the output, not in it
        raise UserError("--plot %s: name the image format by the file's extension (e.g. .png; formats: %s)"
                        % (path, ", ".join(sorted(formats))))
    if ext not in formats:
        raise UserError("--plot %s: cannot draw a .%s file (formats: %s)" % (path, ext, ", ".join(sorted(formats))))


def _run_corr(args, out):
    from host.errors import UserError
    from host.learning.empirical.selectors import maximal_tree
    from host.learning.empirical.selectors.corrcsv import read_corr_csv, read_target_corr_csv

    if args.method != "maxtree":
        raise UserError("--corr works with --method maxtree only (the other methods need the data)")
    if args.runs:
        raise UserError("give either --corr or run folders, not both")
    for flag in ("channel", "sensors"):
        if getattr(args, flag):
            raise UserError("--%s has no meaning with --corr" % flag)
    if args.option:
        raise UserError("--option has no meaning with --corr (the partition choice needs the data)")
    C, names = read_corr_csv(args.corr)
    tc = read_target_corr_csv(args.target_corr, names) if args.target_corr else None
    tree = maximal_tree(C, names, target_corr=tc)
    doc = {"method": "maxtree", "source": args.corr}
    doc.update(tree.to_json())
    if args.plot:
        tree.plot(out.path(args.plot), title="Maximal tree of the correlation matrix %s (%d sensors)" % (args.corr, len(names)))
    print("maxtree on %s: %d sensors, %d tree edges, %d distinct partitions" % (args.corr, len(names), len(tree.edges), len(tree.partitions)))
    for part in tree.partitions:
        print("  lambda in [%.4g, %.4g%s: %d clusters, representatives %s"  # as Li 2021 Table 3 writes them
              % (part.lambda_low, part.lambda_high, "]" if part is tree.partitions[-1] else ")", len(part.clusters), ",".join(part.representatives)))
    return doc


def _run_data(args, out):
    from host.cli import sensor_list
    from host.errors import UserError
    from host.options import parse_options
    from host.learning.empirical.selectors import select
    from host.data.runs import RunFormatError, load_runs

    if args.target_corr:
        raise UserError("--target-corr goes with --corr")
    if not args.runs:
        raise UserError("give run folders (or --corr CORR.csv for maxtree on a matrix)")
    try:
        runs = load_runs(args.runs)
    except RunFormatError as exc:
        raise UserError(str(exc))
    sensors = sensor_list(args.sensors)
    params = parse_options(args.option)
    data = runs if args.split == 1 else _windows(runs, args.split, args.target, args.channel, sensors)
    sel = select(args.method, data, target=args.target, channel=args.channel, sensors=sensors, **params)
    doc = sel.to_json()
    doc.update({"target": args.target, "channel": args.channel, "runs": list(args.runs), "split": args.split})
    if args.plot:
        sel.plot(out.path(args.plot))
    print("%s on %d run(s): %s" % (args.method, len(runs), ", ".join(sel.sensors)))
    return doc


def _windows(runs, n, target, channel, sensors):
    """Each run's targets cut into ``n`` equal time windows, as separate RunArrays.

    Temperature rises stay relative to the run's start, as in the whole run.
    """
    from host.errors import UserError
    from host.learning.empirical.targets import RunArrays, targets, training_arrays

    if n < 1:
        raise UserError("--split must be >= 1, got %d" % n)
    out = []
    for run in runs:
        t, _ = targets(run, target, channel)
        edges = [t[0] + (t[-1] - t[0]) * i / n for i in range(n)] + [None]
        for i in range(n):
            a = training_arrays([run], target, channel, sensors, window=(edges[i], edges[i + 1]))[0]
            hi = t[-1] if edges[i + 1] is None else edges[i + 1]
            out.append(RunArrays(a.X, a.y, a.names, a.time_s, "%s[%.4g-%.4g h]" % (run.name, edges[i] / 3600, hi / 3600), a.start, a.log))
    return out
