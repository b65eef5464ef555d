"""Logger and instrument CSV exports -> run folders and error sweeps (``tcomp import``).

A *mapping* says what each source column is; every source column must be mapped or listed in ``ignore``,
so a misspelt or forgotten column is an error rather than silently lost data. docs/data-format.md
("Importing logs and instrument files") documents every key with a worked example per layout;
``data/fl_thermal_mapping.json`` and ``examples/import/`` are complete mappings.

Two layouts:

- ``"wide"`` (the default): one row per sample time, columns for the time, temperatures, displacement
  channels and maybe spindle speed (a thermal-test logger). ``import_csv`` -> a Run.
- ``"long"``: one row per measured point of a positioning sweep, columns time, target position, error
  and maybe direction and run number (what ISO 230-2 laser software exports). ``import_errors`` -> Errors
  of one sweep per (run, direction), for host/data/merge.py to merge into a run by time.

Units are declared per column, never guessed: a column whose name says another unit than the default
(``ch1_mm`` with no ``unit``) is refused naming the column and the unit to declare.
"""

from __future__ import annotations

from typing import Any, cast
import json
import math
import os
import re
from collections import Counter

import numpy as np

from host.data import logfile
from host.data.logfile import AUTO, ISO8601, MAX_PROBLEMS, LogFileError
from host.data.runs import ERROR_LIMIT_UM, FORMAT, ROLES, START, TEMPERATURE_RANGE_C, Errors, Run, RunFormatError, Spindle, Temperatures, write_run


class LogImportError(ValueError):
    """A mapping or source file problem; the message names file, line and column."""


# A log's time, once scaled to seconds: Unix time (1.7e9 s) fits, and a thermal test lasts at most a year.
MAX_ABS_TIME_S = 1e10
MAX_DURATION_S = 366 * 86400.0

GAP_POLICIES = ("refuse", "drop", "interpolate")
LAYOUTS = ("wide", "long")

# Units a column may declare, each with its conversion to the run format's unit (errors um, positions mm,
# time s, temperatures degC). Spellings with a degree or micro sign are the same units.
ERROR_UNITS = {"um": 1.0, "mm": 1000.0, "in": 25400.0}
POSITION_UNITS = {"mm": 1.0, "um": 0.001, "in": 25.4}
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0}
TEMPERATURE_UNITS = {"degC": (1.0, 0.0), "K": (1.0, -273.15), "degF": (5.0 / 9.0, -32.0 * 5.0 / 9.0)}  # degC = a * v + b
_ALIASES = {"µm": "um", "μm": "um", "°C": "degC", "C": "degC", "°F": "degF", "F": "degF"}
# The unit a column's name states, read from its last word ("ch1_mm", "Error (µm)", "T1 [°F]", "time_min").
_NAME_UNITS = {
    "error": {"mm": "mm", "um": "um", "µm": "um", "μm": "um", "micron": "um", "microns": "um", "in": "in", "inch": "in", "inches": "in"},
    "position": {"mm": "mm", "um": "um", "µm": "um", "μm": "um", "in": "in", "inch": "in", "inches": "in"},
    "temperature": {"c": "degC", "degc": "degC", "°c": "degC", "k": "K", "kelvin": "K", "f": "degF", "degf": "degF", "°f": "degF"},
    "time": {"s": "s", "sec": "s", "secs": "s", "seconds": "s", "min": "min", "mins": "min", "minutes": "min",
             "h": "h", "hr": "h", "hrs": "h", "hours": "h"},
}
DEFAULT_UNIT = {"error": "um", "position": "mm", "temperature": "degC", "time": "s"}
_UNITS = {"error": ERROR_UNITS, "position": POSITION_UNITS, "temperature": TEMPERATURE_UNITS, "time": TIME_UNITS}

_COMMON_KEYS = {"layout", "header_line", "delimiter", "decimal", "time", "time_scale", "time_unit", "time_format", "timezone", "gaps", "ignore", "meta"}
_WIDE_KEYS = _COMMON_KEYS | {"temperatures", "errors", "spindle"}
_LONG_KEYS = _COMMON_KEYS | {"position", "error", "direction", "sweep", "channel"}


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


def _unit(kind, declared, col, where, what):
    """The declared unit of ``col`` (canonical spelling), or the default when none is declared and the column's
    name does not state another one; LogImportError naming the column and the unit to declare otherwise."""
    if declared is not None:
        unit = _ALIASES.get(declared, declared) if isinstance(declared, str) else declared
        if not isinstance(unit, str) or unit not in _UNITS[kind]:
            raise LogImportError("%s: %s unit %r of column %r: expected one of %s" % (where, what, declared, col, ", ".join(_UNITS[kind])))
        return unit
    words = re.findall(r"[0-9A-Za-zµμ°]+", col)
    said = _NAME_UNITS[kind].get(words[-1].lower()) if len(words) > 1 else None
    if said is not None and said != DEFAULT_UNIT[kind]:
        raise LogImportError("%s: %s column %r has no declared unit, and its name says %s (without one it would be read as %s); "
                             "declare it: \"unit\": \"%s\" (or \"%s\" if the name is wrong)"
                             % (where, what, col, said, DEFAULT_UNIT[kind], said, DEFAULT_UNIT[kind]))
    return DEFAULT_UNIT[kind]


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


