"""An instrument's or logger's CSV export, read cell by cell: its dialect, numbers, gaps and timestamps.

Real exports are not the run format's plain CSV: a European logger writes ``;`` between cells and a decimal
comma, a laser's software writes ISO 8601 date-times, a logger leaves a cell empty when a channel drops out.
This module reads those; what the cells *mean* (which column is a temperature, in which unit) is the
mapping's business (host/data/importer.py).

Nothing is guessed silently: a detected delimiter or decimal separator is reported (``Table.dialect``,
written into meta.json by the importer and printed by ``tcomp import``), and a file that reads two ways is
refused, saying why. Every problem names the file, line (1 = header) and column.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime, timedelta, timezone, tzinfo
import math
import re
from typing import Any

from host.data.runs import CsvSyntaxError, parse_number, read_records

DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
DECIMALS = {".": "point", ",": "comma"}
AUTO = "auto"
ISO8601 = "iso8601"
# Problems listed one by one before the rest are cut off: a wrong setting fails every row the same way.
MAX_PROBLEMS = 50


class LogFileError(ValueError):
    """A source-file problem; the message names the file, line and column."""


class Table:
    """The header and rows of one export, split with its delimiter.

    ``dialect``: {"delimiter": ..., "decimal": ..., "detected": [what was detected rather than declared]}."""

    def __init__(self, source: str, header: list[str], records: list[tuple[int, list[str]]], delimiter: str, decimal: str,
                 detected: Iterable[str], header_line: int = 1) -> None:
        self.source = source
        self.header = header
        self.header_line = header_line  # the file's line holding the header (lines before it: the export's preamble)
        self.records = records  # [(line number, cells)] after the header
        self.delimiter = delimiter
        self.decimal = decimal
        self.detected = detected

    @property
    def dialect(self) -> dict[str, Any]:
        return {"delimiter": self.delimiter, "decimal": self.decimal, "detected": list(self.detected)}


def _records(text, source, delimiter, first_line=1):
    import io

    return read_records(io.StringIO(text, newline=""), source, delimiter, first_line)


def _split_consistently(records):
    """True when the header has several cells and every non-blank row as many."""
    if not records or len(records[0][1]) < 2:
        return False
    n = len(records[0][1])
    return all(len(row) == n for _, row in records[1:] if row)


def _detect_delimiter(text, source, first_line):
    plausible, why_not = {}, []
    for d in DELIMITERS:
        try:
            recs = _records(text, source, d, first_line)
        except CsvSyntaxError as exc:
            why_not.append("%s: %s" % (DELIMITERS[d], exc))
            continue
        if _split_consistently(recs):
            plausible[d] = recs
        elif recs and len(recs[0][1]) >= 2:
            bad = next((ln, len(r)) for ln, r in recs[1:] if r and len(r) != len(recs[0][1]))
            why_not.append("at %s the header has %d cells but line %d has %d" % (DELIMITERS[d], len(recs[0][1]), bad[0], bad[1]))
    if len(plausible) == 1:
        return next(iter(plausible.items()))
    if not plausible:
        raise LogFileError("%s line %d: cannot tell how the cells are separated: no delimiter (comma, semicolon, tab) splits the "
                           "header into two or more columns that every row agrees with%s; declare it (mapping \"delimiter\", "
                           "or --delimiter)" % (source, first_line, (" (" + "; ".join(why_not) + ")") if why_not else ""))
    raise LogFileError("%s line %d: ambiguous delimiter: the file splits consistently at %s (%s); declare which one "
                       "separates the cells (mapping \"delimiter\", or --delimiter)"
                       % (source, first_line, " and at ".join(DELIMITERS[d] for d in plausible),
                          ", ".join("%d columns at %s" % (len(r[0][1]), DELIMITERS[d]) for d, r in plausible.items())))


_COMMA_DECIMAL = re.compile(r"[+-]?[0-9]*,[0-9]+(?:[eE][+-]?[0-9]+)?")
_POINT_DECIMAL = re.compile(r"[+-]?[0-9]*\.[0-9]+(?:[eE][+-]?[0-9]+)?|[+-]?[0-9]+\.")


def _detect_decimal(source, header, records, delimiter, numeric_columns):
    """'.' or ',' from the numeric cells; (separator, None) or raises naming a cell of each kind when both occur."""
    if delimiter == ",":
        return "."  # a decimal comma would split the cell; a quoted "20,5" is refused as not a number, with the hint
    idx = [(c, header.index(c)) for c in numeric_columns if c in header]
    comma = point = None
    for lineno, row in records:
        for col, j in idx:
            if j >= len(row):
                continue
            cell = row[j].strip()
            if comma is None and _COMMA_DECIMAL.fullmatch(cell):
                comma = (lineno, col, cell)
            elif point is None and _POINT_DECIMAL.fullmatch(cell):
                point = (lineno, col, cell)
        if comma and point:
            raise LogFileError("%s: ambiguous decimal separator: line %d column %r has %r (decimal comma) and line %d column %r has %r "
                               "(decimal point); declare it (mapping \"decimal\", or --decimal)" % ((source,) + comma + point))
    return "," if comma else "."


def read_table(source: str, delimiter: str = AUTO, decimal: str = AUTO, numeric_columns: Iterable[str] = (),
               header_line: int = 1) -> Table:
    """Read ``source`` (a path) into a Table; ``numeric_columns``: the mapped columns a decimal separator is detected on;
    ``header_line``: the line holding the column names (the lines before it, an export's preamble, are not read)."""
    try:
        # utf-8-sig: spreadsheet programs (Excel) start a UTF-8 CSV with a byte-order mark
        with open(source, newline="", encoding="utf-8-sig") as fh:
            text = fh.read()
    except UnicodeDecodeError as exc:
        raise LogFileError("%s: not a UTF-8 text CSV (byte %d cannot be decoded); save the log as CSV (UTF-8)" % (source, exc.start))
    except OSError as exc:
        raise LogFileError("%s: cannot be read (%s)" % (source, exc.strerror or exc))
    detected = []
    lines = text.split("\n")
    if header_line > 1:
        if len(lines) < header_line or not "\n".join(lines[header_line - 1:]).strip():
            raise LogFileError("%s: no line %d (the declared header_line); the file has %d lines" % (source, header_line, len(lines) - 1))
        text = "\n".join(lines[header_line - 1:])
    try:
        if delimiter == AUTO:
            delimiter, records = _detect_delimiter(text, source, header_line)
            detected.append("delimiter")
        else:
            records = _records(text, source, delimiter, header_line)
    except CsvSyntaxError as exc:
        raise LogFileError(str(exc))
    if not records:
        raise LogFileError("%s line %d: file is empty" % (source, header_line))
    header = [h.strip() for h in records[0][1]]
    if decimal == AUTO:
        decimal = _detect_decimal(source, header, records[1:], delimiter, numeric_columns)
        detected.append("decimal")
    return Table(source, header, records[1:], delimiter, decimal, detected, header_line)


def parse_cell(cell: str, decimal: str) -> float:
    """float of a number cell written with ``decimal`` as its separator; ValueError with the reason otherwise."""
    if decimal == ",":
        if "." in cell:
            raise ValueError("not a number: %r (a '.' in a file whose decimal separator is ','; a thousands separator?)" % cell)
        return parse_number(cell.replace(",", "."))
    try:
        return parse_number(cell)
    except ValueError:
        if _COMMA_DECIMAL.fullmatch(cell):
            raise ValueError("not a number: %r (a decimal comma? declare \"decimal\": \",\")" % cell)
        raise


def number(cell: str, decimal: str, where: str) -> float | None:
    """A finite number, or None for an empty cell (a gap); LogFileError naming ``where`` otherwise."""
    cell = cell.strip()
    if not cell:
        return None
    try:
        v = parse_cell(cell, decimal)
    except ValueError as exc:
        raise LogFileError("%s: %s" % (where, exc))
    if not math.isfinite(v):
        raise LogFileError("%s: %r is not a finite number" % (where, cell))
    return v


# ------------------------------------------------------------------ timestamps

_OFFSET = re.compile(r"(?:UTC)?([+-])([0-9]{2}):?([0-9]{2})")


def fixed_or_named_zone(name: Any, where: str) -> tzinfo:
    """A tzinfo for a declared time zone: "UTC", a fixed offset "+01:00", or an IANA name ("Europe/Berlin")."""
    if not isinstance(name, str) or not name:
        raise LogFileError("%s: \"timezone\" must be a string such as \"UTC\", \"+01:00\" or \"Europe/Berlin\", found %r" % (where, name))
    if name in ("UTC", "Z"):
        return timezone.utc
    m = _OFFSET.fullmatch(name)
    if m:
        sign = 1 if m.group(1) == "+" else -1
        return timezone(sign * timedelta(hours=int(m.group(2)), minutes=int(m.group(3))))
    import zoneinfo

    try:
        return zoneinfo.ZoneInfo(name)
    except (zoneinfo.ZoneInfoNotFoundError, ValueError):
        raise LogFileError("%s: \"timezone\" %r is neither UTC, a fixed offset (+01:00) nor a known IANA zone name (Europe/Berlin)"
                           % (where, name))


def _in_zone(naive, zone, where):
    """``naive`` read in ``zone``; a wall-clock time that a daylight-saving change skips or repeats is refused."""
    a, b = naive.replace(tzinfo=zone, fold=0), naive.replace(tzinfo=zone, fold=1)
    if a.utcoffset() != b.utcoffset():
        raise LogFileError("%s: %s is ambiguous or does not exist in %s (a daylight-saving change); log in UTC or with an offset"
                           % (where, naive.isoformat(sep=" "), zone))
    return a


def parse_timestamp(cell: str, time_format: str, where: str) -> datetime:
    """A datetime (aware or naive, as the cell says) of an ISO 8601 or strptime-formatted cell."""
    cell = cell.strip()
    try:
        if time_format == ISO8601:
            if cell[-1:] in "zZ":  # fromisoformat reads 'Z' from Python 3.11 on; say it for every version
                cell = cell[:-1] + "+00:00"
            return datetime.fromisoformat(cell)
        return datetime.strptime(cell, time_format)
    except (ValueError, IndexError):
        raise LogFileError("%s: %r is not a date-time in %s" % (where, cell, "ISO 8601 (2024-03-01T08:00:00+01:00)"
                                                                   if time_format == ISO8601 else "the format %r" % time_format))


def seconds_since_first(stamps: Sequence[datetime], wheres: Sequence[str], zone_name: str | None,
                        zone_where: str) -> tuple[list[float], str]:
    """Seconds of each datetime since the first, and the first as ISO 8601 UTC.

    Either every timestamp carries its offset (then no "timezone" may be declared: the cells say it), or
    none does (then "timezone" is required: a naive clock across a daylight-saving change would be an hour out);
    a mix is refused naming the first cell that differs."""
    aware = [s.utcoffset() is not None for s in stamps]
    if any(aware) and not all(aware):
        k = aware.index(not aware[0])
        raise LogFileError("%s: %s a time-zone offset, unlike the first timestamp (%s); timestamps of one file must all carry one, or none"
                           % (wheres[k], "has" if aware[k] else "lacks", wheres[0]))
    if aware and aware[0]:
        if zone_name is not None:
            raise LogFileError("%s: \"timezone\" %r is declared, but the timestamps carry their own offsets (%s); remove \"timezone\""
                               % (zone_where, zone_name, wheres[0]))
        utc = [s.astimezone(timezone.utc) for s in stamps]
    else:
        if zone_name is None:
            raise LogFileError("%s: the timestamps carry no time zone (%s); declare the logger's clock (mapping \"timezone\": \"UTC\", "
                               "\"+01:00\" or \"Europe/Berlin\", or --timezone)" % (zone_where, wheres[0] if wheres else "no rows"))
        zone = fixed_or_named_zone(zone_name, zone_where)
        utc = [_in_zone(s, zone, w).astimezone(timezone.utc) for s, w in zip(stamps, wheres)]
    first = utc[0]
    return [(u - first).total_seconds() for u in utc], first.isoformat().replace("+00:00", "Z")


def parse_utc(text: Any, where: str) -> datetime:
    """A datetime in UTC from an ISO 8601 string that carries its offset (meta.json "start_time")."""
    try:
        t = datetime.fromisoformat(text[:-1] + "+00:00" if isinstance(text, str) and text[-1:] in "zZ" else text)
    except (TypeError, ValueError):
        raise LogFileError("%s: %r is not an ISO 8601 date-time" % (where, text))
    if t.utcoffset() is None:
        raise LogFileError("%s: %r carries no time-zone offset (write it as 2024-03-01T07:00:00Z or with +01:00)" % (where, text))
    return t.astimezone(timezone.utc)


_DELIMITER_NAMES = {"comma": ",", "semicolon": ";", "tab": "\t", "\\t": "\t", ",": ",", ";": ";", "\t": "\t", AUTO: AUTO}
_DECIMAL_NAMES = {"point": ".", "comma": ",", ".": ".", ",": ",", AUTO: AUTO}


def delimiter_of(value: Any, where: str) -> str:
    """The delimiter a mapping or flag declares: ',' ';' tab (or their names), or "auto"."""
    if value not in _DELIMITER_NAMES:
        raise LogFileError("%s: delimiter %r: expected \"auto\", \",\" (comma), \";\" (semicolon) or \"tab\"" % (where, value))
    return _DELIMITER_NAMES[value]


def decimal_of(value: Any, where: str) -> str:
    """The decimal separator a mapping or flag declares: '.' or ',' (or point/comma), or "auto"."""
    if value not in _DECIMAL_NAMES:
        raise LogFileError("%s: decimal %r: expected \"auto\", \".\" (point) or \",\" (comma)" % (where, value))
    return _DECIMAL_NAMES[value]
