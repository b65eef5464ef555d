"""Plain CSV logs -> run folders (``tcomp import``).

A thermal-test logger usually writes one wide CSV: a time column, temperatures,
displacement channels, maybe spindle speed. A *mapping* says which column is
what; every source column must be either mapped or listed in ``ignore``, so a
misspelt or forgotten column is an error rather than silently lost data.

Mapping (JSON, or built from command-line flags)::

    {
      "time": "time_s",              # source column with the time
      "time_scale": 1.0,             # multiply to get seconds (60 for minutes)
      "temperatures": {"t1_C": {"name": "t1", "role": "structure", "location": "..."}},
      "errors": {"ch1_um": {"channel": "ch1", "position_mm": 0.0, "scale": 1.0}},
      "spindle": "spindle_rpm",      # optional
      "ignore": ["comment"],         # optional: source columns deliberately not imported
      "meta": {"axis": "Z", "notes": "..."}   # merged into meta.json
    }

``temperatures`` may also be a list of column names (name = column, role
``structure``) and ``errors`` a list (channel = column, position 0).
"""

from __future__ import annotations

from typing import Any
import json
import math
import os
from collections import Counter

import numpy as np

from host.data.runs import (ERROR_LIMIT_UM, FORMAT, START, ROLES, TEMPERATURE_RANGE_C, CsvSyntaxError, Errors, Run, RunFormatError,
                       Spindle, Temperatures, parse_number, read_records, write_run)


class LogImportError(ValueError):
    """A mapping or source file problem; the message names file, line and column."""


# A log's time, once scaled to seconds: Unix time (1.7e9 s) fits, and a thermal test lasts at most a year.
MAX_ABS_TIME_S = 1e10
MAX_DURATION_S = 366 * 86400.0


