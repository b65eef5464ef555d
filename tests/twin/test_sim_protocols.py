"""S004 Table 2 as a protocol (a sweep after each moving state) and a user's schedule from a CSV file."""
import json

import numpy as np
import pytest

from host.data.runs import load_run
from host.twin import make_params
from host.twin.protocols import PROTOCOLS, read_protocol_csv, resolve_protocols, schedule

# S004 Table 2: (feed mm/min, from mm, to mm, minutes); the laser measures after each state
TABLE2 = [(8000, 0, 280, 6), (5000, 490, 700, 10), (10000, 240, 450, 5), (12000, 0, 700, 2)]
CSV = "duration_min,feed_mm_min,from_mm,to_mm\n" + "".join("%d,%d,%d,%d\n" % (m, f, a, b) for f, a, b, m in TABLE2)


def _expected(stop_min):
    """Sweep times and motion rows written out by hand: cold sweep, then state, stop + sweep, state, ..."""
    sweeps, rows, t = [0.0], [], stop_min * 60.0
    for f, a, b, m in TABLE2:
        rows.append([t, t + 60.0 * m, a, b, f])
        t += 60.0 * m
        sweeps.append(t)
        t += stop_min * 60.0
    return np.array(sweeps), np.array(rows, dtype=float)


def test_s004_table2_runs_the_four_states_with_a_sweep_after_each():
    params = make_params()
    sweeps, motion = schedule(PROTOCOLS["s004-table2"], params)
    want_s, want_m = _expected(params.sweep_duration_min)
    np.testing.assert_array_equal(sweeps, want_s)
    np.testing.assert_array_equal(motion, want_m)
    assert PROTOCOLS["s004-table2"].duration_s(params) == want_s[-1]


def test_a_csv_schedule_is_the_same_protocol(tmp_path):
    path = tmp_path / "table2.csv"
    path.write_text(CSV)
    proto = read_protocol_csv(str(path))
    assert proto.name == "table2" and proto.sweeps_after_phases
    params = make_params()
    for a, b in zip(schedule(proto, params), schedule(PROTOCOLS["s004-table2"], params)):
        np.testing.assert_array_equal(a, b)
    # an idle row: no motion, but its sweep
    path.write_text("duration_min,feed_mm_min,from_mm,to_mm\n5,8000,0,100\n10,0,0,0\n")
    sweeps, motion = schedule(read_protocol_csv(str(path)), params)
    assert list(sweeps) == [0.0, 420.0, 1140.0] and motion.shape == (1, 5)


@pytest.mark.parametrize("text, message", [
    ("duration,feed_mm_min,from_mm,to_mm\n5,100,0,10\n", "line 1: header must be duration_min,feed_mm_min,from_mm,to_mm"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n", "no state after the header"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n5,100,0,10\n\n5,abc,0,10\n", "line 4 column 2 \\(feed_mm_min\\): not a number: 'abc'"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n0,100,0,10\n", "line 2 column 1 \\(duration_min\\): must be > 0"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n5,-1,0,10\n", "line 2 column 2 \\(feed_mm_min\\): must be >= 0"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n5,100,0\n", "line 2: 3 cells, expected 4"),
    ("duration_min,feed_mm_min,from_mm,to_mm\n5,100,0,10\n5,100,600,900\n", "line 3: range 600-900 mm is outside the stroke"),
])
def test_bad_csv_schedules_are_refused_naming_the_line(tmp_path, text, message):
    path = tmp_path / "p.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        schedule(resolve_protocols(str(path))[0], make_params())


def test_simulate_cli_takes_the_protocol_name_and_a_file(tmp_path):
    path = tmp_path / "mine.csv"
    path.write_text(CSV)
    from host.cli import main

    for spec, out in (("s004-table2", tmp_path / "a"), (str(path), tmp_path / "b")):
        assert main(["simulate", "--out", str(out), "--protocol", spec]) == 0
        run = load_run(str(out))
        assert len(run.errors.sweeps()) == 5
    meta = json.loads((tmp_path / "b" / "meta.json").read_text())
    assert [ph["minutes"] for ph in meta["simulation"]["phases"]] == [6, 10, 5, 2]
    # the file is an input: the run is never written over it
    assert main(["simulate", "--out", str(path), "--protocol", str(path)]) == 2
    assert path.read_text() == CSV