def _column_name(value, key, where):
    if not isinstance(value, str) or not value:
        raise LogImportError("%s: '%s' must be a column name (a string), found %r" % (where, key, value))
    return value


def _normalise_common(mapping, where, keys):
    """The keys both layouts share: dialect, time, gaps, ignore, meta."""
    if not isinstance(mapping, dict):
        raise LogImportError("%s: mapping must be a JSON object" % where)
    layout = mapping.get("layout", "wide")
    if layout not in LAYOUTS:
        raise LogImportError("%s: 'layout' is %r; expected \"wide\" (one row per sample time) or \"long\" (one row per measured "
                             "point of a sweep)" % (where, layout))
    unknown = set(mapping) - keys
    if unknown:
        raise LogImportError("%s: unknown mapping key(s) %s for the %s layout" % (where, ", ".join(sorted(unknown)), layout))
    if "time" not in mapping:
        raise LogImportError("%s: mapping needs 'time' (the source column holding the time)" % where)
    if not isinstance(mapping["time"], str) or not mapping["time"]:
        raise LogImportError("%s: 'time' must be a column name (a string), found %r" % (where, mapping["time"]))
    ignore = mapping.get("ignore") or []
    if not isinstance(ignore, list) or not all(isinstance(c, str) for c in ignore):
        raise LogImportError("%s: 'ignore' must be a list of column names (strings), found %r" % (where, ignore))
    meta = mapping.get("meta") or {}
    if not isinstance(meta, dict):
        raise LogImportError("%s: 'meta' must be an object, found %r" % (where, meta))
    reserved = sorted(set(meta) & {"format", "sensors", "channels", "import", "error_imports", "errors_pending"})
    if reserved:
        raise LogImportError("%s: 'meta' may not set %s (the importer writes them from the mapping)" % (where, ", ".join(reserved)))
    try:
        delimiter = logfile.delimiter_of(mapping.get("delimiter", AUTO), where)
        decimal = logfile.decimal_of(mapping.get("decimal", AUTO), where)
    except LogFileError as exc:
        raise LogImportError(str(exc))
    header_line = mapping.get("header_line", 1)
    if isinstance(header_line, bool) or not isinstance(header_line, int) or header_line < 1:
        raise LogImportError("%s: 'header_line' must be the line number (1 = first) of the column names, found %r" % (where, header_line))
    gaps = mapping.get("gaps", "refuse")
    if gaps not in GAP_POLICIES:
        raise LogImportError("%s: 'gaps' is %r; expected \"refuse\" (the default: an empty cell is an error), \"drop\" (the row) "
                             "or \"interpolate\" (linearly in time, from the neighbouring samples)" % (where, gaps))
    time_format = mapping.get("time_format")
    if time_format is not None:
        if not isinstance(time_format, str) or not (time_format == ISO8601 or "%" in time_format):
            raise LogImportError("%s: 'time_format' is %r; expected \"iso8601\" or a strptime format such as \"%%d.%%m.%%Y %%H:%%M:%%S\""
                                 % (where, time_format))
        for k in ("time_scale", "time_unit"):
            if k in mapping:
                raise LogImportError("%s: '%s' and 'time_format' both given: date-times are converted to seconds, "
                                     "a scale or unit does not apply" % (where, k))
    elif "timezone" in mapping:
        raise LogImportError("%s: 'timezone' applies to date-times only; give 'time_format' too, or remove it" % where)
    if "time_scale" in mapping and "time_unit" in mapping:
        raise LogImportError("%s: give 'time_unit' or 'time_scale', not both (each sets the factor to seconds)" % where)
    time_scale = _number(mapping.get("time_scale", 1.0), "time_scale", where)
    if time_scale <= 0:
        raise LogImportError("%s: time_scale must be > 0 (the factor from the time column to seconds), found %g" % (where, time_scale))
    time_unit = None
    if time_format is None and "time_scale" not in mapping:
        time_unit = _unit("time", mapping.get("time_unit"), mapping["time"], where, "time")
        time_scale = TIME_UNITS[time_unit]
    return {
        "layout": layout, "header_line": header_line, "delimiter": delimiter, "decimal": decimal, "gaps": gaps,
        "time": mapping["time"], "time_scale": time_scale, "time_unit": time_unit,
        "time_format": time_format, "timezone": mapping.get("timezone"),
        "ignore": list(ignore), "meta": dict(meta),
    }


