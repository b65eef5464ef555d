"""Run folders (format ``tcomp-run/1``, see docs/data-format.md): load, validate, write.

A run is one thermal test: ``meta.json``, ``temperatures.csv``, ``errors.csv`` and
optionally ``motion.csv`` and ``spindle.csv``. Loading validates everything and
raises :class:`RunFormatError` listing every problem, each naming file, line and
column; nothing is silently dropped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any
from numpy.typing import ArrayLike
import csv
import json
import math
import os
import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from host.data.runformat import (  # noqa: F401  (the format's names, numpy-free for the board side's recorder)
    ERROR_COLUMNS, ERROR_OPTIONAL, ERRORS, FORMAT, META, MOTION, MOTION_COLUMNS, ROLES, RUN_FILES, SPINDLE,
    SPINDLE_COLUMNS, TEMPERATURES,
)

# meta.json "error_reference": which temperature errors.csv is referred to (docs/data-format.md).
# START: raw errors relative to the machine at the run's start (the default when the key is absent);
# otherwise a sensor id of the run: the errors were corrected to that sensor's temperature.
START = "start"


class RunFormatError(ValueError):
    """A run folder that does not follow tcomp-run/1. ``problems`` lists every finding."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass
class Temperatures:
    time_s: np.ndarray  # (n,)
    names: list  # sensor names in CSV column order
    values: np.ndarray  # (n, len(names)) in degC

    def column(self, name: str) -> np.ndarray:
        return self.values[:, self.names.index(name)]

    def at(self, t: ArrayLike, names: Sequence[str] | None = None) -> np.ndarray:
        """Temperatures linearly interpolated at times ``t`` -> (len(t), len(names))."""
        names = self.names if names is None else list(names)
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty((t.size, len(names)))
        for j, name in enumerate(names):
            out[:, j] = np.interp(t, self.time_s, self.column(name))
        return out


@dataclass
class Errors:
    time_s: np.ndarray
    position_mm: np.ndarray
    error_um: np.ndarray
    direction: np.ndarray | None = None  # int8 +1/-1, or None when unidirectional
    channel: np.ndarray | None = None  # object array of str, or None

    def __len__(self) -> int:
        return self.time_s.size

    def sweeps(self) -> list[np.ndarray]:
        """Row-index arrays, one per (measurement time, channel, direction) group, in file order."""
        keys = [self.time_s]
        if self.channel is not None:
            keys.append(self.channel.astype(str))
        if self.direction is not None:
            keys.append(self.direction)
        groups = {}
        for i, key in enumerate(zip(*keys)):
            groups.setdefault(key, []).append(i)
        return [np.asarray(v) for v in groups.values()]

    def channels(self) -> list[str]:
        if self.channel is None:
            return []
        seen = []
        for c in self.channel:
            if c not in seen:
                seen.append(c)
        return seen


@dataclass
class Motion:
    t_start_s: np.ndarray
    t_end_s: np.ndarray
    from_mm: np.ndarray
    to_mm: np.ndarray
    feed_mm_min: np.ndarray

    def __len__(self) -> int:
        return self.t_start_s.size


@dataclass
class Spindle:
    time_s: np.ndarray
    rpm: np.ndarray


@dataclass
class Run:
    meta: dict
    temperatures: Temperatures
    errors: Errors
    motion: Motion | None = None
    spindle: Spindle | None = None
    path: str | None = None
    name: str = field(default="run")
    # what an imported log was read as (logfile.Table.dialect), set by import_csv for the command's summary; not a run
    # file's content, so neither in the constructor nor in the comparison or the repr
    dialect: dict[str, Any] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def sensors(self) -> dict[str, dict[str, Any]]:
        return dict(self.meta.get("sensors", {}))

    def sensors_with_role(self, role: str) -> list[str]:
        return [n for n, s in self.meta.get("sensors", {}).items() if s.get("role") == role]

    @property
    def error_reference(self) -> str:
        """``"start"`` or the sensor id the errors are corrected to (meta.json ``error_reference``)."""
        return error_reference(self.meta)

    @property
    def stroke_mm(self) -> float | None:
        return self.meta.get("stroke_mm")

    @property
    def screw(self) -> dict[str, Any] | None:
        return self.meta.get("screw")


