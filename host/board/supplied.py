"""The lag states a board's table asks the controller to supply (issue 21, table format 7; docs/protocol.md
"Supplied lag states").

A dynamic model fitted with ``--option spindle_states=controller`` does not estimate its lags of the spindle speed,
its square or the feed from the temperatures: those states depend only on the signal's past, and the controller
commands the signal, so its record holds that past exactly. The board's dictionary (``Y``, or Modbus input registers
54-71) names each supplied state's source, time constant and scale; the controller keeps a record of the signals
(:class:`SignalRecord`), computes each lag over it, and sends ``round(lag x 2**scale)``, the board's state units.

The record survives the controller's own restarts (:meth:`SignalRecord.save` / :meth:`SignalRecord.load`): while the
controller is off the machine's spindle is stopped and the axis idle, so the record resumes with both at 0 from the
last moment it was saved. A record is kept for ``horizon_s`` (48 h by default): before it, the lag starts in
equilibrium with the oldest input kept, as the host's model does at the start of the controller's record
(host/learning/empirical/observer.py ``record_lags``); e**(-48 h / 8 h) = 0.25 % of the state is what that forgets
for the longest lag FL_THERMAL's models use.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from typing import Sequence

# the sources a supplied state can read (firmware Evaluator._inputs), in the units the controller measures them
SOURCE_SPINDLE = -1  # |spindle speed|, rpm
SOURCE_SPINDLE_SQUARED = -2  # spindle speed squared, rpm**2
SOURCE_FEED = -3  # |axis feed| while it moves, mm/min
SOURCE_NAMES = {SOURCE_SPINDLE: "spindle rpm", SOURCE_SPINDLE_SQUARED: "spindle rpm squared", SOURCE_FEED: "feed mm/min"}
DEFAULT_HORIZON_S = 48 * 3600.0
RECORD_FORMAT = "tcomp-signal-record-1"


class SupplyError(ValueError):
    """A board's dictionary or a saved record that cannot be used; the message names what and where."""


@dataclass(frozen=True)
class SupplyEntry:
    """One supplied lag state of the board's table: its source (SOURCE_*), time constant (ms) and scale (the state is
    the lag in the source's units x 2**scale)."""
    source: int
    tau_ms: int
    scale: int


def parse_dictionary(fields: Sequence[str]) -> tuple[str, list[SupplyEntry]]:
    """The fields of the board's ``A,Y`` answer to a bare ``Y`` (after the frame kind): ``Y,<state>,<k>`` then
    ``<source>,<tau_ms>,<scale>`` per state -> (state letter: ``-`` none, ``A`` awaited, ``S`` set; the entries)."""
    if len(fields) < 3 or fields[0] != "Y" or fields[1] not in ("-", "A", "S"):
        raise SupplyError("not a supplied-states dictionary (A,Y,<state>,<k>,...): %r" % (list(fields),))
    try:
        k = int(fields[2])
        nums = [int(v) for v in fields[3:]]
    except ValueError:
        raise SupplyError("supplied-states dictionary: a field is not an integer: %r" % (list(fields),)) from None
    if len(nums) != 3 * k:
        raise SupplyError("supplied-states dictionary: %d states need %d fields after the count, found %d" % (k, 3 * k, len(nums)))
    entries = [SupplyEntry(*nums[3 * i:3 * i + 3]) for i in range(k)]
    for i, e in enumerate(entries):
        if e.source not in SOURCE_NAMES or e.tau_ms <= 0:
            raise SupplyError("supplied-states dictionary: state %d has source %d, tau %d ms (sources %s, tau > 0)"
                              % (i, e.source, e.tau_ms, sorted(SOURCE_NAMES), ))
    return fields[1], entries


def modbus_dictionary(regs: Sequence[int]) -> tuple[str, list[SupplyEntry]]:
    """The same from Modbus input registers 54.. (IR_SUPPLY_STATE, IR_SUPPLY_COUNT, 4 registers per state)."""
    from firmware.wire import SUPPLY_DICT_REGS, SUPPLY_LETTERS
    if len(regs) < 2 or not 0 <= regs[0] < len(SUPPLY_LETTERS):
        raise SupplyError("supplied-states registers: state %r" % (regs[:1],))
    k = regs[1]
    if len(regs) < 2 + SUPPLY_DICT_REGS * k:
        raise SupplyError("supplied-states registers: %d states need %d registers, got %d" % (k, 2 + SUPPLY_DICT_REGS * k, len(regs)))

    def s16(v):
        return v - 65536 if v > 32767 else v

    fields = ["Y", SUPPLY_LETTERS[regs[0]], str(k)]
    for i in range(k):
        w = regs[2 + SUPPLY_DICT_REGS * i:2 + SUPPLY_DICT_REGS * (i + 1)]
        fields += [str(s16(w[0])), str((w[1] << 16) | w[2]), str(s16(w[3]))]
    return parse_dictionary(fields)


def _input(source: int, rpm: float, feed: float) -> float:
    if source == SOURCE_SPINDLE:
        return abs(rpm)
    if source == SOURCE_SPINDLE_SQUARED:
        return rpm * rpm
    return abs(feed)