def _normalise_wide(mapping, where, temperatures=True):
    """The wide layout; ``temperatures=False`` for an error file merged into a run that has its own."""
    m = _normalise_common(mapping, where, _WIDE_KEYS)
    spindle = mapping.get("spindle")
    if spindle is not None and not isinstance(spindle, str):
        raise LogImportError("%s: 'spindle' must be a column name (a string), found %r" % (where, spindle))
    temps = _columns(mapping.get("temperatures") or {}, "temperatures", where)
    errs = _columns(mapping.get("errors") or {}, "errors", where)
    if temps and not temperatures:
        raise LogImportError("%s: --errors merges error sweeps into a run that has its temperatures; this mapping maps temperature "
                             "columns too (import such a log with --out)" % where)
    if not temps and temperatures:
        raise LogImportError("%s: mapping needs at least one temperature column" % where)
    if not errs and not temperatures:
        raise LogImportError("%s: mapping needs at least one error (displacement) column" % where)
    t_out = {}
    for col, spec in temps.items():
        spec = dict(spec or {})
        unknown = set(spec) - {"name", "role", "location", "unit"}
        if unknown:
            raise LogImportError("%s: temperatures.%s: unknown key(s) %s (name, role, location, unit)" % (where, col, ", ".join(sorted(unknown))))
        role = spec.get("role", "structure")
        if role not in ROLES:
            raise LogImportError("%s: temperature column %r has role %r; expected one of %s" % (where, col, role, ", ".join(ROLES)))
        name = spec.get("name", col)
        if not isinstance(name, str) or not name:
            raise LogImportError("%s: temperatures.%s.name must be a non-empty string, found %r" % (where, col, name))
        location = spec.get("location")
        if location is not None and not isinstance(location, str):
            raise LogImportError("%s: temperatures.%s.location must be text, found %r" % (where, col, location))
        t_out[col] = {"name": name, "role": role, "location": location,
                      "unit": _unit("temperature", spec.get("unit"), col, where, "temperature"), "declared": "unit" in spec}
    names = [s["name"] for s in t_out.values()]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise LogImportError("%s: sensor name(s) used twice: %s" % (where, ", ".join(dup)))
    e_out = {}
    for col, spec in errs.items():
        spec = dict(spec or {})
        unknown = set(spec) - {"channel", "position_mm", "scale", "unit"}
        if unknown:
            raise LogImportError("%s: errors.%s: unknown key(s) %s (channel, position_mm, unit, scale)" % (where, col, ", ".join(sorted(unknown))))
        channel = spec.get("channel", col)
        if not isinstance(channel, str) or not channel:
            raise LogImportError("%s: errors.%s.channel must be a non-empty string, found %r" % (where, col, channel))
        e_out[col] = {"channel": channel, "position_mm": _number(spec.get("position_mm", 0.0), "errors.%s.position_mm" % col, where)}
        e_out[col].update(_error_factor(spec, col, where, "errors.%s" % col))
    roles = [("time", m["time"])] + [("temperatures", c) for c in t_out] + [("errors", c) for c in e_out]
    roles += [("spindle", spindle)] if spindle else []
    _check_roles(roles, m["ignore"], where)
    chans = [e["channel"] for e in e_out.values()]
    dup = sorted({c for c in chans if chans.count(c) > 1})
    if dup:
        raise LogImportError("%s: error channel name(s) used twice: %s" % (where, ", ".join(dup)))
    m.update(temperatures=t_out, errors=e_out, spindle=spindle)
    return m


def _error_factor(spec, col, where, what):
    """{"scale": factor to um, "unit": declared unit or None}. Without a unit, ``scale`` is the factor to um (1000 for mm,
    -1 for a probe measuring the other way), as before units existed; with one, ``scale`` is only the sign."""
    scale = _number(spec.get("scale", 1.0), "%s.scale" % what, where)
    if scale == 0:
        raise LogImportError("%s: %s.scale is 0: every error would read 0 um (the factor from the column to um, "
                             "1 when it is in um, 1000 for mm, -1 for a probe measuring the other way)" % (where, what))
    if "unit" in spec:
        if abs(scale) != 1:
            raise LogImportError("%s: %s has a unit (%r) and scale %g: the unit converts already; with a unit, scale is only "
                                 "the sign (+1, or -1 for a probe measuring the other way)" % (where, what, spec["unit"], scale))
        unit = _unit("error", spec["unit"], col, where, "error")
        return {"scale": ERROR_UNITS[unit] * scale, "unit": unit}
    if scale in (1.0, -1.0):
        _unit("error", None, col, where, "error")  # a name stating mm, with no factor, is refused
    return {"scale": scale, "unit": None}


def _check_roles(roles, ignore, where):
    roles = roles + [("ignore", c) for c in ignore]
    cols = [c for _, c in roles]
    for col in sorted({c for c in cols if cols.count(c) > 1}):
        raise LogImportError("%s: column %r is mapped more than once (as %s); each source column has one meaning"
                           % (where, col, " and ".join(r for r, c in roles if c == col)))


