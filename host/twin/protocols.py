"""Thermal-test protocols: moving states, measurement sweeps, cool-down.

A protocol is a sequence of phases; a phase either reciprocates the nut between
two positions at a feed or leaves the axis idle. Every ``sweep_every_min`` the
axis stops for ``sweep_duration_min`` while the laser interferometer measures a
sweep of target positions (ISO 230-2 style), whatever the phase; the first sweep
is the cold state at t = 0, the last one ends the run.

The literature states (e.g. the ball-screw tests that fit on 8000 mm/min over
210-490 mm and predict the other feeds and ranges) are named
``v<feed>_r<from>_<to>``: three hours of warm-up then two of cool-down.

``random`` is a random moving state (a sequence of states of random feed,
range and length with random dwells); its phases are drawn from the run's seed
by :func:`draw_phases` (``concrete``).

``s004-table2`` is the ball-screw paper's compensation test (S004 Table 2): four
moving states in sequence with a laser sweep after each, not on a clock
(``sweeps_after_phases``). A user's own schedule of that kind is a CSV file
(:func:`read_protocol_csv`, ``tcomp simulate --protocol FILE.csv``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING
import csv
import os
from dataclasses import dataclass

import numpy as np

if TYPE_CHECKING:
    from host.twin.axis import AxisParams


@dataclass(frozen=True)
class Phase:
    minutes: float
    feed_mm_min: float = 0.0  # 0 = idle
    from_mm: float = 0.0
    to_mm: float = 0.0


@dataclass(frozen=True)
class Protocol:
    name: str
    description: str
    phases: tuple
    start_hour: float = 9.0  # wall-clock hour of t = 0, sets the ambient's phase of the day
    drawn: bool = False  # True: the phases are drawn from the seed (concrete())
    # True: a sweep at t = 0 and one after every phase, the axis stopped for each (S004 Table 2), instead of
    # a sweep every sweep_every_min across the phases
    sweeps_after_phases: bool = False
    source: str = ""  # the CSV file a user's protocol was read from ("" for the built-in ones)
    source_lines: tuple = ()  # the file's line of each phase (error messages name it)

    @property
    def minutes(self) -> float:
        """The phases' minutes (without the stops of sweeps_after_phases, see duration_s)."""
        return sum(p.minutes for p in self.phases)

    def duration_s(self, params: AxisParams) -> float:
        """Length of the run: the phases, plus one sweep stop per phase when the sweeps follow the phases."""
        extra = len(self.phases) * params.sweep_duration_min * 60.0 if self.sweeps_after_phases else 0.0
        return self.minutes * 60.0 + extra


def _state(feed, a, b, start_hour, warm=180.0, cool=120.0):
    return Protocol(
        "v%d_r%d_%d" % (feed, a, b),
        "%d mm/min over %d-%d mm for %g min, then %g min cool-down" % (feed, a, b, warm, cool),
        (Phase(warm, feed, a, b), Phase(cool)),
        start_hour,
    )


PROTOCOLS = {
    p.name: p
    for p in (
        _state(8000, 210, 490, 9.0),
        _state(6500, 210, 490, 11.0),
        _state(15000, 210, 490, 10.0),
        _state(8000, 0, 210, 13.0),
        _state(8000, 0, 700, 14.0),
        Protocol(
            "mixed",
            "changing states: 8000 mm/min 210-490, 15000 mm/min 0-700, idle, 6500 mm/min 0-210, cool-down",
            (Phase(60, 8000, 210, 490), Phase(60, 15000, 0, 700), Phase(30), Phase(60, 6500, 0, 210), Phase(90)),
            12.0,
        ),
        Protocol(
            "day24h",
            "24 h from 06:00: two shifts of changing states with breaks, then evening and night at rest (soak tests)",
            (Phase(60), Phase(120, 8000, 0, 700), Phase(30), Phase(60, 15000, 210, 490), Phase(120, 6500, 0, 210),
             Phase(60), Phase(180, 8000, 210, 490), Phase(60, 15000, 0, 700), Phase(750)),
            6.0,
        ),
        Protocol(
            "random",
            "random moving states drawn from the seed for 240 min (feed 2000-15000 mm/min, range >= 100 mm, "
            "10-40 min each, 0-15 min dwells), then 60 min cool-down",
            (Phase(300),),
            9.0,
            drawn=True,
        ),
        Protocol(
            "idle",
            "no motion for 8 h from 10:00 to 18:00: the ambient's day-to-evening drift alone",
            (Phase(480),),
            10.0,
        ),
        Protocol(
            "s004-table2",
            "S004 Table 2 compensation test: 8000 mm/min over 0-280 mm for 6 min, 5000 over 490-700 for 10, "
            "10000 over 240-450 for 5, 12000 over 0-700 for 2; a laser sweep at the start and after each state",
            (Phase(6, 8000, 0, 280), Phase(10, 5000, 490, 700), Phase(5, 10000, 240, 450), Phase(2, 12000, 0, 700)),
            9.0,
            sweeps_after_phases=True,
        ),
    )
}
CSV_HEADER = ("duration_min", "feed_mm_min", "from_mm", "to_mm")

