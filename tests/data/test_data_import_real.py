"""tcomp import on what instruments really write: dialects, date-times, gaps, units, long-format sweeps.

Expected values are written out by hand (212 degF is 100 degC, one inch is 25 400 um, a CET wall clock
is UTC + 1 h), never computed with the importer's own tables."""
import json
import os

import numpy as np
import pytest

from host.data.importer import LogImportError, import_csv, import_errors

TWO = {"time": "t", "temperatures": ["a"], "errors": ["d"]}


def _file(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return str(p)


# ------------------------------------------------------------------ dialect


def test_semicolon_decimal_comma_file_imports_and_says_what_was_detected(tmp_path):
    src = _file(tmp_path, "t;a;d\n0;20,5;1,25\n15;21;-2,5\n")
    run = import_csv(src, TWO)
    np.testing.assert_array_equal(run.temperatures.values[:, 0], [20.5, 21.0])
    np.testing.assert_array_equal(run.errors.error_um, [1.25, -2.5])
    assert run.meta["import"]["dialect"] == {"delimiter": ";", "decimal": ",", "detected": ["delimiter", "decimal"]}


def test_tab_separated_file_is_detected(tmp_path):
    run = import_csv(_file(tmp_path, "t\ta\td\n0\t20.5\t1\n1\t21\t2\n"), TWO)
    assert run.meta["import"]["dialect"]["delimiter"] == "\t"


def test_plain_csv_records_no_dialect(tmp_path):
    """A file of the run format's own plain CSV imports to the meta.json it always did (FL_THERMAL stays byte-identical)."""
    run = import_csv(_file(tmp_path, "t,a,d\n0,20.5,1\n1,21,2\n"), TWO)
    assert "dialect" not in run.meta["import"]
    assert run.dialect == {"delimiter": ",", "decimal": ".", "detected": ["delimiter", "decimal"]}


def test_ambiguous_delimiter_is_refused_naming_both(tmp_path):
    src = _file(tmp_path, "t;a,d\n0;20,1\n1;21,2\n")
    with pytest.raises(LogImportError, match=r"line 1: ambiguous delimiter: the file splits consistently at comma and at semicolon"):
        import_csv(src, TWO)
    run = import_csv(src, dict(TWO, delimiter=";", decimal=",", temperatures=["a,d"], errors=[], ignore=[]))
    assert run.temperatures.names == ["a,d"]


def test_ambiguous_decimal_is_refused_naming_a_cell_of_each(tmp_path):
    src = _file(tmp_path, "t;a;d\n0;20,5;1\n1;21;2.5\n")
    with pytest.raises(LogImportError, match=r"line 2 column 'a' has '20,5' \(decimal comma\) and line 3 column 'd' has '2.5'"):
        import_csv(src, TWO)


def test_no_delimiter_fits(tmp_path):
    src = _file(tmp_path, "t;a;d\n0;20;1\n1;21\n")
    with pytest.raises(LogImportError, match=r"cannot tell how the cells are separated.*line 3 has 2"):
        import_csv(src, TWO)


def test_declared_decimal_point_names_a_comma_cell(tmp_path):
    src = _file(tmp_path, "t;a;d\n0;20,5;1\n")
    with pytest.raises(LogImportError, match=r"line 2 column 'a': not a number: '20,5' \(a decimal comma\?"):
        import_csv(src, dict(TWO, decimal="."))


def test_thousands_separator_in_a_decimal_comma_file_is_refused(tmp_path):
    src = _file(tmp_path, "t;a;d\n0;20,5;1.250,5\n")
    with pytest.raises(LogImportError, match=r"line 2 column 'd': not a number: '1.250,5' \(a '.' in a file whose decimal separator is ','"):
        import_csv(src, dict(TWO, decimal=","))


def test_unknown_delimiter_setting(tmp_path):
    with pytest.raises(LogImportError, match="delimiter '|'"):
        import_csv(_file(tmp_path, "t,a,d\n0,1,2\n"), dict(TWO, delimiter="|"))


# ------------------------------------------------------------------ date-times


def test_iso_timestamps_with_offsets_across_a_daylight_saving_change(tmp_path):
    # 02:30 CEST (+02:00) then 02:15 CET (+01:00) is 45 min later, though the wall clock went back
    src = _file(tmp_path, "t,a,d\n2026-10-25T02:30:00+02:00,20,1\n2026-10-25T02:15:00+01:00,20,1\n2026-10-25T01:20:00Z,20,1\n")
    run = import_csv(src, dict(TWO, time_format="iso8601"))
    np.testing.assert_array_equal(run.temperatures.time_s, [0, 2700, 3000])
    assert run.meta["start_time"] == "2026-10-25T00:30:00Z"
    assert run.meta["import"]["time"] == {"format": "iso8601", "start_time": "2026-10-25T00:30:00Z"}


def test_naive_timestamps_need_a_declared_clock(tmp_path):
    src = _file(tmp_path, "t,a,d\n2026-11-26 08:00:00,20,1\n2026-11-26 08:00:15,20,1\n")
    with pytest.raises(LogImportError, match=r"the timestamps carry no time zone \(.*line 2 column 't'\); declare the logger's clock"):
        import_csv(src, dict(TWO, time_format="iso8601"))
    run = import_csv(src, dict(TWO, time_format="iso8601", timezone="Europe/Berlin"))
    np.testing.assert_array_equal(run.temperatures.time_s, [0, 15])
    assert run.meta["start_time"] == "2026-11-26T07:00:00Z"
    assert import_csv(src, dict(TWO, time_format="iso8601", timezone="-05:00")).meta["start_time"] == "2026-11-26T13:00:00Z"


def test_a_repeated_wall_clock_hour_is_refused(tmp_path):
    src = _file(tmp_path, "t,a,d\n2026-10-25 01:50:00,20,1\n2026-10-25 02:10:00,20,1\n")
    with pytest.raises(LogImportError, match=r"line 3 column 't': 2026-10-25 02:10:00 is ambiguous or does not exist in Europe/Berlin"):
        import_csv(src, dict(TWO, time_format="iso8601", timezone="Europe/Berlin"))


def test_mixed_offsets_and_none_are_refused(tmp_path):
    src = _file(tmp_path, "t,a,d\n2026-11-26T08:00:00+01:00,20,1\n2026-11-26T08:00:15,20,1\n")
    with pytest.raises(LogImportError, match=r"line 3 column 't': lacks a time-zone offset, unlike the first timestamp"):
        import_csv(src, dict(TWO, time_format="iso8601"))
    aware = _file(tmp_path, "t,a,d\n2026-11-26T08:00:00+01:00,20,1\n", "b.csv")
    with pytest.raises(LogImportError, match=r"\"timezone\" 'UTC' is declared, but the timestamps carry their own offsets"):
        import_csv(aware, dict(TWO, time_format="iso8601", timezone="UTC"))


def test_date_times_without_time_format_say_so_once(tmp_path):
    src = _file(tmp_path, "t,a,d\n" + "".join("2026-11-26T08:%02d:00Z,20,1\n" % k for k in range(60)))
    with pytest.raises(LogImportError) as exc:
        import_csv(src, TWO)
    assert str(exc.value).count("\n") == 0 and "line 2 column 't': not a number: '2026-11-26T08:00:00Z'" in str(exc.value)
    assert "the time column holds date-times: declare \"time_format\"" in str(exc.value)


def test_strptime_format_and_a_bad_cell(tmp_path):
    src = _file(tmp_path, "t;a;d\n26.11.2026 08:00:00;20;1\n26.11.2026 08:01:30;20;1\n")
    fmt = dict(TWO, time_format="%d.%m.%Y %H:%M:%S", timezone="UTC")
    np.testing.assert_array_equal(import_csv(src, fmt).temperatures.time_s, [0, 90])
    bad = _file(tmp_path, "t;a;d\n26.11.2026 08:00:00;20;1\n2026-11-26 08:01;20;1\n", "bad.csv")
    with pytest.raises(LogImportError, match=r"bad.csv line 3 column 't': '2026-11-26 08:01' is not a date-time in the format"):
        import_csv(bad, fmt)
    with pytest.raises(LogImportError, match="'time_scale' and 'time_format' both given"):
        import_csv(src, dict(fmt, time_scale=60))


# ------------------------------------------------------------------ gaps


GAPPY = "t,a,b,d\n0,20,30,1\n10,,32,2\n20,22,,3\n30,23,36,4\n"
GAPPY_MAP = {"time": "t", "temperatures": ["a", "b"], "errors": ["d"]}


def test_a_gap_is_refused_by_default_naming_file_line_and_column(tmp_path):
    src = _file(tmp_path, GAPPY)
    with pytest.raises(LogImportError) as exc:
        import_csv(src, GAPPY_MAP)
    assert "log.csv line 3 column 'a': empty cell (a gap)" in str(exc.value)
    assert "log.csv line 4 column 'b': empty cell (a gap)" in str(exc.value)


def test_gaps_drop_counts_the_rows(tmp_path):
    run = import_csv(_file(tmp_path, GAPPY), dict(GAPPY_MAP, gaps="drop"))
    np.testing.assert_array_equal(run.temperatures.time_s, [0, 30])
    assert run.meta["import"]["gaps"] == {"policy": "drop", "rows_dropped": 2, "empty_cells": {"a": 1, "b": 1}, "lines": [3, 4]}


def test_gaps_interpolate_in_time(tmp_path):
    run = import_csv(_file(tmp_path, GAPPY), dict(GAPPY_MAP, gaps="interpolate"))
    np.testing.assert_array_equal(run.temperatures.column("a"), [20, 21, 22, 23])  # 10 s between 20 (0 s) and 22 (20 s)
    np.testing.assert_array_equal(run.temperatures.column("b"), [30, 32, 34, 36])
    assert run.meta["import"]["gaps"]["cells_interpolated"] == {"a": 1, "b": 1}


def test_interpolate_refuses_an_end_gap_and_a_time_gap(tmp_path):
    with pytest.raises(LogImportError, match=r"line 2 column 'a': empty cell before the first or after the last value"):
        import_csv(_file(tmp_path, "t,a,d\n0,,1\n10,21,2\n"), dict(TWO, gaps="interpolate"))
    with pytest.raises(LogImportError, match=r"line 3 column 't': empty cell in the time column"):
        import_csv(_file(tmp_path, "t,a,d\n0,20,1\n,21,2\n", "b.csv"), dict(TWO, gaps="interpolate"))


# ------------------------------------------------------------------ units


def test_a_mm_column_without_a_unit_is_refused_suggesting_it(tmp_path):
    src = _file(tmp_path, "t,a,ch1_mm\n0,20,0.0015\n1,21,0.0025\n")
    m = {"time": "t", "temperatures": ["a"], "errors": ["ch1_mm"]}
    with pytest.raises(LogImportError, match=r"error column 'ch1_mm' has no declared unit, and its name says mm .*\"unit\": \"mm\""):
        import_csv(src, m)
    run = import_csv(src, dict(m, errors={"ch1_mm": {"unit": "mm"}}))
    np.testing.assert_allclose(run.errors.error_um, [1.5, 2.5])
    assert run.meta["channels"]["ch1_mm"] == {"source_column": "ch1_mm", "position_mm": 0.0, "scale": 1000.0, "unit": "mm"}
    # the name may be wrong: a declared unit wins
    np.testing.assert_allclose(import_csv(src, dict(m, errors={"ch1_mm": {"unit": "um"}})).errors.error_um, [0.0015, 0.0025])


def test_temperature_units_convert(tmp_path):
    src = _file(tmp_path, "t,f,k,d\n0,212,293.15,1\n1,32,273.15,1\n")
    run = import_csv(src, {"time": "t", "temperatures": {"f": {"unit": "°F"}, "k": {"unit": "K"}}, "errors": ["d"]})
    np.testing.assert_allclose(run.temperatures.column("f"), [100, 0], atol=1e-12)
    np.testing.assert_allclose(run.temperatures.column("k"), [20, 0], atol=1e-12)
    assert run.meta["import"]["temperature_units"] == {"f": "degF", "k": "K"}
    with pytest.raises(LogImportError, match=r"temperature column 'T1 \[°F\]' has no declared unit, and its name says degF"):
        import_csv(_file(tmp_path, "t,T1 [°F],d\n0,70,1\n", "f.csv"), {"time": "t", "temperatures": ["T1 [°F]"], "errors": ["d"]})


def test_out_of_range_after_conversion_names_the_raw_cell(tmp_path):
    src = _file(tmp_path, "t,a,d\n0,20,1\n1,21,12\n")
    with pytest.raises(LogImportError, match=r"line 3 column 'd': 12 is outside -10000..10000 um"):
        import_csv(src, dict(TWO, errors={"d": {"unit": "in"}}))  # 12 in = 304 800 um


def test_time_units(tmp_path):
    src = _file(tmp_path, "time_min,a,d\n0,20,1\n1.5,21,2\n")
    m = {"time": "time_min", "temperatures": ["a"], "errors": ["d"]}
    with pytest.raises(LogImportError, match=r"time column 'time_min' has no declared unit, and its name says min"):
        import_csv(src, m)
    np.testing.assert_array_equal(import_csv(src, dict(m, time_unit="min")).temperatures.time_s, [0, 90])
    np.testing.assert_array_equal(import_csv(src, dict(m, time_unit="h")).temperatures.time_s, [0, 5400])
    with pytest.raises(LogImportError, match="give 'time_unit' or 'time_scale', not both"):
        import_csv(src, dict(m, time_unit="min", time_scale=60))


def test_a_unit_and_a_scale_factor_would_convert_twice(tmp_path):
    src = _file(tmp_path, "t,a,d\n0,20,1\n")
    with pytest.raises(LogImportError, match=r"has a unit \('mm'\) and scale 1000: the unit converts already"):
        import_csv(src, dict(TWO, errors={"d": {"unit": "mm", "scale": 1000}}))
    np.testing.assert_array_equal(import_csv(src, dict(TWO, errors={"d": {"unit": "mm", "scale": -1}})).errors.error_um, [-1000])


# ------------------------------------------------------------------ no defaults leak


def test_no_axis_or_location_unless_declared(tmp_path):
    src = _file(tmp_path, "t,a,d\n0,20,1\n")
    run = import_csv(src, TWO)
    assert "axis" not in run.meta
    assert run.meta["sensors"] == {"a": {"role": "structure"}}
    run = import_csv(src, dict(TWO, temperatures={"a": {"location": "nut"}}, meta={"axis": "Y"}))
    assert run.meta["axis"] == "Y" and run.meta["sensors"]["a"] == {"role": "structure", "location": "nut"}


# ------------------------------------------------------------------ long-format sweeps


LASER = ("Run;Target (mm);Dir;Time;Error (µm)\n"
         "1;0;Fwd;2026-11-26T08:00:00Z;0\n1;350;Fwd;2026-11-26T08:00:05Z;1,5\n1;700;Fwd;2026-11-26T08:00:10Z;3\n"
         "1;700;Rev;2026-11-26T08:00:15Z;2\n1;350;Rev;2026-11-26T08:00:20Z;0,5\n1;0;Rev;2026-11-26T08:00:25Z;-1\n"
         "2;0;Fwd;2026-11-26T08:20:00Z;0\n2;350;Fwd;2026-11-26T08:20:05Z;2,5\n2;700;Fwd;2026-11-26T08:20:10Z;5\n")
LASER_MAP = {"layout": "long", "time": "Time", "time_format": "iso8601", "sweep": "Run",
             "position": {"column": "Target (mm)", "unit": "mm"}, "error": {"column": "Error (µm)", "unit": "um"},
             "direction": {"column": "Dir", "values": {"Fwd": 1, "Rev": -1}}}


def test_long_format_sweeps(tmp_path):
    s = import_errors(_file(tmp_path, LASER), LASER_MAP)
    e = s.errors
    # one time per sweep: its first point's, relative to the file's first sample
    np.testing.assert_array_equal(e.time_s, [0, 0, 0, 15, 15, 15, 1200, 1200, 1200])
    np.testing.assert_array_equal(e.position_mm, [0, 350, 700, 700, 350, 0, 0, 350, 700])
    np.testing.assert_array_equal(e.error_um, [0, 1.5, 3, 2, 0.5, -1, 0, 2.5, 5])
    np.testing.assert_array_equal(e.direction, [1, 1, 1, -1, -1, -1, 1, 1, 1])
    assert len(e.sweeps()) == 3 and s.record["sweeps"] == 3 and s.start_time == "2026-11-26T08:00:00Z"
    np.testing.assert_array_equal(s.point_time_s, [0, 5, 10, 15, 20, 25, 1200, 1205, 1210])


def test_long_format_without_a_run_column_splits_where_the_pass_starts_over(tmp_path):
    text = "\n".join(line.split(";", 1)[1] for line in LASER.splitlines()) + "\n"
    mapping = {k: v for k, v in LASER_MAP.items() if k != "sweep"}
    # run 2 follows run 1's reverse pass with a forward one: the direction changes
    assert len(import_errors(_file(tmp_path, text), mapping).errors.sweeps()) == 3
    uni = "Target (in);Time;Error (µm)\n0;0;0\n10;5;1\n20;10;2\n0;60;0\n10;65;2\n20;70;4\n"
    s = import_errors(_file(tmp_path, uni, "uni.csv"), {"layout": "long", "time": "Time", "position": {"column": "Target (in)", "unit": "in"},
                                                      "error": {"column": "Error (µm)"}})
    np.testing.assert_array_equal(s.errors.time_s, [0, 0, 0, 60, 60, 60])
    np.testing.assert_allclose(s.errors.position_mm, [0, 254, 508, 0, 254, 508])


def test_long_format_problems_name_the_cell(tmp_path):
    with pytest.raises(LogImportError, match=r"line 3 column 'Dir': direction 'fwd' is not one of the declared values"):
        import_errors(_file(tmp_path, LASER.replace("350;Fwd", "350;fwd", 1)), LASER_MAP)
    with pytest.raises(LogImportError, match=r"line 8 column 'Run': run '1' direction \+1 appears again after other rows"):
        import_errors(_file(tmp_path, LASER.replace("2;0;Fwd", "1;0;Fwd", 1), "b.csv"), LASER_MAP)
    with pytest.raises(LogImportError, match=r"position column 'Target \(in\)' has no declared unit, and its name says in"):
        import_errors(_file(tmp_path, "Target (in);Time;E\n0;0;0\n", "c.csv"),
                      {"layout": "long", "time": "Time", "position": {"column": "Target (in)"}, "error": {"column": "E"}})


def test_a_long_layout_is_not_a_run(tmp_path):
    with pytest.raises(LogImportError, match=r"a long layout holds error sweeps.*tcomp import --errors"):
        import_csv(_file(tmp_path, LASER), LASER_MAP)


# ------------------------------------------------------------------ the bundled examples


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLES = os.path.join(ROOT, "examples", "import")


def _tcomp(*argv):
    from host.cli import main

    return main(list(argv))


def test_example_semicolon_logger_imports_and_validates(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert _tcomp("import", os.path.join(EXAMPLES, "logger_semicolon.csv"), "--mapping",
                  os.path.join(EXAMPLES, "logger_semicolon.mapping.json"), "--out", out) == 0
    said = capsys.readouterr().out
    assert "cells split at semicolon (declared), decimal comma (declared)" in said and "1 empty cells interpolated" in said
    assert _tcomp("validate", out) == 0
    meta = json.load(open(os.path.join(out, "meta.json")))
    assert meta["start_time"] == "2026-11-26T07:00:00Z"  # 08:00 in Berlin, CET
    from host.data.runs import load_run

    run = load_run(out)
    assert abs(run.errors.error_um[-1] - 31.8) < 1e-9  # the last probe cell, '0,0318' mm
    assert run.temperatures.time_s[-1] == 3600


def test_example_laser_sweeps_merge_into_the_iso_logger_run(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert _tcomp("import", os.path.join(EXAMPLES, "logger_iso.csv"), "--mapping", os.path.join(EXAMPLES, "logger_iso.mapping.json"),
                  "--out", out) == 0
    assert "1 rows dropped (empty cells: air_degF 1)" in capsys.readouterr().out
    assert json.load(open(os.path.join(out, "meta.json")))["errors_pending"] is True  # temperatures only: the sweeps come later
    assert _tcomp("import", "--errors", os.path.join(EXAMPLES, "laser_sweeps.csv"), "--mapping",
                  os.path.join(EXAMPLES, "laser_sweeps.mapping.json"), "--into", out) == 0
    assert "12 sweeps (96 points), clock aligned by start times" in capsys.readouterr().out
    assert _tcomp("validate", out) == 0
    from host.data.runs import load_run

    run = load_run(out)
    assert run.temperatures.column("T_nut")[0] == 20.0  # 68.00 degF
    assert sorted({float(t) for t in run.errors.time_s})[:2] == [120.0, 152.0]  # 08:02:00 and 08:02:32 local, the run started 08:00
    assert run.meta["axis"] == "X" and run.error_reference == "start" and "errors_pending" not in run.meta


def test_a_preamble_is_skipped_by_header_line_and_lines_keep_their_numbers(tmp_path):
    src = _file(tmp_path, "Export of logger 7\nOperator,A. B.; C\n\nt;a;d\n0;20;1\n1;x;2\n")
    with pytest.raises(LogImportError, match=r"log.csv line 6 column 'a': not a number: 'x'"):
        import_csv(src, dict(TWO, header_line=4))
    with pytest.raises(LogImportError, match=r"log.csv line 1: cannot tell how the cells are separated"):
        import_csv(src, TWO)
    with pytest.raises(LogImportError, match=r"no line 9 \(the declared header_line\)"):
        import_csv(src, dict(TWO, header_line=9))
    ok = _file(tmp_path, "Export of logger 7\n\nt;a;d\n0;20;1\n", "ok.csv")
    assert import_csv(ok, dict(TWO, header_line=3)).meta["import"]["header_line"] == 3


def test_start_time_is_given_by_date_times_or_declared_as_one(tmp_path):
    src = _file(tmp_path, "t,a,d\n0,20,1\n60,21,2\n")
    assert import_csv(src, dict(TWO, meta={"start_time": "2026-11-26T07:00:00Z"})).meta["start_time"] == "2026-11-26T07:00:00Z"
    with pytest.raises(LogImportError, match=r"meta 'start_time': '2026-11-26 07:00' carries no time-zone offset"):
        import_csv(src, dict(TWO, meta={"start_time": "2026-11-26 07:00"}))
    stamped = _file(tmp_path, "t,a,d\n2026-11-26T08:00:00+01:00,20,1\n", "s.csv")
    with pytest.raises(LogImportError, match=r"meta 'start_time' is declared, but the time column's date-times give it"):
        import_csv(stamped, dict(TWO, time_format="iso8601", meta={"start_time": "2026-11-26T07:00:00Z"}))
    with pytest.raises(LogImportError, match=r"meta 'start_time' belongs to the run"):
        import_errors(_file(tmp_path, LASER, "l.csv"), dict(LASER_MAP, meta={"start_time": "2026-11-26T07:00:00Z"}))


def test_the_run_format_checks_start_time(tmp_path):
    from host.data.runs import RunFormatError, load_run, write_run

    run = import_csv(_file(tmp_path, "t,a,d\n0,20,1\n"), TWO)
    run.meta["start_time"] = "yesterday"
    write_run(run, str(tmp_path / "run"))
    with pytest.raises(RunFormatError, match=r"meta.json: key 'start_time' must be an ISO 8601 date-time with its offset"):
        load_run(str(tmp_path / "run"))
