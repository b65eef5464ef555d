"""tcomp import --errors FILE --into RUN: sweeps merged into a run by time, clocks aligned one declared way."""
import json
import os

import numpy as np
import pytest

from host.data.importer import LogImportError, import_to_folder
from host.data.merge import merge_into
from host.data.runs import load_run

# a run of temperatures only, 08:00..09:00 CET (07:00..08:00 UTC), one sample every 10 min
LOG = "time,T1,T2\n" + "".join("2026-11-26T08:%02d:00+01:00,%d,20\n" % (m, 20 + m // 10) for m in range(0, 60, 10)) \
      + "2026-11-26T09:00:00+01:00,26,20\n"
LOG_MAP = {"time": "time", "time_format": "iso8601", "temperatures": {"T1": {"role": "nut"}, "T2": {"role": "ambient"}}}
SWEEPS = "when,x,e\n{0}:00Z,0,0\n{0}:05Z,100,1.5\n{1}:00Z,0,0\n{1}:05Z,100,2.5\n"
SWEEPS_MAP = {"layout": "long", "time": "when", "time_format": "iso8601", "position": {"column": "x", "unit": "mm"},
              "error": {"column": "e", "unit": "um"}}


def _run(tmp_path, log=LOG, mapping=LOG_MAP):
    src = tmp_path / "log.csv"
    src.write_text(log)
    out = str(tmp_path / "run")
    import_to_folder(str(src), mapping, out)
    return out


def _sweeps(tmp_path, first="2026-11-26T07:10", second="2026-11-26T07:40", text=None, name="laser.csv"):
    p = tmp_path / name
    p.write_text(text if text is not None else SWEEPS.format(first, second))
    return str(p)


def _merge(run, src, mapping=SWEEPS_MAP, offset=None):
    stage = os.path.join(run, ".stage")
    os.makedirs(stage, exist_ok=True)
    summary, _ = merge_into(run, src, mapping, stage, "laser.json", offset)
    for f in os.listdir(stage):
        os.replace(os.path.join(stage, f), os.path.join(run, f))
    os.rmdir(stage)
    return summary


def test_start_times_align_the_clocks(tmp_path):
    run = _run(tmp_path)
    summary = _merge(run, _sweeps(tmp_path))
    r = load_run(run)
    # 07:10 UTC is 10 min after the run's 07:00 UTC start; 07:40 is 40 min after
    np.testing.assert_array_equal(r.errors.time_s, [600, 600, 2400, 2400])
    np.testing.assert_array_equal(r.errors.error_um, [0, 1.5, 0, 2.5])
    assert summary["clock"]["offset_s"] == 600 and summary["clock"]["aligned_by"].startswith("start times")
    assert r.meta["error_imports"][0]["sweeps"] == 2


def test_a_declared_offset_aligns_a_file_of_numbers(tmp_path):
    run = _run(tmp_path)
    src = _sweeps(tmp_path, text="t,x,e\n5,0,0\n9,100,1\n")
    m = dict(SWEEPS_MAP, time="t")
    del m["time_format"]
    with pytest.raises(LogImportError, match=r"laser.csv: its times are numbers, not date-times.*--clock-offset S"):
        _merge(run, src, m)
    _merge(run, src, m, offset=1000)
    np.testing.assert_array_equal(load_run(run).errors.time_s, [1005, 1005])  # the sweep's first point, 5 s + 1000 s


def test_date_times_and_an_offset_together_are_refused(tmp_path):
    run = _run(tmp_path)
    with pytest.raises(LogImportError, match=r"both carry wall-clock times.*drop --clock-offset"):
        _merge(run, _sweeps(tmp_path), offset=10)


def test_a_run_without_start_time_needs_the_offset(tmp_path):
    log = "t,T1\n0,20\n3600,21\n"
    run = _run(tmp_path, log, {"time": "t", "temperatures": ["T1"]})
    with pytest.raises(LogImportError, match=r"meta.json has no 'start_time'.*--clock-offset S"):
        _merge(run, _sweeps(tmp_path))
    _merge(run, _sweeps(tmp_path), offset=100)  # the file's first sample at run time 100 s
    np.testing.assert_array_equal(load_run(run).errors.time_s, [100, 100, 1900, 1900])


def test_sweeps_outside_the_temperatures_are_refused_by_line(tmp_path):
    run = _run(tmp_path)
    with pytest.raises(LogImportError) as exc:
        _merge(run, _sweeps(tmp_path, second="2026-11-26T08:00"))  # its second point is 08:00:05 UTC, after the run's end
    assert "laser.csv lines 4-5: a sweep at run time 3600.000..3605.000 s" in str(exc.value)
    assert "lie outside the run's temperatures" in str(exc.value) and "0.000..3600.000 s" in str(exc.value)
    with pytest.raises(LogImportError, match=r"laser.csv spans run time -3000.000..-1195.000 s and .*temperatures.csv 0.000..3600.000 s: "
                                             r"they do not overlap"):
        _merge(run, _sweeps(tmp_path, "2026-11-26T06:10", "2026-11-26T06:40"))
    assert not os.path.exists(os.path.join(run, "errors.csv")) or open(os.path.join(run, "errors.csv")).read().count("\n") == 1


def test_sweeps_merge_with_the_run_errors_and_refuse_a_second_merge(tmp_path):
    run = _run(tmp_path)
    _merge(run, _sweeps(tmp_path))
    _merge(run, _sweeps(tmp_path, "2026-11-26T07:20", "2026-11-26T07:30", name="b.csv"))
    r = load_run(run)
    np.testing.assert_array_equal(r.errors.time_s, [600, 600, 1200, 1200, 1800, 1800, 2400, 2400])
    assert [i["source"] for i in r.meta["error_imports"]] == ["laser.csv", "b.csv"]
    with pytest.raises(LogImportError, match=r"errors.csv already holds a sweep at time 600.000 s.*already merged"):
        _merge(run, _sweeps(tmp_path))


def test_layouts_and_references_that_differ_are_refused(tmp_path):
    run = _run(tmp_path)
    _merge(run, _sweeps(tmp_path))
    bi = _sweeps(tmp_path, text="when,x,e,d\n2026-11-26T07:20:00Z,0,0,1\n", name="bi.csv")
    with pytest.raises(LogImportError, match=r"errors.csv has no 'direction' column and the merged sweeps do"):
        _merge(run, bi, dict(SWEEPS_MAP, direction="d"))
    later = _sweeps(tmp_path, "2026-11-26T07:20", "2026-11-26T07:30", name="c.csv")
    with pytest.raises(LogImportError, match=r"meta 'error_reference' is 'T2' but .*meta.json says 'start' \(the run's errors.csv already"):
        _merge(run, later, dict(SWEEPS_MAP, meta={"error_reference": "T2"}))


def test_a_merge_that_would_not_validate_writes_nothing(tmp_path):
    run = _run(tmp_path, mapping=dict(LOG_MAP, meta={"stroke_mm": 50}))
    before = {f: open(os.path.join(run, f)).read() for f in os.listdir(run)}
    with pytest.raises(LogImportError, match=r"would not validate after the merge:\n.*run/errors.csv line 3 column 'position_mm': "
                                             r"position 100 mm is outside the stroke 0..50 mm"):
        _merge(run, _sweeps(tmp_path))
    assert {f: open(os.path.join(run, f)).read() for f in os.listdir(run) if f != ".stage"} == before


def test_the_temperature_record_is_untouched(tmp_path):
    run = _run(tmp_path)
    with open(os.path.join(run, "temperatures.csv")) as fh:
        before = fh.read()
    _merge(run, _sweeps(tmp_path))
    with open(os.path.join(run, "temperatures.csv")) as fh:
        assert fh.read() == before
    assert json.load(open(os.path.join(run, "meta.json")))["start_time"] == "2026-11-26T07:00:00Z"


def test_a_recording_is_aligned_by_its_start_time(tmp_path):
    """A run written by tcomp record: errors.csv's header only, errors_pending, the wall clock in start_time."""
    run = _run(tmp_path, "t,T1\n0,20\n3600,21\n", {"time": "t", "temperatures": ["T1"]})
    meta_path = os.path.join(run, "meta.json")
    meta = json.load(open(meta_path))
    assert meta["errors_pending"] is True and open(os.path.join(run, "errors.csv")).read() == "time_s,position_mm,error_um\n"
    meta["start_time"] = "2026-11-26T07:00:00.250+00:00"
    with open(meta_path, "w") as fh:
        json.dump(meta, fh)
    summary = _merge(run, _sweeps(tmp_path))
    assert summary["clock"]["aligned_by"].startswith("start times (meta.json 'start_time'")
    r = load_run(run)
    np.testing.assert_array_equal(r.errors.time_s, [599.75, 599.75, 2399.75, 2399.75])
    assert "errors_pending" not in r.meta