LITERATURE_STATES = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490", "v8000_r0_210", "v8000_r0_700")


RANDOM_MOVING_MIN = 240.0
RANDOM_COOL_MIN = 60.0


def draw_phases(rng: np.random.Generator, stroke_mm: float) -> tuple[Phase, ...]:
    """Random moving states for RANDOM_MOVING_MIN minutes, then a cool-down.

    Each state: 10-40 min (whole minutes) at a feed of 2000-15000 mm/min (steps of
    500) over a range of at least 100 mm inside the stroke (10 mm grid), followed
    by a dwell of 0-15 min (whole minutes, none when 0).
    """
    if stroke_mm < 100:
        raise ValueError("protocol 'random' draws ranges of at least 100 mm: the stroke (%g mm) is shorter" % stroke_mm)
    phases, used = [], 0.0
    while used < RANDOM_MOVING_MIN:
        minutes = float(rng.integers(10, 41))
        feed = float(rng.integers(4, 31) * 500)
        length = float(rng.integers(10, int(stroke_mm // 10) + 1) * 10)
        length = min(length, stroke_mm)
        start = float(rng.integers(0, int((stroke_mm - length) // 10) + 1) * 10)
        dwell = float(rng.integers(0, 16))
        minutes = min(minutes, RANDOM_MOVING_MIN - used)
        phases.append(Phase(minutes, feed, start, start + length))
        used += minutes
        if dwell > 0 and used < RANDOM_MOVING_MIN:
            dwell = min(dwell, RANDOM_MOVING_MIN - used)
            phases.append(Phase(dwell))
            used += dwell
    phases.append(Phase(RANDOM_COOL_MIN))
    return tuple(phases)


def concrete(protocol: Protocol, rng: np.random.Generator, stroke_mm: float) -> Protocol:
    """``protocol`` with its phases drawn from ``rng`` (a ``drawn`` template) or unchanged.

    The result keeps ``drawn=True`` so the run records its phases (meta.json).
    """
    if not protocol.drawn:
        return protocol
    return Protocol(protocol.name, protocol.description, draw_phases(rng, stroke_mm), protocol.start_hour, drawn=True)


def read_protocol_csv(path: str, start_hour: float = 9.0) -> Protocol:
    """A user's schedule: header ``duration_min,feed_mm_min,from_mm,to_mm``, one row per state (feed 0: idle,
    its range is not used), a laser sweep at the start and after every row. The protocol is named after the
    file (its name without .csv). ValueError names the file, line and column of the first problem."""
    name = os.path.splitext(os.path.basename(path))[0]
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise ValueError("protocol file %s: file is missing" % path)
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError("protocol file %s: cannot be read (%s)" % (path, exc))
    rows = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    if not rows:
        raise ValueError("protocol file %s: empty; expected the header %s and one row per state" % (path, ",".join(CSV_HEADER)))
    line, head = rows[0]
    if tuple(c.strip() for c in head) != CSV_HEADER:
        raise ValueError("protocol file %s line %d: header must be %s, found %s" % (path, line, ",".join(CSV_HEADER), ",".join(head)))
    if len(rows) < 2:
        raise ValueError("protocol file %s: no state after the header" % path)
    phases = []
    for line, r in rows[1:]:
        if len(r) != len(CSV_HEADER):
            raise ValueError("protocol file %s line %d: %d cells, expected %d (%s)" % (path, line, len(r), len(CSV_HEADER), ",".join(CSV_HEADER)))
        vals = []
        for col, (key, cell) in enumerate(zip(CSV_HEADER, r)):
            try:
                v = float(cell)
            except ValueError:
                raise ValueError("protocol file %s line %d column %d (%s): not a number: %r" % (path, line, col + 1, key, cell))
            if v != v or v in (float("inf"), float("-inf")):
                raise ValueError("protocol file %s line %d column %d (%s): not a finite number: %r" % (path, line, col + 1, key, cell))
            vals.append(v)
        dur, feed, a, b = vals
        if not dur > 0:
            raise ValueError("protocol file %s line %d column 1 (duration_min): must be > 0, found %g" % (path, line, dur))
        if feed < 0:
            raise ValueError("protocol file %s line %d column 2 (feed_mm_min): must be >= 0 (0: idle), found %g" % (path, line, feed))
        phases.append(Phase(dur, feed, a, b) if feed > 0 else Phase(dur))
    lines = [line for line, _ in rows[1:]]
    return Protocol(name, "from %s: %d states, a laser sweep at the start and after each" % (path, len(phases)), tuple(phases),
                    start_hour, sweeps_after_phases=True, source=path, source_lines=tuple(lines))


def check_protocol(protocol: Protocol, stroke_mm: float) -> None:
    problems = []
    if not protocol.phases:
        problems.append("protocol %r has no phases" % protocol.name)
    for i, ph in enumerate(protocol.phases):
        where = ("protocol file %s line %d" % (protocol.source, protocol.source_lines[i]) if protocol.source_lines
                 else "protocol %r phase %d" % (protocol.name, i + 1))
        if not ph.minutes > 0:
            problems.append("%s: minutes must be > 0 (found %g)" % (where, ph.minutes))
        if ph.feed_mm_min < 0:
            problems.append("%s: feed must be >= 0 (found %g)" % (where, ph.feed_mm_min))
        if ph.feed_mm_min > 0:
            if not (0 <= ph.from_mm <= stroke_mm and 0 <= ph.to_mm <= stroke_mm):
                problems.append("%s: range %g-%g mm is outside the stroke 0..%g mm" % (where, ph.from_mm, ph.to_mm, stroke_mm))
            if ph.from_mm == ph.to_mm:
                problems.append("%s: range %g-%g mm is empty" % (where, ph.from_mm, ph.to_mm))
    if problems:
        raise ValueError("; ".join(problems))


def schedule(protocol: Protocol, params: AxisParams) -> tuple[np.ndarray, np.ndarray]:
    """Sweep times and motion intervals of ``protocol``.

    Returns (sweep_times_s, motion) with motion an (k, 5) array of rows
    t_start_s, t_end_s, from_mm, to_mm, feed_mm_min: the moving phases with the
    sweep windows cut out.
    """
    check_protocol(protocol, params.stroke_mm)
    total = protocol.minutes * 60.0
    every = params.sweep_every_min * 60.0
    busy = params.sweep_duration_min * 60.0
    if protocol.sweeps_after_phases:
        # the cold sweep at 0, then each phase after the previous sweep's stop, a sweep at its end
        sweeps, rows, t0 = [0.0], [], busy
        for ph in protocol.phases:
            t1 = t0 + ph.minutes * 60.0
            if ph.feed_mm_min > 0:
                rows.append((t0, t1, ph.from_mm, ph.to_mm, ph.feed_mm_min))
            sweeps.append(t1)
            t0 = t1 + busy
        return np.asarray(sweeps, dtype=float), np.asarray(rows, dtype=float).reshape(-1, 5)
    n = int(np.floor(total / every + 1e-9))
    sweeps = [k * every for k in range(n + 1)]
    if total - sweeps[-1] > 1e-6:
        sweeps.append(total)
    windows = [(s, s + busy) for s in sweeps]
    rows = []
    t0 = 0.0
    for ph in protocol.phases:
        t1 = t0 + ph.minutes * 60.0
        if ph.feed_mm_min > 0:
            cuts = [t0]
            for a, b in windows:
                if b <= t0 or a >= t1:
                    continue
                cuts.extend([max(a, t0), min(b, t1)])
            cuts.append(t1)
            for a, b in zip(cuts[0::2], cuts[1::2]):
                if b - a > 1e-6:
                    rows.append((a, b, ph.from_mm, ph.to_mm, ph.feed_mm_min))
        t0 = t1
    motion = np.asarray(rows, dtype=float).reshape(-1, 5)
    return np.asarray(sweeps, dtype=float), motion


def resolve_protocols(spec: str | Protocol) -> list[Protocol]:
    """Protocols from 'all', 'literature', a name, a CSV file (``*.csv``, :func:`read_protocol_csv`) or a
    comma-separated list of those."""
    if isinstance(spec, Protocol):
        return [spec]
    names, files = [], {}
    for part in str(spec).split(","):
        part = part.strip()
        if part.lower().endswith(".csv"):
            proto = read_protocol_csv(part)
            if proto.name in PROTOCOLS or proto.name in files:
                raise ValueError("protocol file %s: its name %r is already a protocol; rename the file" % (part, proto.name))
            files[proto.name] = proto
            names.append(proto.name)
        elif part == "all":
            names.extend(PROTOCOLS)
        elif part == "literature":
            names.extend(LITERATURE_STATES)
        elif part in PROTOCOLS:
            names.append(part)
        elif part:
            raise ValueError("unknown protocol %r; known: %s (or 'all', 'literature', or a FILE.csv)" % (part, ", ".join(PROTOCOLS)))
    if not names:
        raise ValueError("no protocol given; known: %s (or 'all', 'literature', or a FILE.csv)" % ", ".join(PROTOCOLS))
    seen = []
    for n in names:
        if n not in seen:
            seen.append(n)
    return [files[n] if n in files else PROTOCOLS[n] for n in seen]