def _normalise_long(mapping, where):
    m = _normalise_common(mapping, where, _LONG_KEYS)
    for key in ("position", "error"):
        if key not in mapping:
            raise LogImportError("%s: a long layout needs '%s' ({\"column\": ..., \"unit\": ...})" % (where, key))
    pos, err = mapping["position"], mapping["error"]
    for key, spec, allowed in (("position", pos, {"column", "unit"}), ("error", err, {"column", "unit", "scale"})):
        if not isinstance(spec, dict) or "column" not in spec:
            raise LogImportError("%s: '%s' must be an object {\"column\": ..., \"unit\": ...}, found %r" % (where, key, spec))
        unknown = set(spec) - allowed
        if unknown:
            raise LogImportError("%s: %s: unknown key(s) %s (%s)" % (where, key, ", ".join(sorted(unknown)), ", ".join(sorted(allowed))))
        _column_name(spec["column"], key + ".column", where)
    pos_unit = _unit("position", pos.get("unit"), pos["column"], where, "position")
    direction = mapping.get("direction")
    d_out = None
    if direction is not None:
        if isinstance(direction, str):
            direction = {"column": direction}
        if not isinstance(direction, dict) or "column" not in direction or set(direction) - {"column", "values"}:
            raise LogImportError("%s: 'direction' must be a column name or {\"column\": ..., \"values\": {cell: +1 or -1}}, found %r"
                                 % (where, mapping["direction"]))
        values = direction.get("values", {"1": 1, "+1": 1, "-1": -1})
        if not isinstance(values, dict) or not values or any(v not in (1, -1) or isinstance(v, bool) for v in values.values()):
            raise LogImportError("%s: direction.values must map each cell text to +1 or -1, e.g. {\"Forward\": 1, \"Reverse\": -1}, found %r"
                                 % (where, values))
        d_out = {"column": _column_name(direction["column"], "direction.column", where), "values": {str(k): int(v) for k, v in values.items()}}
    sweep = mapping.get("sweep")
    if sweep is not None:
        _column_name(sweep, "sweep", where)
    channel = mapping.get("channel")
    if channel is not None and (not isinstance(channel, str) or not channel):
        raise LogImportError("%s: 'channel' must be a non-empty name for errors.csv's channel column, found %r" % (where, channel))
    roles = [("time", m["time"]), ("position", pos["column"]), ("error", err["column"])]
    roles += [("direction", d_out["column"])] if d_out else []
    roles += [("sweep", sweep)] if sweep else []
    _check_roles(roles, m["ignore"], where)
    m.update(position={"column": pos["column"], "unit": pos_unit, "factor": POSITION_UNITS[pos_unit]},
             error=dict(column=err["column"], **_error_factor(err, err["column"], where, "error")),
             direction=d_out, sweep=sweep, channel=channel)
    return m


# ------------------------------------------------------------------ reading the cells


def _shortened(header, n=20):
    return ",".join(header) if len(header) <= n else "%s,... (%d columns)" % (",".join(header[:n]), len(header))


def _check_header(table, m, used):
    source, header = table.source, table.header
    dup = sorted(c for c, k in Counter(header).items() if k > 1)
    if dup:
        raise LogImportError("%s line %d: column name(s) %s appear more than once in the header; rename them in the source"
                             % (source, table.header_line, ", ".join(repr(h) for h in dup)))
    problems = []
    known, named = set(header), set(used + m["ignore"])
    for col in used + m["ignore"]:
        if col not in known:
            hint = ""
            if len(header) == 1 and table.delimiter == ",":
                hint = " (the header is one cell: is the file ';'- or tab-separated? declare \"delimiter\")"
            problems.append("%s line %d: mapped column %r is not in the header (%s)%s" % (source, table.header_line, col, _shortened(header), hint))
            if hint:
                break
    for col in header:
        if col not in named:
            problems.append("%s line %d: column %r is neither mapped nor listed in 'ignore'" % (source, table.header_line, col))
            if len(problems) > MAX_PROBLEMS:
                problems.append("... (stopped after %d problems)" % MAX_PROBLEMS)
                break
    if problems:
        raise LogImportError("\n".join(problems))


_DATE_TIME = re.compile(r"[0-9]{1,4}[-./][0-9]{1,2}[-./][0-9]{1,4}|[0-9]{1,2}:[0-9]{2}")


class _Cells:
    """The mapped columns of a table: numbers (NaN where a cell is empty), texts, timestamps, with their line numbers."""

    def __init__(self, table, m, numeric, text=()):
        source, header = table.source, table.header
        idx = {c: header.index(c) for c in list(numeric) + list(text) + [m["time"]]}
        stamps = m["time_format"] is not None
        numeric = ([] if stamps else [m["time"]]) + list(numeric)
        problems, lines, rows, texts, times, time_gap = [], [], [], [], [], []
        for lineno, row in table.records:
            if len(row) != len(header):
                problems.append("%s line %d: has %d cells, header has %d" % (source, lineno, len(row), len(header)))
            else:
                vals = []
                for col in numeric:
                    try:
                        v = logfile.number(row[idx[col]], table.decimal, "%s line %d column %r" % (source, lineno, col))
                    except LogFileError as exc:
                        if col == m["time"] and _DATE_TIME.match(row[idx[col]].strip()):
                            # one message, not one per row: the whole column is date-times
                            raise LogImportError("%s; the time column holds date-times: declare \"time_format\" (\"iso8601\", or a "
                                                 "strptime format such as \"%%d.%%m.%%Y %%H:%%M:%%S\"; --time-format)" % exc)
                        problems.append(str(exc))
                        v = None
                    vals.append(math.nan if v is None else v)
                lines.append(lineno)
                rows.append(vals)
                texts.append([row[idx[c]].strip() for c in text])
                if stamps:
                    cell = row[idx[m["time"]]].strip()
                    time_gap.append(not cell)
                    stamp = None
                    if cell:
                        try:
                            stamp = logfile.parse_timestamp(cell, m["time_format"], "%s line %d column %r" % (source, lineno, m["time"]))
                        except LogFileError as exc:
                            problems.append(str(exc))
                    times.append(stamp)
            if len(problems) > MAX_PROBLEMS:
                problems.append("... (stopped after %d problems)" % MAX_PROBLEMS)
                break
        if problems:
            raise LogImportError("\n".join(problems))
        if not lines:
            raise LogImportError("%s: no data rows after the header" % source)
        self.source, self.columns, self.text_columns, self.time_column = source, numeric, list(text), m["time"]
        self.lines = np.asarray(lines)
        self.values = np.asarray(rows, dtype=float).reshape(len(lines), len(numeric))
        self.texts = texts
        self.stamps = times if stamps else None
        self.time_gap = np.asarray(time_gap if stamps else np.isnan(self.values[:, 0]), dtype=bool)

    def gaps(self):
        """(row, column) of every empty cell among the mapped columns, time first."""
        out = [(i, self.time_column) for i in np.flatnonzero(self.time_gap)]
        start = 0 if self.stamps is not None else 1
        for j, col in enumerate(self.columns[start:], start):
            out += [(i, col) for i in np.flatnonzero(np.isnan(self.values[:, j]))]
        for j, col in enumerate(self.text_columns):
            out += [(i, col) for i, t in enumerate(self.texts) if not t[j]]
        return sorted(out)

    def keep(self, rows):
        self.lines, self.values = self.lines[rows], self.values[rows]
        self.texts = [self.texts[i] for i in np.flatnonzero(rows)]
        if self.stamps is not None:
            self.stamps = [self.stamps[i] for i in np.flatnonzero(rows)]
        self.time_gap = self.time_gap[rows]

    def column(self, col):
        return self.values[:, self.columns.index(col)]

    def text(self, col):
        return [t[self.text_columns.index(col)] for t in self.texts]


