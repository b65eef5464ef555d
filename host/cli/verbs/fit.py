"""tcomp fit --model KIND RUN... --out MODEL.json"""

from __future__ import annotations

import argparse

from host.learning.empirical.methods import FIT_METHODS as EMPIRICAL  # the empirical methods with a document form


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders to fit on")
    p.add_argument("--model", required=True, choices=EMPIRICAL + ("screw",))
    p.add_argument("--out", required=True, help="model document to write (docs/model-format.md)")
    p.add_argument("--sensors", help="comma-separated sensors to use (default: all, or the method's own selection)")
    p.add_argument("--channel", help="errors.csv channel to model (multi-channel runs)")
    p.add_argument("--direct", action="store_true", help="direct model of the error (linear_direct) instead of poly_slope")
    p.add_argument("--no-intercept", action="store_true", help="direct model without intercept")
    p.add_argument("--json", help="write the fit report as JSON")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="method-specific setting (repeatable)")


def run(args: argparse.Namespace) -> int:
    from host.cli import sensor_list
    from host.outputs import Outputs

    with Outputs(args.runs) as out:
        # Claimed before the fit, which can take minutes, so a typo in a path does not waste it.
        out.file(args.out, "--out")
        if args.json:
            out.file(args.json, "--json")
        sensor_list(args.sensors)
        if args.model in EMPIRICAL:
            from host.cli.fit_empirical import fit_command
        else:
            from host.cli.fit_screw import fit_command
        rc = fit_command(args, out)
        out.commit()
    print("wrote %s" % args.out)  # after the commit: a failed --json leaves no model, so none is announced
    return rc