# ---------------------------------------------------------------- reading


class _Problems:
    def __init__(self):
        self.items = []

    def add(self, where, what):
        self.items.append("%s: %s" % (where, what))

    def __bool__(self):
        return bool(self.items)


# A plain decimal number in ASCII. float() also reads '2_0' (as 20) and full-width or Arabic-Indic digits,
# which no logger writes: such a cell is a typo or a mangled file, not a number.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
CELL_LIMIT = csv.field_size_limit()  # 131072 characters (128 KiB), Python's csv default, kept as our limit


def parse_number(cell: str) -> float:
    """float(cell) for a plain ASCII decimal number (nan/inf included, for the caller to name); ValueError otherwise."""
    if not _NUMBER.fullmatch(cell):
        raise ValueError("not a number: %r" % cell)
    return float(cell)


class CsvSyntaxError(ValueError):
    """A CSV file that cannot be split into cells unambiguously; the message names file and line."""


def read_records(fh: Iterable[str], path: str, delimiter: str = ",", first_line: int = 1) -> list[tuple[int, list[str]]]:
    """[(line number, cells)] of an open CSV file, one record per physical line (cells split at ``delimiter``;
    ``first_line``: the file's line number of ``fh``'s first line, when lines before it were skipped).

    A quote opens a cell that may run over line ends; in a log, that is almost always a stray ``"`` that
    silently swallows the following rows. So a record spanning lines, a quote never closed, text after a
    closing quote and a cell over 128 KiB are all CsvSyntaxError naming the file and line.
    """
    reader = csv.reader(fh, delimiter=delimiter, strict=True)
    out = []
    start = 1
    try:
        for row in reader:
            if reader.line_num != start:
                raise CsvSyntaxError("%s lines %d-%d: one quoted cell runs over %d lines (a stray '\"'? each row of the log must "
                                     "be one line)" % (path, start + first_line - 1, reader.line_num + first_line - 1, reader.line_num - start + 1))
            out.append((start + first_line - 1, row))
            start = reader.line_num + 1
    except csv.Error as exc:
        text = str(exc)
        if "unexpected end of data" in text or reader.line_num > start:
            why = "a quote opened on this line is never closed (a stray '\"'?)"
        elif "field larger than field limit" in text:
            why = "a cell is longer than %d characters (128 KiB; a missing line end?)" % CELL_LIMIT
        elif "expected after" in text:
            why = "text follows a closing quote in a cell (a stray '\"'?)"
        else:
            why = "not valid CSV (%s)" % text
        raise CsvSyntaxError("%s line %d: %s" % (path, start + first_line - 1, why))
    return out