def _where(cells, i, col):
    return "%s line %d column %r" % (cells.source, cells.lines[i], col)


def _apply_gaps(cells, m, where):
    """Apply the declared gap policy; returns what it did (for meta.json and the summary)."""
    gaps = cells.gaps()
    if not gaps:
        return None
    policy = m["gaps"]
    if policy == "refuse":
        shown = ["%s: empty cell (a gap); the mapping's \"gaps\" is \"refuse\" (the default): declare \"drop\" (the row) or "
                 "\"interpolate\" (from the neighbouring samples) to import it" % _where(cells, i, c) for i, c in gaps[:MAX_PROBLEMS]]
        if len(gaps) > MAX_PROBLEMS:
            shown.append("... and %d more empty cells" % (len(gaps) - MAX_PROBLEMS))
        raise LogImportError("\n".join(shown))
    counts = Counter(c for _, c in gaps)
    if policy == "drop":
        bad = sorted({i for i, _ in gaps})
        keep = np.ones(len(cells.lines), dtype=bool)
        keep[bad] = False
        lines = [int(cells.lines[i]) for i in bad]
        if not keep.any():
            raise LogImportError("%s: every row has an empty cell; \"gaps\": \"drop\" would leave nothing" % cells.source)
        cells.keep(keep)
        return {"policy": "drop", "rows_dropped": len(bad), "empty_cells": dict(counts), "lines": lines[:20]}
    # interpolate: only numbers between two samples; a gap in the time, a text column, or at either end cannot be.
    for i, c in gaps:
        if c == m["time"] or c in cells.text_columns:
            raise LogImportError("%s: empty cell in the %s column; \"gaps\": \"interpolate\" fills numbers between samples, "
                                 "not %s (declare \"drop\" to drop such rows)" % (_where(cells, i, c), "time" if c == m["time"] else "text",
                                                                                 "times" if c == m["time"] else "labels"))
    return {"policy": "interpolate", "cells_interpolated": dict(counts), "lines": sorted({int(cells.lines[i]) for i, _ in gaps})[:20]}


def _interpolate(cells, time_s):
    """Fill the empty numeric cells linearly in time; a gap at the first or last sample has one neighbour only and is refused."""
    for j, col in enumerate(cells.columns):
        v = cells.values[:, j]
        bad = np.isnan(v)
        if not bad.any():
            continue
        first, last = np.flatnonzero(~bad)[[0, -1]] if (~bad).any() else (len(v), -1)
        ends = np.flatnonzero(bad & ((np.arange(len(v)) < first) | (np.arange(len(v)) > last)))
        if ends.size:
            raise LogImportError("%s: empty cell before the first or after the last value of the column; \"gaps\": \"interpolate\" "
                                 "needs a sample on each side (declare \"drop\")" % _where(cells, ends[0], col))
        v[bad] = np.interp(time_s[bad], time_s[~bad], v[~bad])


def _time_s(cells, m):
    """Seconds of each row: the time column x its unit, as is; date-times relative to the first sample.
    Returns (time_s, start_time): start_time the first sample's ISO 8601 UTC date-time, or None."""
    source, col = cells.source, m["time"]
    start = None
    if cells.stamps is not None:
        wheres = ["%s line %d column %r" % (source, ln, col) for ln in cells.lines]
        try:
            secs, start = logfile.seconds_since_first(cells.stamps, wheres, m["timezone"], "%s (mapping)" % m["where"])
        except LogFileError as exc:
            raise LogImportError(str(exc))
        time_s, raw = np.asarray(secs, dtype=float), np.asarray(secs, dtype=float)
    else:
        raw = cells.column(col)
        with np.errstate(over="ignore"):  # an overflow to inf is refused below, by name
            time_s = raw * m["time_scale"]
    far = np.flatnonzero(~(np.abs(time_s) <= MAX_ABS_TIME_S))
    if far.size:
        i = far[0]
        raise LogImportError("%s line %d column %r: %g x time_scale %g = %g s is beyond +-%g s (a wrong time_scale?)"
                             % (source, cells.lines[i], col, raw[i], m["time_scale"], time_s[i], MAX_ABS_TIME_S))
    if time_s[-1] - time_s[0] > MAX_DURATION_S:
        raise LogImportError("%s: the log spans %g s once scaled by time_scale %g, more than a year (%g s): a wrong time_scale?"
                             % (source, time_s[-1] - time_s[0], m["time_scale"], MAX_DURATION_S))
    return time_s, raw, start