def _number(value, what, where):
    """A JSON number of the mapping; a string ("2.5") is refused: it is a quoted cell of a spreadsheet export,
    or a word, and reading it would guess."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise LogImportError("%s: %s must be a number, found %r%s" % (where, what, value,
                                                                    " (a string: write it without quotes)" if isinstance(value, str) else ""))
    try:
        v = float(value)
    except OverflowError:  # an integer of 400 digits
        v = math.inf
    if not math.isfinite(v):
        raise LogImportError("%s: %s must be a finite number, found %r" % (where, what, value))
    return v


def _columns(value, key, where):
    """'temperatures'/'errors' as {column: spec}; column names must be strings, specs objects."""
    if isinstance(value, list):
        dup = sorted({c for c in value if isinstance(c, str) and value.count(c) > 1})
        if dup:
            raise LogImportError("%s: '%s' lists column(s) %s more than once" % (where, key, ", ".join(dup)))
        value = {c: {} for c in value} if all(isinstance(c, str) for c in value) else value
    if isinstance(value, list):
        bad = [c for c in value if not isinstance(c, str)]
        raise LogImportError("%s: '%s' lists column names, which must be strings (found %r); write them as in the CSV header, in quotes"
                           % (where, key, bad[0]))
    if not isinstance(value, dict):
        raise LogImportError("%s: '%s' must be a list of column names or an object {column: settings}, found %s"
                           % (where, key, type(value).__name__))
    for col, spec in value.items():
        if spec is not None and not isinstance(spec, dict):
            raise LogImportError("%s: %s.%s must be an object of settings, found %r" % (where, key, col, spec))
    return value


def _normalise_mapping(mapping, where):
    if not isinstance(mapping, dict):
        raise LogImportError("%s: mapping must be a JSON object" % where)
    unknown = set(mapping) - {"time", "time_scale", "temperatures", "errors", "spindle", "ignore", "meta"}
    if unknown:
        raise LogImportError("%s: unknown mapping key(s) %s" % (where, ", ".join(sorted(unknown))))
    if "time" not in mapping:
        raise LogImportError("%s: mapping needs 'time' (the source column holding the time)" % where)
    if not isinstance(mapping["time"], str) or not mapping["time"]:
        raise LogImportError("%s: 'time' must be a column name (a string), found %r" % (where, mapping["time"]))
    spindle = mapping.get("spindle")
    if spindle is not None and not isinstance(spindle, str):
        raise LogImportError("%s: 'spindle' must be a column name (a string), found %r" % (where, spindle))
    ignore = mapping.get("ignore") or []
    if not isinstance(ignore, list) or not all(isinstance(c, str) for c in ignore):
        raise LogImportError("%s: 'ignore' must be a list of column names (strings), found %r" % (where, ignore))
    meta = mapping.get("meta") or {}
    if not isinstance(meta, dict):
        raise LogImportError("%s: 'meta' must be an object, found %r" % (where, meta))
    reserved = sorted(set(meta) & {"format", "sensors", "channels", "import"})
    if reserved:
        raise LogImportError("%s: 'meta' may not set %s (the importer writes them from the mapping)" % (where, ", ".join(reserved)))
    time_scale = _number(mapping.get("time_scale", 1.0), "time_scale", where)
    if time_scale <= 0:
        raise LogImportError("%s: time_scale must be > 0 (the factor from the time column to seconds), found %g" % (where, time_scale))
    temps = _columns(mapping.get("temperatures") or {}, "temperatures", where)
    errs = _columns(mapping.get("errors") or {}, "errors", where)
    if not temps:
        raise LogImportError("%s: mapping needs at least one temperature column" % where)
    if not errs:
        raise LogImportError("%s: mapping needs at least one error (displacement) column" % where)
    t_out = {}
    for col, spec in temps.items():
        spec = dict(spec or {})
        role = spec.get("role", "structure")
        if role not in ROLES:
            raise LogImportError("%s: temperature column %r has role %r; expected one of %s" % (where, col, role, ", ".join(ROLES)))
        name = spec.get("name", col)
        if not isinstance(name, str) or not name:
            raise LogImportError("%s: temperatures.%s.name must be a non-empty string, found %r" % (where, col, name))
        t_out[col] = {"name": name, "role": role, "location": spec.get("location", "")}
    names = [s["name"] for s in t_out.values()]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise LogImportError("%s: sensor name(s) used twice: %s" % (where, ", ".join(dup)))
    e_out = {}
    for col, spec in errs.items():
        spec = dict(spec or {})
        channel = spec.get("channel", col)
        if not isinstance(channel, str) or not channel:
            raise LogImportError("%s: errors.%s.channel must be a non-empty string, found %r" % (where, col, channel))
        e_out[col] = {
            "channel": channel,
            "position_mm": _number(spec.get("position_mm", 0.0), "errors.%s.position_mm" % col, where),
            "scale": _number(spec.get("scale", 1.0), "errors.%s.scale" % col, where),
        }
        if e_out[col]["scale"] == 0:
            raise LogImportError("%s: errors.%s.scale is 0: every error would read 0 um (the factor from the column to um, "
                               "1 when it is in um, 1000 for mm, -1 for a probe measuring the other way)" % (where, col))
    roles = [("time", mapping["time"])] + [("temperatures", c) for c in t_out] + [("errors", c) for c in e_out]
    roles += [("spindle", spindle)] if spindle else []
    roles += [("ignore", c) for c in ignore]
    cols = [c for _, c in roles]
    for col in sorted({c for c in cols if cols.count(c) > 1}):
        raise LogImportError("%s: column %r is mapped more than once (as %s); each source column has one meaning"
                           % (where, col, " and ".join(r for r, c in roles if c == col)))
    chans = [e["channel"] for e in e_out.values()]
    dup = sorted({c for c in chans if chans.count(c) > 1})
    if dup:
        raise LogImportError("%s: error channel name(s) used twice: %s" % (where, ", ".join(dup)))
    return {
        "time": mapping["time"],
        "time_scale": time_scale,
        "temperatures": t_out,
        "errors": e_out,
        "spindle": spindle,
        "ignore": list(ignore),
        "meta": dict(meta),
    }


def _check_ranges(source, m, used, data):
    """The run format's plausibility ranges (host/data/runs.py), named by source line and column before anything is written."""
    lo, hi = TEMPERATURE_RANGE_C
    checks = [(c, 1.0, lo, hi, "degC, the range of a Pt100 (IEC 60751)") for c in m["temperatures"]]
    checks += [(c, m["errors"][c]["scale"], -ERROR_LIMIT_UM, ERROR_LIMIT_UM, "um once scaled: no feed axis grows that much")
               for c in m["errors"]]
    problems = []
    for col, scale, lo, hi, why in checks:
        values = data[:, used.index(col)]
        for i in np.flatnonzero(~((values * scale >= lo) & (values * scale <= hi)))[:10]:
            problems.append("%s line %d column %r: %g is outside %g..%g %s (a logger fault or a wrong unit?)"
                            % (source, i + 2, col, values[i], lo, hi, why))
    if problems:
        raise LogImportError("\n".join(problems))