def _read_csv(path, required, optional, problems, text_columns=(), rows_pending=False):
    """Parse a numeric CSV strictly. Returns {column: list} or None if unreadable."""
    try:
        # utf-8-sig: spreadsheet programs (Excel) start a UTF-8 CSV with a byte-order mark
        with open(path, newline="", encoding="utf-8-sig") as fh:
            records = read_records(fh, path)
    except FileNotFoundError:
        problems.add(path, "file is missing")
        return None
    except IsADirectoryError:
        problems.add(path, "is a folder, expected a CSV file")
        return None
    except UnicodeDecodeError as exc:
        problems.add(path, "not a UTF-8 text CSV (byte %d cannot be decoded)" % exc.start)
        return None
    except OSError as exc:
        problems.add(path, "cannot be read (%s)" % (exc.strerror or exc))
        return None
    except CsvSyntaxError as exc:
        problems.items.append(str(exc))
        return None
    rows = [r for _, r in records]
    lines = [n for n, _ in records]
    if not rows:
        problems.add("%s line 1" % path, "file is empty (expected a header %s)" % ",".join(required))
        return None
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    for c in missing:
        problems.add("%s line 1" % path, "missing column '%s' (header is %s)" % (c, ",".join(header)))
    dup = sorted(c for c, k in Counter(header).items() if k > 1)  # Counter: a wide header stays linear
    for c in dup:
        problems.add("%s line 1" % path, "column '%s' appears more than once" % c)
    empty = [i + 1 for i, h in enumerate(header) if not h]
    for i in empty:
        problems.add("%s line 1 column %d" % (path, i), "empty column name")
    if missing or dup or empty:
        return None
    if optional is not None:
        extra = [c for c in header if c not in required and c not in optional]
        for c in extra:
            problems.add("%s line 1" % path, "unknown column '%s' (allowed: %s)" % (c, ",".join(tuple(required) + tuple(optional))))
        if extra:
            return None
    data = {h: [] for h in header}
    for lineno, row in zip(lines[1:], rows[1:]):
        if not row or all(not c.strip() for c in row):
            problems.add("%s line %d" % (path, lineno), "blank line")
            continue
        if len(row) != len(header):
            problems.add("%s line %d" % (path, lineno), "has %d cells, header has %d" % (len(row), len(header)))
            continue
        for col, cell in zip(header, row):
            cell = cell.strip()
            if col in text_columns:
                if not cell:
                    problems.add("%s line %d column '%s'" % (path, lineno, col), "empty cell")
                data[col].append(cell)
                continue
            try:
                v = parse_number(cell)
            except ValueError:
                problems.add("%s line %d column '%s'" % (path, lineno, col), "not a number: %r" % cell)
                v = math.nan
            else:
                if not math.isfinite(v):
                    problems.add("%s line %d column '%s'" % (path, lineno, col), "%r is not a finite number" % cell)
            data[col].append(v)
    if len(rows) == 1 and not rows_pending:
        problems.add(path, "no data rows after the header%s" % (
            " (a recording whose laser sweeps are still to come declares meta.json \"errors_pending\": true)"
            if os.path.basename(path) == ERRORS else ""))
    return data


# Values no thermal test produces; beyond them a number is a logger fault or a wrong unit, and it would reach the
# fits as a spike (1e308 degC: "perfectly collinear" and overflow warnings instead of the row at fault).
TEMPERATURE_RANGE_C = (-200.0, 850.0)  # Pt100 measuring range, IEC 60751
ERROR_LIMIT_UM = 10000.0  # 10 mm: four times a 20 m steel axis (11.5e-6/K) warming by 10 K
_SHOWN = 10  # problems of one kind listed one by one; the rest are counted


def _check_range(path, data, columns, bounds, what, problems):
    lo, hi = bounds
    bad = [(i, c, v) for c in columns for i, v in enumerate(data[c]) if not lo <= v <= hi and math.isfinite(v)]
    for i, c, v in bad[:_SHOWN]:
        problems.add("%s line %d column '%s'" % (path, i + 2, c), what % (v, lo, hi))
    if len(bad) > _SHOWN:
        problems.add(path, "... and %d more values outside %g..%g" % (len(bad) - _SHOWN, lo, hi))


def _check_increasing(path, col, values, problems, strict=True):
    for i in range(1, len(values)):
        a, b = values[i - 1], values[i]
        if math.isnan(a) or math.isnan(b):
            continue
        if (b <= a) if strict else (b < a):
            problems.add(
                "%s line %d column '%s'" % (path, i + 2, col),
                "time goes backwards or repeats (%g after %g)" % (b, a) if strict else "time goes backwards (%g after %g)" % (b, a),
            )


