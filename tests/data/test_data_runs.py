"""The run-folder format tcomp-run/1: round trip and every validation error."""
import os
import subprocess
import sys

import numpy as np
import pytest

from host.data.runs import RunFormatError, check_run, load_run, write_run


@pytest.mark.parametrize("bidirectional,channels", [(False, None), (True, None), (False, ["ch1", "ch2"])])
def test_round_trip(tmp_path, bidirectional, channels, make_run):
    run = make_run(bidirectional, channels)
    folder = write_run(run, str(tmp_path / "r"))
    back = load_run(folder)
    assert back.meta["operator_extra"] == {"kept": True}, "unknown meta keys are kept"
    assert back.temperatures.names == run.temperatures.names
    np.testing.assert_allclose(back.temperatures.values, run.temperatures.values, atol=5e-5)
    np.testing.assert_allclose(back.errors.error_um, run.errors.error_um, atol=5e-5)
    np.testing.assert_array_equal(back.errors.position_mm, run.errors.position_mm)
    if bidirectional:
        np.testing.assert_array_equal(back.errors.direction, run.errors.direction)
    else:
        assert back.errors.direction is None
    if channels:
        assert back.errors.channels() == channels
    np.testing.assert_array_equal(back.motion.feed_mm_min, run.motion.feed_mm_min)
    assert back.sensors_with_role("nut") == ["T1"]


def test_sweeps_group_by_time_and_direction(tmp_path, make_run):
    back = load_run(write_run(make_run(bidirectional=True), str(tmp_path / "r")))
    sweeps = back.errors.sweeps()
    assert len(sweeps) == 8 * 2
    for rows in sweeps:
        assert np.unique(back.errors.time_s[rows]).size == 1
        assert np.unique(back.errors.direction[rows]).size == 1


def _problems(folder):
    with pytest.raises(RunFormatError) as exc:
        load_run(folder)
    return exc.value.problems


def test_missing_column_names_file_and_line(run_dir, edit_csv):
    edit_csv(run_dir, "errors.csv", lambda ls: [ls[0].replace("position_mm", "pos")] + ls[1:])
    probs = _problems(run_dir)
    assert any("errors.csv line 1" in p and "missing column 'position_mm'" in p for p in probs), probs


def test_non_numeric_cell_names_line_and_column(run_dir, edit_csv):
    def bad(ls):
        cells = ls[5].split(",")
        cells[2] = "abc"
        ls[5] = ",".join(cells)
        return ls

    edit_csv(run_dir, "temperatures.csv", bad)
    probs = _problems(run_dir)
    assert any("temperatures.csv line 6 column 'T2'" in p and "not a number: 'abc'" in p for p in probs), probs


def test_nan_rejected(run_dir, edit_csv):
    def bad(ls):
        cells = ls[3].split(",")
        cells[1] = "nan"
        ls[3] = ",".join(cells)
        return ls

    edit_csv(run_dir, "temperatures.csv", bad)
    probs = _problems(run_dir)
    assert any("line 4 column 'T1'" in p and "not a finite number" in p for p in probs), probs


def test_time_going_backwards(run_dir, edit_csv):
    def bad(ls):
        ls[10], ls[11] = ls[11], ls[10]
        return ls

    edit_csv(run_dir, "temperatures.csv", bad)
    probs = _problems(run_dir)
    assert any("temperatures.csv line 12 column 'time_s'" in p and "backwards" in p for p in probs), probs


def test_errors_time_backwards(run_dir, edit_csv):
    def bad(ls):
        ls.append("0,100,1.0")
        return ls

    edit_csv(run_dir, "errors.csv", bad)
    probs = _problems(run_dir)
    assert any("errors.csv line" in p and "backwards" in p for p in probs), probs


def test_sensor_not_in_meta(run_dir, edit_meta):
    edit_meta(run_dir, lambda m: m["sensors"].pop("T4"))
    probs = _problems(run_dir)
    assert any("temperatures.csv line 1 column 5" in p and "'T4' is not declared in meta.json" in p for p in probs), probs


def test_position_outside_stroke(run_dir, edit_csv):
    edit_csv(run_dir, "errors.csv", lambda ls: ls + ["7199,750,1.0"])
    probs = _problems(run_dir)
    assert any("column 'position_mm'" in p and "750 mm is outside the stroke 0..700" in p for p in probs), probs


