"""An instrument's error sweeps merged into an existing run folder by time (``tcomp import --errors FILE --into RUN``).

The run (recorded by ``tcomp record``, or imported from a logger) has the temperatures; the laser's software
wrote the sweeps with its own clock. The clocks are aligned one declared way, never guessed:

- ``clock_offset_s`` given: run ``time_s`` = the file's time + offset. A file of numbers keeps its times as they
  are (x its unit); a file of date-times counts from its first sample, so the offset is the run time of that sample.
- otherwise both clocks must be wall clocks: the file's date-times and the run's date-time of time 0: ``meta.json``
  ``start_time`` (written by ``tcomp import`` of a date-time log and by ``tcomp record``, docs/recording.md).

Every sweep must lie inside the run's temperature record (a model reads the temperatures at each sweep's
time; outside it they would be extrapolated); those that do not are refused by line and time.
The run is re-validated with its new errors.csv and meta.json before anything is written.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from typing import Any

import numpy as np

from host.data import logfile
from host.data.importer import LogImportError, import_errors
from host.data.logfile import LogFileError
from host.data.runs import ERRORS, META, MOTION, SPINDLE, START, TEMPERATURES, Errors, RunFormatError, load_run, write_errors, write_meta


def run_start_time(meta: dict[str, Any]) -> tuple[Any, str]:
    """(the wall clock of the run's time 0, the meta.json key holding it) or (None, "start_time").

    ``start_time``: written by tcomp import of a date-time log and by tcomp record (docs/recording.md)."""
    return meta.get("start_time"), "start_time"


def _alignment(sweeps, run, clock_offset_s, source):
    """(offset_s, how) with run time_s = file time_s + offset_s."""
    meta_path = os.path.join(run.path, META)
    run_start, start_key = run_start_time(run.meta)
    if clock_offset_s is not None:
        if sweeps.start_time is not None and run_start is not None:
            raise LogImportError("%s and %s both carry wall-clock times (its date-times, '%s' %s): they align the clocks; "
                                 "drop --clock-offset, or it would override them" % (source, meta_path, start_key, run_start))
        return float(clock_offset_s), "declared offset (--clock-offset)"
    if sweeps.start_time is None:
        raise LogImportError("%s: its times are numbers, not date-times, so nothing ties its clock to the run's; declare the offset "
                             "(--clock-offset S: run time_s = the file's time + S)" % source)
    if run_start is None:
        raise LogImportError("%s has no 'start_time' (the date-time of run time 0), so the "
                             "date-times of %s cannot be placed in it; "
                             "declare the offset (--clock-offset S: the run time_s of the file's first sample)" % (meta_path, source))
    try:
        t0 = logfile.parse_utc(run_start, "%s '%s'" % (meta_path, start_key))
        first = logfile.parse_utc(sweeps.start_time, source)
    except LogFileError as exc:
        raise LogImportError(str(exc))
    return (first - t0).total_seconds(), "start times (%s '%s' %s, %s first sample %s)" % (
        META, start_key, run_start, os.path.basename(source), sweeps.start_time)


def _check_overlap(sweeps, run, offset_s, source):
    """Every sweep inside the run's temperatures; else LogImportError naming each sweep outside (lines, times)."""
    t = run.temperatures.time_s
    lo, hi = float(t[0]), float(t[-1])
    point = sweeps.point_time_s + offset_s
    outside = []
    for rows in sweeps.groups():
        a, b = point[rows].min(), point[rows].max()
        if a < lo or b > hi:
            outside.append("%s lines %d-%d: a sweep at run time %.3f..%.3f s" % (source, sweeps.lines[rows].min(), sweeps.lines[rows].max(), a, b))
    if not outside:
        return
    tpath = os.path.join(run.path, TEMPERATURES)
    if len(outside) == len(sweeps.groups()):
        raise LogImportError("%s spans run time %.3f..%.3f s and %s %.3f..%.3f s: they do not overlap (a wrong clock offset or "
                             "start_time?)" % (source, point.min(), point.max(), tpath, lo, hi))
    shown = outside[:20] + (["... and %d more sweeps" % (len(outside) - 20)] if len(outside) > 20 else [])
    raise LogImportError("\n".join(shown) + "\nlie outside the run's temperatures (%s, %.3f..%.3f s): a model would read "
                         "extrapolated temperatures there; cut them from the file or record longer" % (tpath, lo, hi))


def _merge_errors(old, new, run_errors_path):
    if old is None:
        return new
    for col, a, b in (("direction", old.direction, new.direction), ("channel", old.channel, new.channel)):
        if (a is None) != (b is None):
            raise LogImportError("%s has %s '%s' column and the merged sweeps %s; one errors.csv has one layout (map \"%s\" in the "
                                 "mapping%s)" % (run_errors_path, "a" if a is not None else "no", col,
                                                 "do not" if a is not None else "do", col,
                                                 "" if col == "direction" else ", the name of the instrument's channel"))
    key = lambda e, i: (e.time_s[i], None if e.channel is None else e.channel[i], None if e.direction is None else int(e.direction[i]))  # noqa: E731
    existing = {key(old, i) for i in range(len(old))}
    clash = [i for i in range(len(new)) if key(new, i) in existing]
    if clash:
        raise LogImportError("%s already holds a sweep at time %.3f s%s: the merged file would join it (already merged?)"
                             % (run_errors_path, new.time_s[clash[0]], "" if new.channel is None else " channel %s" % new.channel[clash[0]]))
    cat = lambda a, b: None if a is None else np.concatenate([a, b])  # noqa: E731
    time_s = np.concatenate([old.time_s, new.time_s])
    order = np.argsort(time_s, kind="stable")
    pick = lambda a: None if a is None else a[order]  # noqa: E731
    # position and error are never None (cat/pick pass a None through, for direction and channel)
    return Errors(time_s[order], np.concatenate([old.position_mm, new.position_mm])[order],
                  np.concatenate([old.error_um, new.error_um])[order],
                  pick(cat(old.direction, new.direction)), pick(cat(old.channel, new.channel)))


def _merge_meta(run, sweeps, record, source, mapping_where):
    meta = dict(run.meta)
    meta.pop("errors_pending", None)  # the sweeps have come
    has_errors = run.errors is not None and len(run.errors) > 0
    for k, v in sweeps.meta.items():
        current = meta.get(k, START if (k == "error_reference" and has_errors) else None)
        if current is not None and current != v:
            raise LogImportError("%s: meta %r is %r but %s says %r%s" % (
                mapping_where, k, v, os.path.join(run.path, META), current,
                " (the run's errors.csv already holds errors of that reference)" if k == "error_reference" else ""))
        meta[k] = v
    meta["error_imports"] = list(meta.get("error_imports", [])) + [record]
    return meta


def merge_into(run_folder: str, source: str, mapping: Any, stage: str, mapping_where: str = "mapping",
               clock_offset_s: float | None = None) -> tuple[dict[str, Any], Errors]:
    """Merge the sweeps of ``source`` into the run ``run_folder``; write its new errors.csv and meta.json into the
    folder ``stage`` (the caller renames them into place). Returns (summary dict, merged Errors)."""
    try:
        run = load_run(run_folder)
    except RunFormatError as exc:
        raise LogImportError("%s: not a valid run to merge into:\n%s" % (run_folder, exc))
    sweeps = import_errors(source, mapping, mapping_where)
    offset, how = _alignment(sweeps, run, clock_offset_s, source)
    _check_overlap(sweeps, run, offset, source)
    new = sweeps.errors
    new = Errors(new.time_s + offset, new.position_mm, new.error_um, new.direction, new.channel)
    old = run.errors if run.errors is not None and len(run.errors) else None  # a header-only errors.csv holds no layout yet
    merged = _merge_errors(old, new, os.path.join(run_folder, ERRORS))
    record = dict(sweeps.record, clock={"offset_s": offset, "aligned_by": how})
    meta = _merge_meta(run, sweeps, record, source, mapping_where)
    write_errors(merged, os.path.join(stage, ERRORS), decimals=6)
    write_meta(meta, os.path.join(stage, META))
    _validate(run_folder, stage)
    return dict(record, into=run_folder, rows_before=0 if old is None else len(old), rows_after=len(merged)), merged


def _validate(run_folder, stage):
    """The run as it will be once committed (its other files with the staged ones) loads without a problem."""
    check = tempfile.mkdtemp(prefix="tcomp-merge-check-")
    try:
        for f in (TEMPERATURES, MOTION, SPINDLE):
            if os.path.exists(os.path.join(run_folder, f)):
                shutil.copyfile(os.path.join(run_folder, f), os.path.join(check, f))
        for f in (ERRORS, META):
            shutil.copyfile(os.path.join(stage, f), os.path.join(check, f))
        try:
            load_run(check)
        except RunFormatError as exc:
            raise LogImportError("%s would not validate after the merge:\n%s" % (run_folder, str(exc).replace(check, run_folder)))
    finally:
        shutil.rmtree(check, ignore_errors=True)