def _positive(v):
    """A JSON number > 0 and finite: json reads NaN, Infinity and 1e400 (as Infinity) too."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def _check_meta(path, meta, problems):
    if not isinstance(meta, dict):
        problems.add(path, "top level must be a JSON object")
        return
    if meta.get("format") != FORMAT:
        problems.add(path, "key 'format' must be %r (found %r)" % (FORMAT, meta.get("format")))
    sensors = meta.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        problems.add(path, "key 'sensors' must be a non-empty object {name: {role, location}}")
    else:
        for name, s in sensors.items():
            if not isinstance(s, dict):
                problems.add(path, "sensors.%s must be an object with 'role'" % name)
                continue
            if s.get("role") not in ROLES:
                problems.add(path, "sensors.%s.role is %r; expected one of %s" % (name, s.get("role"), ", ".join(ROLES)))
    _check_error_reference(path, meta, problems)
    if "errors_pending" in meta and not isinstance(meta["errors_pending"], bool):
        problems.add(path, "key 'errors_pending' must be true or false (found %s)" % json.dumps(meta["errors_pending"]))
    stroke = meta.get("stroke_mm")
    if stroke is not None and not _positive(stroke):
        problems.add(path, "key 'stroke_mm' must be a positive finite number (found %r)" % (stroke,))
    if "start_time" in meta and not _is_utc_date_time(meta["start_time"]):
        problems.add(path, "key 'start_time' must be an ISO 8601 date-time with its offset, e.g. \"2026-11-26T07:00:00Z\" "
                     "(found %r)" % (meta["start_time"],))
    screw = meta.get("screw")
    if screw is not None:
        if not isinstance(screw, dict):
            problems.add(path, "key 'screw' must be an object")
        else:
            for k in ("length_mm", "diameter_mm", "lead_mm"):
                v = screw.get(k)
                if not _positive(v):
                    problems.add(path, "screw.%s must be a positive finite number (found %r)" % (k, v))
            fe = screw.get("fixed_end_mm", 0)
            if not isinstance(fe, (int, float)) or isinstance(fe, bool) or not math.isfinite(fe):
                problems.add(path, "screw.fixed_end_mm must be a finite number (found %r)" % (fe,))


def _is_utc_date_time(text):
    """An ISO 8601 date-time that carries its offset (meta.json ``start_time``: the wall clock of time_s = 0)."""
    from datetime import datetime

    if not isinstance(text, str):
        return False
    try:
        return datetime.fromisoformat(text[:-1] + "+00:00" if text[-1:] in "zZ" else text).utcoffset() is not None
    except ValueError:
        return False


def error_reference(meta: dict[str, Any]) -> str:
    """The declared error reference of a run's meta: ``"start"`` when absent (load_run has validated it)."""
    return meta.get("error_reference", START)


def _check_error_reference(path, meta, problems):
    ref = meta.get("error_reference", START)
    sensors = meta.get("sensors") if isinstance(meta.get("sensors"), dict) else {}
    if ref == START or (isinstance(ref, str) and ref in sensors):
        return
    problems.add(path, "key 'error_reference' is %s; expected \"start\" (raw errors relative to the machine at the run's "
                 "start) or a sensor id of this run the errors are corrected to (%s)"
                 % (json.dumps(ref), ", ".join(sensors) or "no sensors declared"))


def common_error_reference(runs: Iterable[Run]) -> str:
    """The error reference all ``runs`` declare; ValueError naming the runs of each reference when they differ.

    One fit mixes no conventions: a sensor-referenced error lacks the expansion a raw error holds, so a model
    fitted on both would learn half of it."""
    by = {}
    for r in runs:
        by.setdefault(r.error_reference, []).append(r.path or r.name)
    if len(by) > 1:
        raise ValueError("the runs declare different error references (meta.json 'error_reference'): %s; fit runs of one "
                         "reference at a time (docs/data-format.md)"
                         % "; ".join("%s: %s" % (json.dumps(k), ", ".join(v)) for k, v in by.items()))
    return next(iter(by), START)


def check_model_reference(run: Run, model_reference: str | None) -> None:
    """ValueError when ``run``'s errors are referred otherwise than a model's training runs were.

    A prediction and a measurement in different conventions differ by the expansion at the reference
    temperature: comparing them would report that as model error."""
    ref = run.error_reference
    if ref != model_reference:
        raise ValueError("%s: its errors are referred to %s (meta.json error_reference) but the model was fitted on errors "
                         "referred to %s (docs/data-format.md)" % (run.path or run.name, json.dumps(ref), json.dumps(model_reference)))


