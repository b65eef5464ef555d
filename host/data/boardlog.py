"""A board's offset log, read into run time: what `tcomp check` compares a check measurement against.

Two layouts are read (docs/check.md):

- ``tcomp monitor --csv`` output (columns ``kind``, ``t_ms``, ``pos_um``, ``total_um``): the board's O and Q
  frames; other frames (H, A, E, ...) carry no offset and are skipped. ``t_ms`` is the board's tick counter,
  so the caller must say which tick was run time 0 (``board_t0_ms``); the counter's wrap at 2^30 ms
  (docs/protocol.md) is unwrapped, a tick that goes back by less than half the wrap is refused as a reset.
- an aligned log with columns ``time_s``, ``position_mm``, ``offset_um`` (run time, axis position, the board's
  offset), a log already put on the run's clock;
- the JSON `tcomp hil --json` writes: its ``answers`` (``time_s``, ``position_mm``, ``offset_um``) are the
  firmware's offsets at every errors.csv row of the run it played, on that run's clock.

Nothing is guessed: a missing column, a cell that is not a number or a time that goes backwards is a
``BoardLogError`` naming the file and line.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from host.data.runs import CsvSyntaxError, parse_number, read_records

T_MS_WRAP = 1 << 30  # the firmware's tick counter wraps here (docs/protocol.md, "time stamp t_ms")
MONITOR_COLUMNS = ("kind", "t_ms", "pos_um", "total_um")
ALIGNED_COLUMNS = ("time_s", "position_mm", "offset_um")
OFFSET_KINDS = ("O", "Q")  # the frames that carry an offset


class BoardLogError(ValueError):
    pass


@dataclass
class BoardLog:
    time_s: np.ndarray  # run time of each offset
    position_mm: np.ndarray  # the axis position the board computed the offset for
    offset_um: np.ndarray  # the board's offset (the predicted error with its sign, docs/protocol.md)
    layout: str  # "monitor" or "aligned"

    def __len__(self) -> int:
        return self.time_s.size


def _number(path, line, column, cell):
    try:
        v = parse_number(cell.strip())
    except ValueError:
        raise BoardLogError("%s line %d: %s %r is not a number" % (path, line, column, cell))
    if not math.isfinite(v):
        raise BoardLogError("%s line %d: %s %r is not a finite number" % (path, line, column, cell))
    return v


def _read_hil_json(path, fh):
    import json

    try:
        doc = json.load(fh)
    except json.JSONDecodeError as exc:
        raise BoardLogError("%s line %d column %d: invalid JSON (%s)" % (path, exc.lineno, exc.colno, exc.msg))
    answers = doc.get("answers") if isinstance(doc, dict) else None
    if not isinstance(answers, list) or not answers:
        raise BoardLogError("%s: a JSON board log is tcomp hil --json output, with a non-empty list 'answers'" % path)
    cols = {k: [] for k in ALIGNED_COLUMNS}
    for i, a in enumerate(answers):
        for k in ALIGNED_COLUMNS:
            v = a.get(k) if isinstance(a, dict) else None
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise BoardLogError("%s: answers[%d].%s is %r, not a finite number (the board gave no offset there?)"
                                    % (path, i, k, v))
            cols[k].append(float(v))
        if i and cols["time_s"][-1] < cols["time_s"][-2]:
            raise BoardLogError("%s: answers[%d].time_s %g goes back from %g; the log must be in time order"
                                % (path, i, cols["time_s"][-1], cols["time_s"][-2]))
    return BoardLog(np.asarray(cols["time_s"]), np.asarray(cols["position_mm"]), np.asarray(cols["offset_um"]), "hil")


def read_board_log(path: str, board_t0_ms: float | None = None) -> BoardLog:
    """The offsets of a board log on the run's clock (see the module doc); BoardLogError names what is wrong."""
    if path.lower().endswith(".json"):
        if board_t0_ms is not None:
            raise BoardLogError("%s is tcomp hil output, already on the run's clock: --board-t0-ms does not apply" % path)
        try:
            with open(path, encoding="utf-8") as fh:
                return _read_hil_json(path, fh)
        except (OSError, UnicodeDecodeError) as exc:
            raise BoardLogError("%s: cannot be read (%s)" % (path, getattr(exc, "strerror", None) or exc))
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            records = read_records(fh, path)
    except FileNotFoundError:
        raise BoardLogError("%s: file is missing" % path)
    except IsADirectoryError:
        raise BoardLogError("%s: is a folder, expected a board log CSV" % path)
    except UnicodeDecodeError:
        raise BoardLogError("%s: not a text file (expected a board log CSV)" % path)
    except CsvSyntaxError as exc:
        raise BoardLogError(str(exc))
    except OSError as exc:
        raise BoardLogError("%s: cannot be read (%s)" % (path, exc.strerror or exc))
    if not records:
        raise BoardLogError("%s: empty (expected a header line)" % path)
    header = [c.strip() for c in records[0][1]]
    if all(c in header for c in ALIGNED_COLUMNS):
        layout, columns = "aligned", ALIGNED_COLUMNS
    elif all(c in header for c in MONITOR_COLUMNS):
        layout, columns = "monitor", MONITOR_COLUMNS
    else:
        raise BoardLogError("%s line 1: header %s has neither the columns of tcomp monitor --csv (%s) nor those of an "
                            "aligned log (%s)" % (path, ",".join(header), ",".join(MONITOR_COLUMNS), ",".join(ALIGNED_COLUMNS)))
    if layout == "monitor" and board_t0_ms is None:
        raise BoardLogError("%s is a tcomp monitor log (board ticks t_ms): give --board-t0-ms, the board's t_ms at "
                            "run time 0, so its offsets can be put on the run's clock" % path)
    col = {c: header.index(c) for c in columns}
    t, p, o = [], [], []
    wraps, last_tick, last_line = 0, None, None
    for line, cells in records[1:]:
        if not cells or all(not c.strip() for c in cells):
            continue
        if len(cells) != len(header):
            raise BoardLogError("%s line %d: %d cells, the header has %d" % (path, line, len(cells), len(header)))
        if layout == "monitor":
            if cells[col["kind"]].strip() not in OFFSET_KINDS:
                continue
            tick = _number(path, line, "t_ms", cells[col["t_ms"]])
            if last_tick is not None and tick < last_tick:
                if last_tick - tick > T_MS_WRAP // 2:
                    wraps += 1  # the counter wrapped
                else:
                    raise BoardLogError("%s line %d: t_ms %d is %d ms before line %d's %d (a board reset? a log of two "
                                        "sessions?); check one session at a time" % (path, line, tick, last_tick - tick,
                                                                                     last_line, last_tick))
            last_tick, last_line = tick, line
            assert board_t0_ms is not None  # a monitor log without it was refused above
            t.append((tick + wraps * T_MS_WRAP - board_t0_ms) / 1000.0)
            p.append(_number(path, line, "pos_um", cells[col["pos_um"]]) / 1000.0)
            o.append(_number(path, line, "total_um", cells[col["total_um"]]))
        else:
            time_s = _number(path, line, "time_s", cells[col["time_s"]])
            if t and time_s < t[-1]:
                raise BoardLogError("%s line %d: time_s %g goes back from %g (line %d); the log must be in time order"
                                    % (path, line, time_s, t[-1], last_line))
            last_line = line
            t.append(time_s)
            p.append(_number(path, line, "position_mm", cells[col["position_mm"]]))
            o.append(_number(path, line, "offset_um", cells[col["offset_um"]]))
    if not t:
        raise BoardLogError("%s: no offsets (%s)" % (path, "no O or Q frame" if layout == "monitor" else "no data line"))
    return BoardLog(np.asarray(t), np.asarray(p), np.asarray(o), layout)


