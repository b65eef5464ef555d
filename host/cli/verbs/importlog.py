"""tcomp import CSV --out DIR (--mapping MAP.json | --time COL --temp COL... --error COL...)"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="CSV log with a header row")
    p.add_argument("--out", required=True, help="run folder to write")
    p.add_argument("--mapping", help="JSON mapping of source columns (see host/data/importer.py and docs/data-format.md)")
    p.add_argument("--time", help="time column (seconds unless --time-scale)")
    p.add_argument("--time-scale", type=float, default=1.0, help="factor to seconds (60 for minutes)")
    p.add_argument("--temp", action="append", default=[], metavar="COL[=NAME[:ROLE]]", help="temperature column (repeatable)")
    p.add_argument("--error", action="append", default=[], metavar="COL[=CHANNEL[@POSITION_MM]]", help="displacement/error column in um (repeatable)")
    p.add_argument("--spindle", help="spindle speed column (rpm)")
    p.add_argument("--ignore", action="append", default=[], metavar="COL", help="source column deliberately not imported (repeatable)")
    p.add_argument("--axis", help="axis letter for meta.json")
    p.add_argument("--error-reference", metavar="start|SENSOR",
                   help="what the errors are referred to (meta.json error_reference, docs/data-format.md): 'start' (raw, "
                        "relative to the machine at the log's start; the default) or the sensor the laser corrected them to")
    p.add_argument("--json", help="write a summary of what was imported")


def _once(given, col, flag):
    from host.errors import UserError

    if col in given:
        raise UserError("%s: column %r is already mapped by %s; give each column once" % (flag, col, given[col]))
    given[col] = flag


def _from_flags(args):
    from host.errors import UserError

    temps = {}
    given = {}  # column -> the flag that mapped it: a column given twice would keep only the last meaning
    for spec in args.temp:
        col, _, rest = spec.partition("=")
        _once(given, col, "--temp %s" % spec)
        name, _, role = rest.partition(":")
        temps[col] = {"name": name or col, "role": role or "structure"}
    errors = {}
    for spec in args.error:
        col, _, rest = spec.partition("=")
        _once(given, col, "--error %s" % spec)
        chan, _, pos = rest.partition("@")
        try:
            position = float(pos) if pos else 0.0
        except ValueError:
            raise UserError("--error %r: position %r is not a number of mm (COL[=CHANNEL[@POSITION_MM]])" % (spec, pos))
        errors[col] = {"channel": chan or col, "position_mm": position}
    mapping = {"time": args.time, "time_scale": args.time_scale, "temperatures": temps, "errors": errors, "ignore": args.ignore}
    if args.spindle:
        mapping["spindle"] = args.spindle
    return mapping


def run(args: argparse.Namespace) -> int:
    import json

    import math

    from host.errors import UserError
    from host.data.importer import LogImportError, import_to_folder
    from host.outputs import Outputs

    if not (math.isfinite(args.time_scale) and args.time_scale > 0):
        raise UserError("--time-scale %s: must be a positive factor to seconds (60 for minutes)" % args.time_scale)
    from host.data.runs import RUN_FILES

    out = Outputs([args.source, args.mapping])
    out.folder(args.out, "--out", owned=RUN_FILES)
    if args.json:
        out.file(args.json, "--json")
    if args.mapping:
        try:
            with open(args.mapping, encoding="utf-8-sig") as fh:
                mapping = json.load(fh)
        except (OSError, UnicodeDecodeError) as exc:
            raise UserError("%s: cannot be read as UTF-8 JSON (%s)" % (args.mapping, getattr(exc, "strerror", None) or exc))
        except json.JSONDecodeError as exc:
            raise UserError("%s line %d column %d: invalid JSON (%s)" % (args.mapping, exc.lineno, exc.colno, exc.msg))
        where = args.mapping
    else:
        if not args.time:
            raise UserError("give --mapping MAP.json, or --time COL with --temp and --error columns")
        mapping, where = _from_flags(args), "command line"
    if args.axis:
        mapping.setdefault("meta", {})["axis"] = args.axis
    if args.error_reference is not None:
        if not isinstance(mapping.get("meta", {}), dict):
            raise UserError("%s: 'meta' must be an object, found %r" % (where, mapping["meta"]))
        mapping.setdefault("meta", {})["error_reference"] = args.error_reference
        where = "%s (with --error-reference)" % where
    with out:
        try:
            run_ = import_to_folder(args.source, mapping, out.path(args.out), where)
        except LogImportError as exc:
            raise UserError(str(exc))
        _report(args, run_, out)
        out.commit()
    return 0


def _report(args, run_, out):
    import json

    t = run_.temperatures
    print("%s -> %s: %d samples, %d temperatures, %d error channels, %.1f h"
          % (args.source, args.out, t.time_s.size, len(t.names), len(run_.errors.channels()), (t.time_s[-1] - t.time_s[0]) / 3600))
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"out": args.out, "samples": int(t.time_s.size), "sensors": t.names, "channels": run_.errors.channels()}, fh, indent=2)