def slice_run(run: Run, t_start_s: float, t_end_s: float | None = None) -> Run:
    """The part of ``run`` with t_start_s <= time < t_end_s as a run of its own: what a board switched on at
    ``t_start_s`` would have seen (forward-chaining validation, a restart on a warm machine).

    Times stay as logged (not shifted to 0). The temperature log starts at its first sample at or after
    ``t_start_s``, and errors.csv keeps only rows from that sample on (a model cannot be evaluated before
    its first temperature). The errors keep their values: they stay referred to the machine at the
    original run's start (meta.json ``error_reference``), which is the error the board must correct.
    The spindle speed in force at the slice's start (the last spindle.csv sample at or before it) is
    carried to the slice's first temperature time; motion intervals are clipped to the slice.
    ValueError when the slice holds fewer than 2 temperature samples.
    """
    t = np.asarray(run.temperatures.time_s, dtype=float)
    hi = np.inf if t_end_s is None else float(t_end_s)
    keep = (t >= float(t_start_s)) & (t < hi)
    name = "%s[%g..%s s]" % (run.name, float(t_start_s), "end" if t_end_s is None else "%g" % hi)
    if keep.sum() < 2:
        raise ValueError("%s: the slice holds %d temperature sample(s); a run needs at least 2" % (name, int(keep.sum())))
    t0 = float(t[keep][0])
    temps = Temperatures(t[keep].copy(), list(run.temperatures.names), np.array(run.temperatures.values[keep], dtype=float))
    e = run.errors
    rows = (e.time_s >= t0) & (e.time_s < hi)  # may be none: a history (predict --history) needs no error row
    errors = Errors(e.time_s[rows].copy(), e.position_mm[rows].copy(), e.error_um[rows].copy(),
                    None if e.direction is None else e.direction[rows].copy(), None if e.channel is None else e.channel[rows].copy())
    spindle = None
    if run.spindle is not None:
        st, rpm = run.spindle.time_s, run.spindle.rpm
        inside = (st > t0) & (st < hi)
        before = np.flatnonzero(st <= t0)
        held = rpm[before[-1]] if before.size else 0.0  # no sample yet: the spindle is taken as standing, as signals() does
        spindle = Spindle(np.r_[t0, st[inside]], np.r_[held, rpm[inside]])
    motion = None
    if run.motion is not None:
        m = run.motion
        on = (m.t_end_s > t0) & (m.t_start_s < hi)
        motion = Motion(np.maximum(m.t_start_s[on], t0), np.minimum(m.t_end_s[on], hi), m.from_mm[on].copy(), m.to_mm[on].copy(),
                        m.feed_mm_min[on].copy())
    return Run(dict(run.meta), temps, errors, motion, spindle, path=None, name=name)


def load_meta(folder: str) -> dict[str, Any]:
    path = os.path.join(folder, META)
    problems = _Problems()
    try:
        with open(path, encoding="utf-8-sig") as fh:
            meta = json.load(fh)
    except FileNotFoundError:
        raise RunFormatError(["%s: file is missing" % path])
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFormatError(["%s: cannot be read as UTF-8 JSON (%s)" % (path, getattr(exc, "strerror", None) or exc)])
    except json.JSONDecodeError as exc:
        raise RunFormatError(["%s line %d column %d: invalid JSON (%s)" % (path, exc.lineno, exc.colno, exc.msg)])
    _check_meta(path, meta, problems)
    if problems:
        raise RunFormatError(problems.items)
    return meta


def check_run(folder: str) -> list[str]:
    """Every problem with a run folder, as a list of messages (empty when valid)."""
    try:
        load_run(folder)
    except RunFormatError as exc:
        return exc.problems
    return []