def _read_cells(source, m, numeric, mapping_where):
    """The mapped cells of ``source`` with the declared gap policy applied, in time order -> (table, cells, gaps, time_s,
    start): gaps as _apply_gaps counts them, start the date-time of the first sample (None for
    numeric times)."""
    table = _read(source, m, numeric)
    cells = _Cells(table, m, numeric)
    gaps = _apply_gaps(cells, m, mapping_where)
    time_s, raw, start = _time_s(cells, m)
    _check_time_order(cells, m, time_s, raw, strict=True)
    if gaps is not None and gaps["policy"] == "interpolate":
        _interpolate(cells, time_s)
    return table, cells, gaps, time_s, start

def _check_time_order(cells, m, time_s, raw, strict):
    back = np.flatnonzero(np.diff(time_s) <= 0 if strict else np.diff(time_s) < 0)
    if back.size:
        shown = [(cells.stamps[i + 1].isoformat(sep=" "), cells.stamps[i].isoformat(sep=" ")) if cells.stamps is not None
                 else ("%g" % raw[i + 1], "%g" % raw[i]) for i in back[:20]]
        raise LogImportError("\n".join("%s line %d column %r: time goes backwards%s (%s after %s)"
                                       % (cells.source, cells.lines[i + 1], m["time"], " or repeats" if strict else "", a, b)
                                       for i, (a, b) in zip(back[:20], shown)))


def _out_of_range(cells, col, converted, lo, hi, why):
    """Messages for the first ten cells of ``col`` whose converted value lies outside lo..hi, naming the raw cell."""
    raw = cells.column(col)
    return ["%s line %d column %r: %g is outside %g..%g %s (a logger fault or a wrong unit?)"
            % (cells.source, cells.lines[i], col, raw[i], lo, hi, why)
            for i in np.flatnonzero(~((converted >= lo) & (converted <= hi)))[:10]]


def _check_ranges(checks):
    problems = [p for c in checks for p in _out_of_range(*c)]
    if problems:
        raise LogImportError("\n".join(problems))


def _to_degc(values, unit):
    a, b = TEMPERATURE_UNITS[unit]
    return values if unit == "degC" else values * a + b


def _import_record(table, m, gaps, start):
    """meta.json "import" entries beyond the source and rows: what was detected or declared about the file.

    The plain CSV of the run format itself (comma, decimal point, no gaps, seconds) adds nothing, so a log
    imported before these existed imports to the same meta.json."""
    rec = {}
    if table.header_line != 1:
        rec["header_line"] = table.header_line
    if table.delimiter != "," or table.decimal != ".":
        rec["dialect"] = table.dialect
    if m["time_format"] is not None:
        rec["time"] = {"format": m["time_format"], "start_time": start}
        if m["timezone"] is not None:
            rec["time"]["timezone"] = m["timezone"]
    elif m["time_unit"] not in (None, "s"):
        rec["time"] = {"unit": m["time_unit"]}
    if gaps is not None:
        rec["gaps"] = gaps
    return rec


def _read(source, m, numeric, text=()):
    try:
        table = logfile.read_table(source, m["delimiter"], m["decimal"],
                                   numeric_columns=([] if m["time_format"] else [m["time"]]) + list(numeric), header_line=m["header_line"])
    except LogFileError as exc:
        raise LogImportError(str(exc))
    _check_header(table, m, [m["time"]] + list(numeric) + list(text))
    return table


