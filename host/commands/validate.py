"""tcomp validate RUN..."""


def add_arguments(p):
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders")
    p.add_argument("--json", help="write {run: [problems]} as JSON")


def run(args):
    import json

    from host.cli import check_output, open_output
    from host.runs import check_run

    if args.json:
        check_output(args.json, "--json")
    report = {}
    for folder in args.runs:
        problems = check_run(folder)
        report[folder] = problems
        if problems:
            print("%s: %d problem%s" % (folder, len(problems), "" if len(problems) == 1 else "s"))
            for p in problems:
                print("  " + p)
        else:
            print("%s: ok" % folder)
    if args.json:
        with open_output(args.json) as fh:
            json.dump({"runs": [{"run": k, "ok": not v, "problems": v} for k, v in report.items()]}, fh, indent=2)
    return 1 if any(report.values()) else 0
