"""Reading a published correlation matrix and per-sensor target correlations from CSV.

CORR.csv: a header row of sensor names, then the square matrix, one row per
sensor in header order. Rows may start with the sensor's name (then the header
may have an extra first cell such as ``sensor`` or be empty there); the names
must then match the header order.

TCORR.csv: one ``sensor,r`` row per sensor. A header line is optional: the first
line is taken as a header when its second cell is not a number (e.g. ``sensor,r``).
"""

from __future__ import annotations

from collections.abc import Sequence

import csv

import numpy as np

from host.learning.empirical.selectors.common import SelectionError


def _rows(path):
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = [[c.strip() for c in row] for row in csv.reader(fh)]
    except FileNotFoundError:
        raise SelectionError("%s: file is missing" % path)
    except (OSError, UnicodeDecodeError) as exc:
        raise SelectionError("%s: cannot be read (%s)" % (path, exc))
    # keep line numbers: blank lines are reported, trailing ones are ignored
    while rows and not any(rows[-1]):
        rows.pop()
    if not rows:
        raise SelectionError("%s: file is empty" % path)
    return rows


def _number(cell, path, line, col):
    try:
        v = float(cell)
    except ValueError:
        raise SelectionError("%s line %d column %d: not a number: %r" % (path, line, col, cell))
    if not np.isfinite(v):
        raise SelectionError("%s line %d column %d: %r is not a finite number" % (path, line, col, cell))
    return v


def _is_number(cell):
    try:
        float(cell)
        return True
    except ValueError:
        return False


def read_corr_csv(path: str) -> tuple[np.ndarray, list[str]]:
    """-> (matrix (p, p), names)."""
    rows = _rows(path)
    header, body = rows[0], rows[1:]
    if not body:
        raise SelectionError("%s: no matrix rows after the header" % path)
    for i, row in enumerate(body, start=2):
        if not any(row):
            raise SelectionError("%s line %d: blank line inside the matrix" % (path, i))
    labelled = not _is_number(body[0][0])
    names = header[1:] if labelled and len(header) == len(body[0]) else header
    p = len(names)
    empty = [i + 1 for i, n in enumerate(names) if not n]
    if empty:
        raise SelectionError("%s line 1: empty sensor name in column %d" % (path, empty[0] + (len(header) - p)))
    if len(set(names)) != p:
        raise SelectionError("%s line 1: sensor name(s) %s appear more than once" % (path, ", ".join(sorted({n for n in names if names.count(n) > 1}))))
    if len(body) != p:
        raise SelectionError("%s: %d sensor names in the header but %d matrix rows; the matrix must be square" % (path, p, len(body)))
    M = np.empty((p, p))
    for i, row in enumerate(body):
        line = i + 2
        cells = row
        if labelled:
            if row[0] != names[i]:
                raise SelectionError("%s line %d: row is labelled %r but the header's sensor %d is %r" % (path, line, row[0], i + 1, names[i]))
            cells = row[1:]
        if len(cells) != p:
            raise SelectionError("%s line %d: %d values, expected %d (one per sensor in the header)" % (path, line, len(cells), p))
        for j, cell in enumerate(cells):
            M[i, j] = _number(cell, path, line, j + 1 + int(labelled))
    return M, names


def read_target_corr_csv(path: str, names: Sequence[str]) -> dict[str, float]:
    """-> {name: r} for exactly the sensors in ``names``."""
    rows = _rows(path)
    start = 0
    if len(rows[0]) >= 2 and not _is_number(rows[0][1]):
        start = 1
    out = {}
    for i, row in enumerate(rows[start:], start=start + 1):
        if not any(row):
            raise SelectionError("%s line %d: blank line" % (path, i))
        if len(row) != 2:
            raise SelectionError("%s line %d: expected 2 cells 'sensor,r', got %d" % (path, i, len(row)))
        name, cell = row
        if name not in names:
            raise SelectionError("%s line %d: sensor %r is not in the correlation matrix (%s)" % (path, i, name, ",".join(names)))
        if name in out:
            raise SelectionError("%s line %d: sensor %r appears a second time" % (path, i, name))
        r = _number(cell, path, i, 2)
        if abs(r) > 1.0 + 1e-9:
            raise SelectionError("%s line %d: r = %g is outside [-1, 1]" % (path, i, r))
        out[name] = r
    missing = [n for n in names if n not in out]
    if missing:
        raise SelectionError("%s: no target correlation for sensor(s) %s" % (path, ", ".join(missing)))
    return out