def import_csv(source: str, mapping: Any, mapping_where: str = "mapping") -> Run:
    """Read a wide-layout ``source`` (CSV path) with ``mapping``; return a Run (not yet written)."""
    if isinstance(mapping, dict) and mapping.get("layout") == "long":
        raise LogImportError("%s: a long layout holds error sweeps, not the run's temperatures: import the temperatures first (tcomp "
                             "import LOG --out RUN, or tcomp record), then merge the sweeps with tcomp import --errors %s --into RUN"
                             % (mapping_where, source))
    m = _normalise_wide(mapping, mapping_where)
    m["where"] = mapping_where
    tcols, ecols = list(m["temperatures"]), list(m["errors"])
    numeric = tcols + ecols + ([m["spindle"]] if m["spindle"] else [])
    table, cells, gaps, time_s, start = _read_cells(source, m, numeric, mapping_where)
    lo, hi = TEMPERATURE_RANGE_C
    tvals = np.column_stack([_to_degc(cells.column(c), m["temperatures"][c]["unit"]) for c in tcols])
    evals = np.column_stack([cells.column(c) * m["errors"][c]["scale"] for c in ecols]) if ecols else None
    units = {c: m["temperatures"][c]["unit"] for c in tcols}
    _check_ranges([(cells, c, tvals[:, j], lo, hi, "degC%s, the range of a Pt100 (IEC 60751)"
                    % ("" if units[c] == "degC" else " once converted from %s" % units[c])) for j, c in enumerate(tcols)]
                  # evals is None only without ecols, when this list is empty
                  + [(cells, c, evals[:, j], -ERROR_LIMIT_UM,  # pyright: ignore[reportOptionalSubscript]
                       ERROR_LIMIT_UM, "um once scaled: no feed axis grows that much")
                     for j, c in enumerate(ecols)])
    temps = Temperatures(time_s, [m["temperatures"][c]["name"] for c in tcols], tvals)
    n = time_s.size
    errors = None  # a log of temperatures only: its sweeps come from an instrument (tcomp import --errors FILE --into RUN)
    if ecols:
        err_time = np.repeat(time_s, len(ecols))
        err_pos = np.tile([m["errors"][c]["position_mm"] for c in ecols], n)
        # The channel column is kept even for one channel: it records which probe it was.
        channel = np.tile(np.array([m["errors"][c]["channel"] for c in ecols], dtype=object), n)
        assert evals is not None  # made with ecols
        errors = Errors(err_time, err_pos, evals.reshape(-1), None, channel)
    spindle = Spindle(time_s, cells.column(m["spindle"])) if m["spindle"] else None
    # Only what the user declared: no axis, no sensor location unless the mapping (or a flag) gives it.
    meta: dict[str, Any] = {"format": FORMAT}
    if "axis" in m["meta"]:
        meta["axis"] = m["meta"].pop("axis")
    meta["sensors"] = {s["name"]: dict({"role": s["role"]}, **({"location": s["location"]} if s["location"] is not None else {}))
                       for s in m["temperatures"].values()}
    meta["channels"] = {s["channel"]: dict({"source_column": c, "position_mm": s["position_mm"], "scale": s["scale"]},
                                           **({"unit": s["unit"]} if s["unit"] else {})) for c, s in m["errors"].items()}
    if errors is None:
        meta["errors_pending"] = True  # errors.csv holds its header until the sweeps are merged (tcomp import --errors --into)
    meta["import"] = {"source": os.path.basename(source), "rows": int(n), "ignored_columns": m["ignore"]}
    declared = {c: s["unit"] for c, s in m["temperatures"].items() if s["declared"]}
    if declared:
        meta["import"]["temperature_units"] = declared
    meta["import"].update(_import_record(table, m, gaps, start))
    if start is not None:
        if "start_time" in m["meta"]:
            raise LogImportError("%s: meta 'start_time' is declared, but the time column's date-times give it (%s); remove it"
                                 % (mapping_where, start))
        meta["start_time"] = start
    elif "start_time" in m["meta"]:
        try:  # a log of numbers whose start the user knows: declared, so it must be a date-time with its offset
            logfile.parse_utc(m["meta"]["start_time"], "%s: meta 'start_time'" % mapping_where)
        except LogFileError as exc:
            raise LogImportError(str(exc))
    meta.update(m["meta"])
    ref = meta.get("error_reference", START)
    if not (ref == START or (isinstance(ref, str) and ref in meta["sensors"])):
        raise LogImportError("%s: error_reference %s is neither \"start\" (raw errors relative to the machine at the run's start) "
                             "nor one of the imported sensors (%s) the errors were corrected to"
                             % (mapping_where, json.dumps(ref), ", ".join(meta["sensors"])))
    name = os.path.splitext(os.path.basename(source))[0]
    # errors None: a run awaiting its sweeps, which write_run writes as errors.csv's header (a loaded Run always has Errors)
    run = Run(meta, temps, cast(Errors, errors), None, spindle, name=name)
    run.dialect = table.dialect  # what the file was read as, for the command's summary (meta.json keeps it when not plain CSV)
    return run


class Sweeps:
    """Error sweeps read from an instrument file: ``errors`` with times relative to the file's clock,
    ``point_time_s`` each row's own time (the sweep's rows share its first point's time in ``errors``),
    ``lines`` each row's source line, ``start_time`` the first sample's UTC date-time (date-time files only),
    ``record`` what meta.json keeps of the import, ``meta`` the mapping's meta."""

    def __init__(self, errors: Errors, point_time_s: np.ndarray, lines: np.ndarray, start_time: str | None, record: dict[str, Any],
                 meta: dict[str, Any]) -> None:
        self.errors, self.point_time_s, self.lines = errors, point_time_s, lines
        self.start_time, self.record, self.meta = start_time, record, meta

    def groups(self) -> list[np.ndarray]:
        return self.errors.sweeps()


def _no_start_time(m, where):
    if "start_time" in m["meta"]:
        raise LogImportError("%s: meta 'start_time' belongs to the run (the wall clock of its time 0); an error file's clock is "
                             "aligned with it by its date-times or --clock-offset" % where)


def _direction(cells, m):
    if m["direction"] is None:
        return None
    col, values = m["direction"]["column"], m["direction"]["values"]
    out = []
    for i, cell in enumerate(cells.text(col)):
        if cell not in values:
            raise LogImportError("%s: direction %r is not one of the declared values (%s)"
                                 % (_where(cells, i, col), cell, ", ".join("%r = %+d" % kv for kv in values.items())))
        out.append(values[cell])
    return np.asarray(out, dtype=np.int8)


