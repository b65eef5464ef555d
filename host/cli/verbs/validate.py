"""tcomp validate RUN..."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders")
    p.add_argument("--json", help="write {run: [problems]} as JSON")


def run(args: argparse.Namespace) -> int:
    import json

    from host.outputs import Outputs

    with Outputs(args.runs) as out:
        if args.json:
            out.file(args.json, "--json")
        report = _check(args.runs)
        if args.json:
            with out.open(args.json) as fh:
                json.dump({"runs": [{"run": k, "ok": not v, "problems": v} for k, v in report.items()]}, fh, indent=2)
        out.commit()
    return 1 if any(report.values()) else 0


def _check(folders):
    from host.data.runs import check_run

    report = {}
    for folder in folders:
        problems = check_run(folder)
        report[folder] = problems
        if problems:
            print("%s: %d problem%s" % (folder, len(problems), "" if len(problems) == 1 else "s"))
            for p in problems:
                print("  " + p)
        else:
            print("%s: ok" % folder)
    return report