def offsets_at(log: BoardLog, time_s: np.ndarray, position_mm: np.ndarray, max_dt_s: float, position_tol_mm: float,
               where: str) -> np.ndarray:
    """The board's offset for each (time, position) measured: the log entry nearest in time among those at the
    position (within ``position_tol_mm``) and within ``max_dt_s``. BoardLogError names the first row without one."""
    out = np.empty(len(time_s))
    span = "%.6g..%.6g s" % (log.time_s[0], log.time_s[-1])
    for i, (t, x) in enumerate(zip(time_s, position_mm)):
        at = np.flatnonzero(np.abs(log.position_mm - x) <= position_tol_mm)
        if at.size == 0:
            raise BoardLogError("%s row %d (time %.6g s, position %.6g mm): the board log has no offset at this position "
                                "(within %g mm; --position-tol-mm); was the check run measured with this board and log?"
                                % (where, i + 1, t, x, position_tol_mm))
        dt = np.abs(log.time_s[at] - t)
        k = int(np.argmin(dt))
        if dt[k] > max_dt_s:
            raise BoardLogError("%s row %d (time %.6g s, position %.6g mm): the nearest board offset at this position is "
                                "%.6g s away (limit %g s, --max-dt-s); the log spans %s on the run's clock: is "
                                "--board-t0-ms right, and does the log cover the check?" % (where, i + 1, t, x, dt[k],
                                                                                           max_dt_s, span))
        out[i] = log.offset_um[at[k]]
    return out