class SignalRecord:
    """The controller's record of the spindle speed (rpm) and the axis feed (mm/min), as the times each changed
    (seconds on a clock that survives restarts: the wall clock), and the lags of it that a board asks for."""

    def __init__(self, horizon_s: float = DEFAULT_HORIZON_S) -> None:
        if not horizon_s > 0:
            raise SupplyError("the signal record's horizon must be > 0 s, got %r" % horizon_s)
        self.horizon_s = float(horizon_s)
        self.events: list[tuple[float, float, float]] = []  # (t, rpm, feed) from t until the next event
        self.last_t: float | None = None  # the latest time the record covers

    def note(self, t: float, rpm: float, feed: float = 0.0) -> None:
        """The signals at time ``t`` (held until the next note): an event is kept only when one of them changed."""
        if not (math.isfinite(t) and math.isfinite(rpm) and math.isfinite(feed)):
            raise SupplyError("signal record: a value is not finite (t %r, rpm %r, feed %r)" % (t, rpm, feed))
        if self.last_t is not None and t < self.last_t:
            raise SupplyError("signal record: time %.3f s is before the record's last %.3f s (one clock, forward)" % (t, self.last_t))
        if not self.events or (self.events[-1][1], self.events[-1][2]) != (rpm, feed):
            self.events.append((float(t), float(rpm), float(feed)))
        self.last_t = float(t)
        self._trim()

    def _trim(self) -> None:
        # keep the event in force at (last_t - horizon) as the record's first: the lag starts in equilibrium with it
        cut = (self.last_t or 0.0) - self.horizon_s
        k = 0
        while k + 1 < len(self.events) and self.events[k + 1][0] <= cut:
            k += 1
        if k:
            del self.events[:k]

    def lag(self, entry: SupplyEntry, t: float) -> float:
        """The first-order lag of ``entry``'s source at ``t`` (exact for the piecewise-constant record: each input held
        until the next event), started in equilibrium with the record's first input."""
        if not self.events:
            raise SupplyError("signal record: empty (no spindle speed or feed noted yet)")
        if self.last_t is not None and t < self.last_t:
            raise SupplyError("signal record: the lag at %.3f s is asked before the record's last %.3f s" % (t, self.last_t))
        tau = entry.tau_ms / 1000.0
        y = _input(entry.source, *self.events[0][1:])
        for i, (t0, rpm, feed) in enumerate(self.events):
            t1 = self.events[i + 1][0] if i + 1 < len(self.events) else t
            u = _input(entry.source, rpm, feed)
            y = u + (y - u) * math.exp(-(t1 - t0) / tau)
        return y

    def values(self, entries: Sequence[SupplyEntry], t: float) -> list[int]:
        """What the controller sends at ``t``: each lag in the board's state units, round(lag x 2**scale)."""
        return [int(round(math.ldexp(self.lag(e, t), e.scale))) for e in entries]

    # --- across the controller's restarts --------------------------------------------------------------------------
    def save(self, path: str) -> None:
        """Write the record to ``path`` atomically (a temporary file beside it, then a rename)."""
        doc = {"format": RECORD_FORMAT, "horizon_s": self.horizon_s, "last_t": self.last_t,
               "events": [list(e) for e in self.events]}
        tmp = "%s.tmp%d" % (path, os.getpid())
        with open(tmp, "w") as fh:
            json.dump(doc, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str, now: float, horizon_s: float = DEFAULT_HORIZON_S) -> "SignalRecord":
        """The record saved at ``path``, resumed at ``now``: the spindle stopped and the axis idle from the record's
        last time (the controller was off). A missing file is an empty record; a file that is not a record, or one
        whose last time is after ``now`` (another clock), is refused naming the file."""
        rec = cls(horizon_s)
        if not os.path.exists(path):
            return rec
        try:
            with open(path) as fh:
                doc = json.load(fh)
        except (OSError, ValueError) as exc:
            raise SupplyError("%s: unreadable signal record (%s)" % (path, exc)) from None
        if not isinstance(doc, dict) or doc.get("format") != RECORD_FORMAT:
            raise SupplyError("%s: not a tcomp signal record (format %r, expected %r)"
                              % (path, doc.get("format") if isinstance(doc, dict) else None, RECORD_FORMAT))
        try:
            events = [(float(t), float(r), float(f)) for t, r, f in doc["events"]]
            last = doc["last_t"]
            last = None if last is None else float(last)
        except (ValueError, KeyError, TypeError) as exc:
            raise SupplyError("%s: unreadable signal record (%s)" % (path, exc)) from None
        if not all(math.isfinite(v) for e in events for v in e) or (last is not None and not math.isfinite(last)):
            raise SupplyError("%s: the signal record holds a value that is not finite" % path)
        if last is None or not events:
            return rec
        if last > now:
            raise SupplyError("%s: the record ends at %.0f s, after now (%.0f s): not the same clock" % (path, last, now))
        if any(b[0] < a[0] for a, b in zip(events, events[1:])) or events[-1][0] > last:
            raise SupplyError("%s: the record's times are not in order" % path)
        rec.events = events
        rec.last_t = float(last)
        rec.note(float(last), 0.0, 0.0)  # the controller went off after its last save: spindle stopped, axis idle
        rec.note(float(now), 0.0, 0.0)
        return rec