def _sweep_starts(cells, m, position, direction):
    """Row indices where a sweep starts: the run number (``sweep``) or the direction changes; without a run number,
    also where the position stops moving the way the sweep goes (the next pass starting over)."""
    runs = cells.text(m["sweep"]) if m["sweep"] else None
    starts, sense = [0], 0
    for i in range(1, len(position)):
        step = position[i] - position[i - 1]
        new = (runs is not None and runs[i] != runs[i - 1]) or (direction is not None and direction[i] != direction[i - 1])
        if not new and runs is None:
            want = direction[i] if direction is not None else (sense or np.sign(step))
            new = step * want <= 0
            sense = 0 if new else want
        if new:
            starts.append(i)
            sense = 0
    return starts


def import_errors(source: str, mapping: Any, mapping_where: str = "mapping") -> Sweeps:
    """Read an instrument's error file (long layout: one row per point; or wide: probe columns) into Sweeps."""
    layout = mapping.get("layout", "wide") if isinstance(mapping, dict) else "wide"
    if layout == "wide":
        return _wide_errors(source, mapping, mapping_where)
    m = _normalise_long(mapping, mapping_where)
    _no_start_time(m, mapping_where)
    m["where"] = mapping_where
    pcol, ecol = m["position"]["column"], m["error"]["column"]
    text = ([m["direction"]["column"]] if m["direction"] else []) + ([m["sweep"]] if m["sweep"] else [])
    table = _read(source, m, [pcol, ecol], text)
    cells = _Cells(table, m, [pcol, ecol], text)
    gaps = _apply_gaps(cells, m, mapping_where)
    time_s, raw, start = _time_s(cells, m)
    _check_time_order(cells, m, time_s, raw, strict=False)
    if gaps is not None and gaps["policy"] == "interpolate":
        _interpolate(cells, time_s)
    position = cells.column(pcol) * m["position"]["factor"]
    error = cells.column(ecol) * m["error"]["scale"]
    _check_ranges([(cells, ecol, error, -ERROR_LIMIT_UM, ERROR_LIMIT_UM, "um once converted: no feed axis grows that much")])
    direction = _direction(cells, m)
    starts = _sweep_starts(cells, m, position, direction)
    bounds = list(zip(starts, starts[1:] + [len(position)]))
    sweep_time = np.empty_like(time_s)
    seen = {}
    for a, b in bounds:
        sweep_time[a:b] = time_s[a]
        key = (time_s[a], None if direction is None else int(direction[a]))
        if key in seen:
            raise LogImportError("%s lines %d-%d: this sweep starts at the same time as the sweep of lines %d-%d%s; errors.csv tells "
                                 "sweeps apart by their time: give the rows distinct times" % (source, cells.lines[a], cells.lines[b - 1],
                                                                                             seen[key][0], seen[key][1], " in the same direction" if direction is not None else ""))
        seen[key] = (cells.lines[a], cells.lines[b - 1])
    if m["sweep"]:
        order = []
        ids = cells.text(m["sweep"])
        for a, b in bounds:
            k = (ids[a], None if direction is None else int(direction[a]))
            if k in order:
                raise LogImportError("%s line %d column %r: run %r%s appears again after other rows; the rows of one sweep must follow "
                                     "each other" % (source, cells.lines[a], m["sweep"], ids[a], "" if direction is None else
                                                     " direction %+d" % direction[a]))
            order.append(k)
    channel = None if m["channel"] is None else np.array([m["channel"]] * len(position), dtype=object)
    errors = Errors(sweep_time, position, error, direction, channel)
    record = {"source": os.path.basename(source), "layout": "long", "rows": int(len(position)), "sweeps": len(bounds),
              "position_unit": m["position"]["unit"], "error_unit": m["error"]["unit"] or "um", "dialect": table.dialect}
    record.update(_import_record(table, m, gaps, start))
    return Sweeps(errors, time_s, cells.lines, start, record, m["meta"])


def _wide_errors(source, mapping, mapping_where):
    """Probe columns sampled in time (the wide layout without temperatures): one sweep per channel and sample."""
    m = _normalise_wide(mapping, mapping_where, temperatures=False)
    _no_start_time(m, mapping_where)
    if m["spindle"]:
        raise LogImportError("%s: --errors merges error sweeps; 'spindle' belongs to the run's own log" % mapping_where)
    m["where"] = mapping_where
    ecols = list(m["errors"])
    table, cells, gaps, time_s, start = _read_cells(source, m, ecols, mapping_where)
    evals = np.column_stack([cells.column(c) * m["errors"][c]["scale"] for c in ecols])
    _check_ranges([(cells, c, evals[:, j], -ERROR_LIMIT_UM, ERROR_LIMIT_UM, "um once scaled: no feed axis grows that much")
                   for j, c in enumerate(ecols)])
    n = time_s.size
    errors = Errors(np.repeat(time_s, len(ecols)), np.tile([m["errors"][c]["position_mm"] for c in ecols], n), evals.reshape(-1), None,
                    np.tile(np.array([m["errors"][c]["channel"] for c in ecols], dtype=object), n))
    record = {"source": os.path.basename(source), "layout": "wide", "rows": int(n), "sweeps": int(n * len(ecols)),
              "channels": {s["channel"]: dict({"source_column": c, "position_mm": s["position_mm"], "scale": s["scale"]},
                                              **({"unit": s["unit"]} if s["unit"] else {})) for c, s in m["errors"].items()},
              "dialect": table.dialect}
    record.update(_import_record(table, m, gaps, start))
    return Sweeps(errors, np.repeat(time_s, len(ecols)), np.repeat(cells.lines, len(ecols)), start, record, m["meta"])


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