def test_bad_role_and_format(run_dir, edit_meta):
    def bad(m):
        m["format"] = "other/2"
        m["sensors"]["T1"]["role"] = "spindle-ish"

    edit_meta(run_dir, bad)
    probs = _problems(run_dir)
    assert any("key 'format'" in p for p in probs)
    assert any("sensors.T1.role is 'spindle-ish'" in p for p in probs)


def test_invalid_json_names_line(run_dir):
    with open(os.path.join(run_dir, "meta.json"), "w") as fh:
        fh.write('{"format": "tcomp-run/1",\n  "sensors": }\n')
    probs = _problems(run_dir)
    assert any("meta.json line 2" in p and "invalid JSON" in p for p in probs), probs


def test_missing_file_and_all_problems_reported(run_dir, edit_csv):
    os.remove(os.path.join(run_dir, "errors.csv"))
    edit_csv(run_dir, "temperatures.csv", lambda ls: ls[:3] + ["60.5,x,1,2,3"] + ls[3:])
    probs = _problems(run_dir)
    assert any("errors.csv: file is missing" in p for p in probs)
    assert any("not a number: 'x'" in p for p in probs), "problems in other files are still reported"


def test_wrong_cell_count_and_unknown_column(run_dir, edit_csv):
    edit_csv(run_dir, "errors.csv", lambda ls: [ls[0] + ",speed"] + [line + ",1" for line in ls[1:]])
    assert any("unknown column 'speed'" in p for p in _problems(run_dir))


def test_motion_checks(run_dir, edit_csv):
    edit_csv(run_dir, "motion.csv", lambda ls: ls + ["4000,3900,0,800,-5"])
    probs = _problems(run_dir)
    assert any("motion.csv line 4 column 't_end_s'" in p for p in probs), probs
    assert any("overlaps" in p for p in probs)
    assert any("feed must be positive" in p for p in probs)
    assert any("800 mm is outside the stroke" in p for p in probs)


def test_direction_values(tmp_path, make_run, edit_csv):
    folder = write_run(make_run(bidirectional=True), str(tmp_path / "r"))
    edit_csv(folder, "errors.csv", lambda ls: ls[:2] + [ls[2].rsplit(",", 1)[0] + ",2"] + ls[3:])
    assert any("direction must be +1 or -1" in p for p in _problems(folder))


def test_validate_cli_exit_status(run_dir, tmp_path, edit_csv):
    ok = subprocess.run([sys.executable, "-m", "host", "validate", run_dir], capture_output=True, text=True)
    assert ok.returncode == 0 and "ok" in ok.stdout
    edit_csv(run_dir, "errors.csv", lambda ls: ls + ["7199,900,1"])
    bad = subprocess.run([sys.executable, "-m", "host", "validate", run_dir, str(tmp_path / "nowhere")], capture_output=True, text=True)
    assert bad.returncode == 1
    assert "outside the stroke" in bad.stdout and "not a folder" in bad.stdout
    assert check_run(run_dir)


def test_errors_pending_admits_a_header_only_errors_csv(run_dir, edit_csv, edit_meta):
    """A recording (tcomp record) before its laser sweeps are merged declares meta.json errors_pending: only then may
    errors.csv hold its header alone; the key is a boolean."""
    edit_csv(run_dir, "errors.csv", lambda ls: ls[:1])
    probs = _problems(run_dir)
    assert any("errors.csv: no data rows after the header" in p and '"errors_pending": true' in p for p in probs), probs
    edit_meta(run_dir, lambda m: m.update(errors_pending=True))
    assert check_run(run_dir) == []
    assert len(load_run(run_dir).errors.time_s) == 0
    edit_meta(run_dir, lambda m: m.update(errors_pending="yes"))
    probs = _problems(run_dir)
    assert any("key 'errors_pending' must be true or false (found \"yes\")" in p for p in probs), probs
    edit_csv(run_dir, "temperatures.csv", lambda ls: ls[:1])  # a temperatures.csv needs its rows all the same
    edit_meta(run_dir, lambda m: m.update(errors_pending=True))
    assert any("temperatures.csv: no data rows after the header" in p for p in _problems(run_dir))