def _shortened(header, n=20):
    return ",".join(header) if len(header) <= n else "%s,... (%d columns)" % (",".join(header[:n]), len(header))


def import_csv(source: str, mapping: dict[str, Any], mapping_where: str = "mapping") -> Run:
    """Read ``source`` (CSV path) with ``mapping``; return a Run (not yet written)."""
    m = _normalise_mapping(mapping, mapping_where)
    try:
        # utf-8-sig: spreadsheet programs (Excel) start a UTF-8 CSV with a byte-order mark
        with open(source, newline="", encoding="utf-8-sig") as fh:
            records = read_records(fh, source)
    except UnicodeDecodeError as exc:
        raise LogImportError("%s: not a UTF-8 text CSV (byte %d cannot be decoded); save the log as CSV (UTF-8)" % (source, exc.start))
    except OSError as exc:
        raise LogImportError("%s: cannot be read (%s)" % (source, exc.strerror or exc))
    except CsvSyntaxError as exc:
        raise LogImportError(str(exc))
    rows = [r for _, r in records]
    if not rows:
        raise LogImportError("%s line 1: file is empty" % source)
    header = [h.strip() for h in rows[0]]
    dup = sorted(c for c, k in Counter(header).items() if k > 1)
    if dup:
        raise LogImportError("%s line 1: column name(s) %s appear more than once in the header; rename them in the source"
                           % (source, ", ".join(repr(h) for h in dup)))
    used = [m["time"]] + list(m["temperatures"]) + list(m["errors"]) + ([m["spindle"]] if m["spindle"] else [])
    problems = []
    known, named = set(header), set(used + m["ignore"])
    for col in used + m["ignore"]:
        if col not in known:
            problems.append("%s line 1: mapped column %r is not in the header (%s)" % (source, col, _shortened(header)))
    for col in header:
        if col not in named:
            problems.append("%s line 1: column %r is neither mapped nor listed in 'ignore'" % (source, col))
            if len(problems) > 50:
                problems.append("... (stopped after 50 problems)")
                break
    if problems:
        raise LogImportError("\n".join(problems))
    idx = {c: header.index(c) for c in used}
    data = np.empty((len(rows) - 1, len(used)))
    for k, (lineno, row) in enumerate(records[1:]):
        if len(row) != len(header):
            problems.append("%s line %d: has %d cells, header has %d" % (source, lineno, len(row), len(header)))
            continue
        for j, col in enumerate(used):
            cell = row[idx[col]].strip()
            try:
                v = parse_number(cell)
            except ValueError:
                problems.append("%s line %d column %r: not a number: %r" % (source, lineno, col, cell))
                continue
            if not math.isfinite(v):
                problems.append("%s line %d column %r: %r is not a finite number" % (source, lineno, col, cell))
            data[k, j] = v
        if len(problems) > 50:
            problems.append("... (stopped after 50 problems)")
            break
    if problems:
        raise LogImportError("\n".join(problems))
    if data.shape[0] == 0:
        raise LogImportError("%s: no data rows after the header" % source)
    with np.errstate(over="ignore"):  # an overflow to inf is refused below, by name
        time_s = data[:, 0] * m["time_scale"]
    far = np.flatnonzero(~(np.abs(time_s) <= MAX_ABS_TIME_S))
    if far.size:
        i = far[0]
        raise LogImportError("%s line %d column %r: %g x time_scale %g = %g s is beyond +-%g s (a wrong time_scale?)"
                           % (source, records[1 + i][0], m["time"], data[i, 0], m["time_scale"], time_s[i], MAX_ABS_TIME_S))
    if time_s[-1] - time_s[0] > MAX_DURATION_S:
        raise LogImportError("%s: the log spans %g s once scaled by time_scale %g, more than a year (%g s): a wrong time_scale?"
                           % (source, time_s[-1] - time_s[0], m["time_scale"], MAX_DURATION_S))
    back = np.flatnonzero(np.diff(time_s) <= 0)
    if back.size:
        raise LogImportError(
            "\n".join("%s line %d column %r: time goes backwards or repeats (%g after %g)" % (source, i + 3, m["time"], data[i + 1, 0], data[i, 0]) for i in back[:20])
        )
    _check_ranges(source, m, used, data)
    tcols = list(m["temperatures"])
    tvals = data[:, [used.index(c) for c in tcols]]
    temps = Temperatures(time_s, [m["temperatures"][c]["name"] for c in tcols], tvals)
    n = time_s.size
    ecols = list(m["errors"])
    err_time = np.repeat(time_s, len(ecols))
    err_pos = np.tile([m["errors"][c]["position_mm"] for c in ecols], n)
    err_val = (data[:, [used.index(c) for c in ecols]] * np.array([m["errors"][c]["scale"] for c in ecols])).reshape(-1)
    # The channel column is kept even for one channel: it records which probe it was.
    channel = np.tile(np.array([m["errors"][c]["channel"] for c in ecols], dtype=object), n)
    errors = Errors(err_time, err_pos, err_val, None, channel)
    spindle = None
    if m["spindle"]:
        spindle = Spindle(time_s, data[:, used.index(m["spindle"])])
    meta = {"format": FORMAT, "axis": m["meta"].pop("axis", "Z")}
    meta["sensors"] = {
        s["name"]: {"role": s["role"], "location": s["location"] or "not documented in the source"} for s in m["temperatures"].values()
    }
    meta["channels"] = {s["channel"]: {"source_column": c, "position_mm": s["position_mm"], "scale": s["scale"]} for c, s in m["errors"].items()}
    meta["import"] = {"source": os.path.basename(source), "rows": int(n), "ignored_columns": m["ignore"]}
    meta.update(m["meta"])
    ref = meta.get("error_reference", START)
    if not (ref == START or (isinstance(ref, str) and ref in meta["sensors"])):
        raise LogImportError("%s: error_reference %s is neither \"start\" (raw errors relative to the machine at the run's start) "
                           "nor one of the imported sensors (%s) the errors were corrected to"
                           % (mapping_where, json.dumps(ref), ", ".join(meta["sensors"])))
    name = os.path.splitext(os.path.basename(source))[0]
    return Run(meta, temps, errors, None, spindle, name=name)


def import_to_folder(source: str, mapping: dict[str, Any], out: str, mapping_where: str = "mapping") -> Run:
    run = import_csv(source, mapping, mapping_where)
    write_run(run, out, decimals=6)
    # Round-trip through the loader so a written folder is always a valid run.
    from host.data.runs import load_run

    try:
        load_run(out)
    except RunFormatError as exc:  # pragma: no cover - would be a bug in write_run
        raise LogImportError("imported run does not validate:\n%s" % exc)
    return run