def load_run(folder: str) -> Run:
    """Load and validate one run folder; raise RunFormatError naming every problem."""
    folder = os.fspath(folder)
    problems = _Problems()
    if not os.path.isdir(folder):
        raise RunFormatError(["%s: not a folder (a run is a folder with meta.json, temperatures.csv, errors.csv)" % folder])
    meta = None
    try:
        meta = load_meta(folder)
    except RunFormatError as exc:
        problems.items.extend(exc.problems)

    # temperatures.csv: time_s + any sensor columns
    tpath = os.path.join(folder, TEMPERATURES)
    tdata = _read_csv(tpath, ("time_s",), None, problems)
    temps = None
    if tdata is not None:
        names = [c for c in tdata if c != "time_s"]
        if not names:
            problems.add("%s line 1" % tpath, "no temperature columns after time_s")
        _check_increasing(tpath, "time_s", tdata["time_s"], problems)
        if meta is not None and isinstance(meta.get("sensors"), dict):
            undeclared = [(j, n) for j, n in enumerate(names) if n not in meta["sensors"]]
            for j, n in undeclared[:_SHOWN]:
                problems.add("%s line 1 column %d" % (tpath, j + 2), "sensor '%s' is not declared in meta.json 'sensors'" % n)
            if len(undeclared) > _SHOWN:
                problems.add("%s line 1" % tpath, "... and %d more undeclared sensor columns (%d in all)" % (len(undeclared) - _SHOWN, len(undeclared)))
        _check_range(tpath, tdata, names, TEMPERATURE_RANGE_C, "temperature %g degC is outside %g..%g degC, the range of a Pt100 "
                     "(IEC 60751), the sensor tcomp reads (a logger fault or a wrong unit?)", problems)
        temps = Temperatures(
            np.asarray(tdata["time_s"], dtype=float),
            names,
            np.asarray([tdata[n] for n in names], dtype=float).T.reshape(len(tdata["time_s"]), len(names)),
        )

    # errors.csv
    epath = os.path.join(folder, ERRORS)
    # a recording (tcomp record) declares that its errors come later (tcomp import --errors --into): header only
    pending = bool(meta) and meta.get("errors_pending") is True
    edata = _read_csv(epath, ERROR_COLUMNS, ERROR_OPTIONAL, problems, text_columns=("channel",), rows_pending=pending)
    errors = None
    if edata is not None:
        _check_increasing(epath, "time_s", edata["time_s"], problems, strict=False)
        _check_range(epath, edata, ["error_um"], (-ERROR_LIMIT_UM, ERROR_LIMIT_UM), "error %g um is outside %g..%g um: "
                     "no feed axis grows that much (a 20 m steel axis warming 10 K grows 2300 um; a wrong unit?)", problems)
        stroke = meta.get("stroke_mm") if meta else None
        if isinstance(stroke, (int, float)) and stroke > 0:
            for i, p in enumerate(edata["position_mm"]):
                if not math.isnan(p) and (p < 0 or p > stroke):
                    problems.add("%s line %d column 'position_mm'" % (epath, i + 2), "position %g mm is outside the stroke 0..%g mm" % (p, stroke))
        direction = None
        if "direction" in edata:
            for i, d in enumerate(edata["direction"]):
                if d not in (1.0, -1.0) and not math.isnan(d):
                    problems.add("%s line %d column 'direction'" % (epath, i + 2), "direction must be +1 or -1 (found %g)" % d)
            direction = np.asarray([0 if math.isnan(d) else int(d) for d in edata["direction"]], dtype=np.int8)
        channel = np.asarray(edata["channel"], dtype=object) if "channel" in edata else None
        errors = Errors(
            np.asarray(edata["time_s"], dtype=float),
            np.asarray(edata["position_mm"], dtype=float),
            np.asarray(edata["error_um"], dtype=float),
            direction,
            channel,
        )

    motion = None
    mpath = os.path.join(folder, MOTION)
    if os.path.exists(mpath):
        mdata = _read_csv(mpath, MOTION_COLUMNS, (), problems)
        if mdata is not None:
            for i in range(len(mdata["t_start_s"])):
                a, b = mdata["t_start_s"][i], mdata["t_end_s"][i]
                if b <= a:
                    problems.add("%s line %d column 't_end_s'" % (mpath, i + 2), "interval ends (%g) before it starts (%g)" % (b, a))
                if i and a < mdata["t_end_s"][i - 1]:
                    problems.add("%s line %d column 't_start_s'" % (mpath, i + 2), "interval overlaps the previous one (starts %g before %g)" % (a, mdata["t_end_s"][i - 1]))
                if mdata["feed_mm_min"][i] <= 0:
                    problems.add("%s line %d column 'feed_mm_min'" % (mpath, i + 2), "feed must be positive (found %g)" % mdata["feed_mm_min"][i])
                stroke = meta.get("stroke_mm") if meta else None
                if isinstance(stroke, (int, float)):
                    for col in ("from_mm", "to_mm"):
                        p = mdata[col][i]
                        if p < 0 or p > stroke:
                            problems.add("%s line %d column '%s'" % (mpath, i + 2, col), "position %g mm is outside the stroke 0..%g mm" % (p, stroke))
            motion = Motion(*(np.asarray(mdata[c], dtype=float) for c in MOTION_COLUMNS))

    spindle = None
    spath = os.path.join(folder, SPINDLE)
    if os.path.exists(spath):
        sdata = _read_csv(spath, SPINDLE_COLUMNS, (), problems)
        if sdata is not None:
            _check_increasing(spath, "time_s", sdata["time_s"], problems)
            spindle = Spindle(np.asarray(sdata["time_s"], dtype=float), np.asarray(sdata["rpm"], dtype=float))

    if problems:
        raise RunFormatError(problems.items)
    assert meta is not None and temps is not None and errors is not None  # each is read, or a problem was named
    return Run(meta, temps, errors, motion, spindle, path=folder, name=os.path.basename(os.path.normpath(folder)))


