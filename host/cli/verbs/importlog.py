"""tcomp import CSV --out DIR (--mapping MAP.json | --time COL --temp COL... --error COL...)
tcomp import --errors FILE.csv --into RUN --mapping MAP.json [--clock-offset S]"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", nargs="?", help="CSV log with a header row (with --out)")
    p.add_argument("--out", help="run folder to write")
    p.add_argument("--errors", metavar="FILE.csv", help="an instrument's error file (a laser's sweeps) to merge into --into RUN by time")
    p.add_argument("--into", metavar="RUN", help="existing run folder that receives the --errors sweeps (errors.csv, meta.json rewritten)")
    p.add_argument("--clock-offset", type=float, metavar="S",
                   help="with --errors: run time_s = the file's time + S (a file of date-times counts from its first sample); "
                        "without it both clocks must be wall clocks: the file's date-times and the run's meta.json start_time")
    p.add_argument("--mapping", help="JSON mapping of source columns (docs/data-format.md, 'Importing logs and instrument files')")
    p.add_argument("--time", help="time column (seconds unless --time-unit/--time-scale, or date-times with --time-format)")
    p.add_argument("--time-scale", type=float, help="factor to seconds (60 for minutes)")
    p.add_argument("--time-unit", choices=("s", "min", "h"), help="unit of a numeric time column")
    p.add_argument("--time-format", metavar="iso8601|STRPTIME", help="the time column holds date-times: 'iso8601' or a strptime format "
                   "('%%d.%%m.%%Y %%H:%%M:%%S'); time_s counts from the first sample")
    p.add_argument("--timezone", metavar="TZ", help="clock of date-times without an offset: UTC, +01:00 or an IANA name (Europe/Berlin)")
    p.add_argument("--header-line", type=int, metavar="N", help="line holding the column names (the export's preamble before it is skipped)")
    p.add_argument("--delimiter", metavar="auto|comma|semicolon|tab", help="cell separator (default: detected, and reported)")
    p.add_argument("--decimal", metavar="auto|point|comma", help="decimal separator (default: detected, and reported)")
    p.add_argument("--gaps", choices=("refuse", "drop", "interpolate"), help="empty cells: refuse (default), drop the row, or interpolate in time")
    p.add_argument("--temp", action="append", default=[], metavar="COL[=NAME[:ROLE]]", help="temperature column (repeatable)")
    p.add_argument("--error", action="append", default=[], metavar="COL[=CHANNEL[@POSITION_MM]]", help="displacement/error column (um unless --unit; repeatable)")
    p.add_argument("--unit", action="append", default=[], metavar="COL=UNIT",
                   help="unit of a --temp (degC, K, degF) or --error (um, mm, in) column (repeatable)")
    p.add_argument("--location", action="append", default=[], metavar="COL=TEXT", help="where a --temp sensor sits, for meta.json (repeatable)")
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


def _pairs(specs, flag):
    """{COL: VALUE} of repeated COL=VALUE flags; a column given twice is refused."""
    from host.errors import UserError

    out = {}
    for spec in specs:
        col, eq, value = spec.partition("=")
        if not eq or not col or not value:
            raise UserError("%s %r: expected COL=VALUE" % (flag, spec))
        if col in out:
            raise UserError("%s %r: column %r is given twice" % (flag, spec, col))
        out[col] = value
    return out


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
    for col, unit in _pairs(args.unit, "--unit").items():
        if col not in temps and col not in errors:
            raise UserError("--unit %s=%s: %r is neither a --temp nor an --error column (the time's unit is --time-unit)" % (col, unit, col))
        (temps if col in temps else errors)[col]["unit"] = unit
    for col, text in _pairs(args.location, "--location").items():
        if col not in temps:
            raise UserError("--location %s=%s: %r is not a --temp column" % (col, text, col))
        temps[col]["location"] = text
    mapping = {"time": args.time, "temperatures": temps, "errors": errors, "ignore": args.ignore}
    if args.time_scale is not None:
        mapping["time_scale"] = args.time_scale
    if args.spindle:
        mapping["spindle"] = args.spindle
    return mapping


# flag -> mapping key, for the settings a mapping may hold too (a flag fills a key the mapping leaves out; a clash is refused)
_READING_FLAGS = (("header_line", "header_line"), ("delimiter", "delimiter"), ("decimal", "decimal"), ("gaps", "gaps"), ("time_format", "time_format"),
                  ("timezone", "timezone"), ("time_unit", "time_unit"))


def _load_mapping(path):
    import json

    from host.errors import UserError

    try:
        with open(path, encoding="utf-8-sig") as fh:
            return json.load(fh)
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError("%s: cannot be read as UTF-8 JSON (%s)" % (path, getattr(exc, "strerror", None) or exc))
    except json.JSONDecodeError as exc:
        raise UserError("%s line %d column %d: invalid JSON (%s)" % (path, exc.lineno, exc.colno, exc.msg))


def _mapping(args):
    """(mapping, where it came from) of --mapping or the column flags, with the reading flags applied."""
    import math

    from host.errors import UserError

    if args.time_scale is not None and not (math.isfinite(args.time_scale) and args.time_scale > 0):
        raise UserError("--time-scale %s: must be a positive factor to seconds (60 for minutes)" % args.time_scale)
    if args.mapping:
        mapping, where = _load_mapping(args.mapping), args.mapping
        if not isinstance(mapping, dict):
            raise UserError("%s: mapping must be a JSON object" % where)
        for flag in ("time", "time_scale", "spindle"):
            if getattr(args, flag) is not None:
                raise UserError("--%s: the mapping %s gives the columns; set it there" % (flag.replace("_", "-"), where))
        for flag in ("temp", "error", "unit", "location", "ignore"):
            if getattr(args, flag):
                raise UserError("--%s: the mapping %s gives the columns; set it there" % (flag, where))
    else:
        if args.errors:
            raise UserError("--errors: give --mapping MAP.json (docs/data-format.md: the long layout of a laser's sweeps)")
        if not args.time:
            raise UserError("give --mapping MAP.json, or --time COL with --temp and --error columns")
        mapping, where = _from_flags(args), "command line"
    for flag, key in _READING_FLAGS:
        value = getattr(args, flag)
        if value is None:
            continue
        if key in mapping and mapping[key] != value:
            raise UserError("--%s %s: the mapping %s says %r; give it in one place" % (flag.replace("_", "-"), value, where, mapping[key]))
        mapping[key] = value
    if args.axis:
        mapping.setdefault("meta", {})["axis"] = args.axis
    if args.error_reference is not None:
        if not isinstance(mapping.get("meta", {}), dict):
            raise UserError("%s: 'meta' must be an object, found %r" % (where, mapping["meta"]))
        mapping.setdefault("meta", {})["error_reference"] = args.error_reference
        where = "%s (with --error-reference)" % where
    return mapping, where


def run(args: argparse.Namespace) -> int:
    from host.errors import UserError

    if args.errors or args.into:
        if not (args.errors and args.into):
            raise UserError("--errors FILE.csv and --into RUN go together (merge an instrument's sweeps into a run)")
        if args.source or args.out:
            raise UserError("--errors/--into merge sweeps into an existing run; a log given as SOURCE with --out makes a new run: "
                            "do one at a time")
        return _merge(args)
    if args.clock_offset is not None:
        raise UserError("--clock-offset aligns an --errors file with an --into run; it does not apply to --out")
    if not args.source or not args.out:
        raise UserError("give a log and --out RUN (tcomp import LOG.csv --out RUN ...), or --errors FILE.csv --into RUN")
    return _import(args)


def _import(args):
    from host.data.importer import LogImportError, import_to_folder
    from host.data.runs import RUN_FILES
    from host.errors import UserError
    from host.outputs import Outputs

    out = Outputs([args.source, args.mapping])
    out.folder(args.out, "--out", owned=RUN_FILES)
    if args.json:
        out.file(args.json, "--json")
    mapping, where = _mapping(args)
    with out:
        try:
            run_ = import_to_folder(args.source, mapping, out.path(args.out), where)
        except LogImportError as exc:
            raise UserError(str(exc))
        _report(args, run_, out)
        out.commit()
    return 0


def _merge(args):
    import os

    from host.data.merge import merge_into
    from host.data.importer import LogImportError
    from host.errors import UserError
    from host.outputs import Outputs

    if not os.path.isdir(args.into):
        raise UserError("--into %s: not a folder (a run folder to merge the sweeps into; make one with tcomp import or tcomp record)" % args.into)
    out = Outputs([args.errors, args.mapping])
    out.folder(args.into, "--into")
    if args.json:
        out.file(args.json, "--json")
    mapping, where = _mapping(args)
    with out:
        try:
            summary, _ = merge_into(args.into, args.errors, mapping, out.path(args.into), where, args.clock_offset)
        except LogImportError as exc:
            raise UserError(str(exc))
        print("%s -> %s: %d sweeps (%d points), clock aligned by %s, offset %.3f s; errors.csv %d -> %d rows"
              % (args.errors, args.into, summary["sweeps"], summary["rows"], summary["clock"]["aligned_by"], summary["clock"]["offset_s"],
                 summary["rows_before"], summary["rows_after"]))
        _print_reading(summary, summary["dialect"])
        if args.json:
            import json

            with out.open(args.json) as fh:
                json.dump(summary, fh, indent=2)
        out.commit()
    return 0


def _print_reading(record, dialect):
    """What the file was read as (detected or declared), and what the gap policy did: said, never silent."""
    d = dialect
    if d:
        names = {",": "comma", ";": "semicolon", "\t": "tab", ".": "point"}
        how = lambda k: "detected" if k in d["detected"] else "declared"  # noqa: E731
        print("  read as: cells split at %s (%s), decimal %s (%s)" % (names[d["delimiter"]], how("delimiter"),
                                                                       "comma" if d["decimal"] == "," else "point", how("decimal")))
    t = record.get("time")
    if t and "format" in t:
        print("  time: date-times (%s)%s, time_s counts from the first sample at %s" % (
            t["format"], ", clock %s" % t["timezone"] if "timezone" in t else ", offsets in the cells", t["start_time"]))
    g = record.get("gaps")
    if g and g["policy"] == "drop":
        print("  gaps: %d rows dropped (empty cells: %s)" % (g["rows_dropped"], ", ".join("%s %d" % kv for kv in g["empty_cells"].items())))
    elif g:
        print("  gaps: %d empty cells interpolated (%s)" % (sum(g["cells_interpolated"].values()),
                                                     ", ".join("%s %d" % kv for kv in g["cells_interpolated"].items())))


def _report(args, run_, out):
    import json

    t = run_.temperatures
    channels = run_.errors.channels() if run_.errors is not None else []
    print("%s -> %s: %d samples, %d temperatures, %d error channels, %.1f h"
          % (args.source, args.out, t.time_s.size, len(t.names), len(channels), (t.time_s[-1] - t.time_s[0]) / 3600))
    _print_reading(run_.meta["import"], run_.dialect)
    if run_.errors is None:
        print("  no error columns: errors.csv holds its header only (meta.json errors_pending) until an instrument's sweeps "
              "are merged (tcomp import --errors FILE --into %s)" % args.out)
    if not run_.meta.get("axis"):
        print("  no axis declared (--axis or the mapping's meta.axis); meta.json has none")
    if args.json:
        summary = {"out": args.out, "samples": int(t.time_s.size), "sensors": t.names, "channels": channels}
        summary["dialect"] = run_.dialect
        summary.update({k: run_.meta["import"][k] for k in ("time", "gaps") if k in run_.meta["import"]})
        with out.open(args.json) as fh:
            json.dump(summary, fh, indent=2)
