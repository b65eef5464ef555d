"""A run's laser sweeps (errors.csv) written as a laser's long-format export, as examples/import/laser_sweeps.csv lays
it out: a preamble, then one row per measured point (run number, point, target, direction, ISO 8601 date-time, error,
air and material temperature, pressure, humidity). `tcomp import --errors FILE --mapping
examples/import/laser_sweeps.mapping.json --into RUN` reads it back.

What it is for: the commissioning walkthrough (docs/commissioning.md), where the machine is the twin (`tcomp simulate`)
and a simulated board (`tcomp board --run`) plays its temperatures. The laser's side of the test is then the twin's
errors.csv, and this tool gives it the shape and the wall clock a real laser's software would.

    python tools/laser_export.py TWIN_RUN --clock-of RECORDED_RUN --out laser.csv
    python tools/laser_export.py TWIN_RUN --start-time 2026-11-26T08:00:00+01:00 --out laser.csv

Times. Each sweep of errors.csv has one time (its start); its points are written ``--point-s`` seconds apart (a
laser stops at every target), in the order of the file. The date-time of run time ``t`` is ``--start-time`` + t, or,
with ``--clock-of RECORDED_RUN`` (a run `tcomp record` wrote from a `tcomp board --run TWIN_RUN` board), the
recording's clock: its meta.json ``start_time`` is the wall clock of its ``time_s`` 0, when the board's clock read
``record.t_ms_at_time_0``; the board's clock started with the twin run (within its boot, a fraction of a second),
so twin time ``t`` is ``start_time + t - t_ms_at_time_0 / 1000``. Only the sweeps whose every point lies inside
the recording are written (a merge refuses the others); how many were left out, and why, is printed.

Air and material temperature columns are the run's first `ambient` and `base` sensors at the point's time
(empty when the run has none); pressure and humidity are not simulated: the nominal 1013.25 mbar and 50 %,
which the mapping ignores. Direction: the run's `direction` column (+1 Forward, -1 Reverse), Forward without one.
A run with a `channel` column (several probes) is refused: a laser measures one axis.
"""
import argparse
import json
import os
import sys
from datetime import datetime, timedelta

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

HEADER = ("Run", "Point", "Target (mm)", "Direction", "Date/Time", "Error (µm)", "Air temp (°C)", "Material temp (°C)",
          "Pressure (mbar)", "Humidity (%)")
NOMINAL_PRESSURE_MBAR = 1013.25  # not simulated; the mapping ignores the column
NOMINAL_HUMIDITY_PCT = 50


class ExportError(ValueError):
    pass


def _date_time(text, where):
    try:
        t = datetime.fromisoformat(text[:-1] + "+00:00" if text[-1:] in "zZ" else text)
    except (TypeError, ValueError):
        t = None
    if t is None or t.utcoffset() is None:
        raise ExportError("%s %r: not an ISO 8601 date-time with its offset (e.g. 2026-11-26T08:00:00+01:00)"
                          % (where, text))
    return t


def recording_clock(recorded):
    """(the date-time of twin time 0, the recording's span in twin seconds) of a run `tcomp record` wrote."""
    from host.data.runs import RunFormatError, load_run
    path = os.path.join(recorded, "meta.json")
    try:
        with open(path, encoding="utf-8") as fh:
            meta = json.load(fh)
        t0_ms = meta["record"]["t_ms_at_time_0"]
        start = meta["start_time"]
    except (OSError, ValueError) as exc:
        raise ExportError("--clock-of %s: %s" % (recorded, exc))
    except (KeyError, TypeError):
        raise ExportError("--clock-of %s: its meta.json has no start_time and record.t_ms_at_time_0: not a run "
                          "tcomp record wrote" % recorded)
    try:
        rec = load_run(recorded)
    except RunFormatError as exc:
        raise ExportError("--clock-of %s: %s" % (recorded, exc))
    if not isinstance(t0_ms, int) or t0_ms < 0:
        raise ExportError("--clock-of %s: record.t_ms_at_time_0 %r is not a board time in ms" % (recorded, t0_ms))
    origin = _date_time(start, "--clock-of %s: start_time" % recorded) - timedelta(milliseconds=t0_ms)
    t = rec.temperatures.time_s
    return origin, (t0_ms / 1000.0 + float(t[0]), t0_ms / 1000.0 + float(t[-1]))