def load_runs(folders: Iterable[str]) -> list[Run]:
    """Load several runs; one folder given twice is refused: its samples would count twice and inflate every statistic."""
    seen = {}
    for f in folders:
        key = os.path.realpath(f)
        if key in seen:
            raise RunFormatError(["%s: the same run folder as %s, given twice (its samples would count twice "
                                  "and inflate the statistics)" % (f, seen[key])])
        seen[key] = f
    return [load_run(f) for f in folders]


# ---------------------------------------------------------------- writing


def _write_csv(path, header, columns, formats):
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(header) + "\n")
        n = len(columns[0]) if columns else 0
        for i in range(n):
            fh.write(",".join(f(c[i]) for f, c in zip(formats, columns)) + "\n")


def _g(decimals):
    def f(v):
        s = "%.*f" % (decimals, v)
        if "." in s:
            s = s.rstrip("0").rstrip(".")
        return "0" if s == "-0" else s

    return f


def write_meta(meta: dict[str, Any], path: str) -> None:
    """meta.json of a run (``format`` set when missing)."""
    meta = dict(meta)
    meta.setdefault("format", FORMAT)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(meta, fh, indent=2)
        fh.write("\n")


def write_errors(e: Errors | None, path: str, decimals: int = 4) -> None:
    """errors.csv of a run: time to the millisecond, positions and errors to ``decimals``.

    ``e`` None writes the header only: a run of temperatures awaiting its sweeps (meta.json ``errors_pending``,
    filled by ``tcomp import --errors --into``)."""
    if e is None:
        _write_csv(path, list(ERROR_COLUMNS), [], [])
        return
    header: list[str] = list(ERROR_COLUMNS)
    cols: list[np.ndarray] = [e.time_s, e.position_mm, e.error_um]
    fmts: list[Callable[[Any], str]] = [_g(3), _g(decimals), _g(decimals)]
    if e.direction is not None:
        header.append("direction")
        cols.append(e.direction)
        fmts.append(lambda d: "%+d" % d)
    if e.channel is not None:
        header.append("channel")
        cols.append(e.channel)
        fmts.append(str)
    _write_csv(path, header, cols, fmts)


def write_run(run: Run, folder: str, decimals: int = 4) -> str:
    """Write ``run`` as a tcomp-run/1 folder (created if needed). Returns the folder.

    Raises NotADirectoryError naming ``folder`` when it exists as a file (os.makedirs would only say "File exists").
    """
    if os.path.exists(folder) and not os.path.isdir(folder):
        import errno

        raise NotADirectoryError(errno.ENOTDIR, "exists and is not a folder (a run is written as a folder)", folder)
    os.makedirs(folder, exist_ok=True)
    write_meta(run.meta, os.path.join(folder, META))
    t = run.temperatures
    _write_csv(
        os.path.join(folder, TEMPERATURES),
        ["time_s"] + list(t.names),
        [t.time_s] + [t.values[:, j] for j in range(len(t.names))],
        [_g(3)] + [_g(decimals)] * len(t.names),
    )
    write_errors(run.errors, os.path.join(folder, ERRORS), decimals)  # None: the header only (docs/data-format.md)
    if run.motion is not None and len(run.motion):
        m = run.motion
        _write_csv(os.path.join(folder, MOTION), list(MOTION_COLUMNS), [m.t_start_s, m.t_end_s, m.from_mm, m.to_mm, m.feed_mm_min], [_g(3)] * 5)
    if run.spindle is not None:
        s = run.spindle
        _write_csv(os.path.join(folder, SPINDLE), list(SPINDLE_COLUMNS), [s.time_s, s.rpm], [_g(3), _g(3)])
    return folder