def export_rows(run, origin, point_s, window=None):
    """(the export's rows, sweeps written, [(sweep time, why left out)])."""
    e = run.errors
    if e.channel is not None:
        raise ExportError("%s: errors.csv has a channel column (several probes); a laser export holds one axis"
                          % run.path)
    air = run.sensors_with_role("ambient")[:1]
    material = run.sensors_with_role("base")[:1]
    rows, left_out = [], []
    n = 0
    for idx in e.sweeps():
        t_first = float(e.time_s[idx[0]])
        times = [t_first + k * point_s for k in range(len(idx))]
        if window is not None and not (window[0] <= times[0] and times[-1] <= window[1]):
            left_out.append((t_first, "its points span %.1f..%.1f s, outside the recording's %.1f..%.1f s"
                             % (times[0], times[-1], window[0], window[1])))
            continue
        n += 1
        for k, (i, t) in enumerate(zip(idx, times)):
            d = 1 if e.direction is None else int(e.direction[i])
            cells = ["%d" % n, "%d" % (k + 1), "%.3f" % e.position_mm[i], "Forward" if d > 0 else "Reverse",
                     (origin + timedelta(seconds=t)).isoformat(timespec="milliseconds"), "%.4f" % e.error_um[i]]
            for names in (air, material):
                cells.append("%.2f" % run.temperatures.at([t], names)[0, 0] if names else "")
            cells += ["%.2f" % NOMINAL_PRESSURE_MBAR, "%d" % NOMINAL_HUMIDITY_PCT]
            rows.append(cells)
    return rows, n, left_out


def write_export(path, run, rows):
    text = ["Linear positioning test export (ISO 230-2 style), written by tools/laser_export.py",
            "Machine,%s,%s axis" % ("tcomp twin", run.meta.get("axis", "X")),
            "Operator,-",
            "Material expansion coefficient (ppm/°C),0.000",
            "Material temperature compensation,off",
            "",
            ",".join(HEADER)]
    text += [",".join(r) for r in rows]
    from host.outputs import Outputs
    with Outputs([run.path]) as out:
        out.file(path, "--out")
        with out.open(path, encoding="utf-8", newline="") as fh:
            fh.write("\n".join(text) + "\n")
        out.commit()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", help="run folder whose errors.csv holds the sweeps (the twin's)")
    clock = ap.add_mutually_exclusive_group(required=True)
    clock.add_argument("--start-time", help="ISO 8601 date-time with offset of the run's time 0")
    clock.add_argument("--clock-of", metavar="RECORDED_RUN",
                       help="a run tcomp record wrote from a board playing RUN: its clock, and only the sweeps "
                            "inside its recording")
    ap.add_argument("--point-s", type=float, default=4.0, help="seconds between two points of a sweep (default 4)")
    ap.add_argument("--out", required=True, help="the export to write (CSV)")
    args = ap.parse_args(argv)

    from host.data.runs import RunFormatError, load_run
    from host.errors import UserError
    try:
        if not (0 <= args.point_s <= 600):
            raise ExportError("--point-s %s: must be 0..600 seconds" % args.point_s)
        run = load_run(args.run)
        if args.clock_of:
            origin, window = recording_clock(args.clock_of)
        else:
            origin, window = _date_time(args.start_time, "--start-time"), None
        rows, n, left_out = export_rows(run, origin, args.point_s, window)
        if not rows:
            raise ExportError("no sweep of %s lies inside the recording %s (%d sweeps: the first %s)"
                              % (args.run, args.clock_of, len(left_out), left_out[0][1] if left_out else "none"))
        write_export(args.out, run, rows)
    except (ExportError, RunFormatError, UserError) as exc:
        print("laser_export: error: %s" % exc, file=sys.stderr)
        return 2
    print("%s: %d sweeps, %d points%s" % (args.out, n, len(rows),
                                           "; %d sweeps left out (outside the recording)" % len(left_out)
                                           if left_out else ""))
    for t, why in left_out:
        print("  left out: the sweep at run time %.1f s: %s" % (t, why))
    return 0


if __name__ == "__main__":
    sys.exit(main())
