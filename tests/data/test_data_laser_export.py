"""tools/laser_export.py: a run's sweeps as a laser's long-format export, read back by `tcomp import --errors --into`
with examples/import/laser_sweeps.mapping.json. The recording here is made by the test from the twin's temperatures
(as `tcomp record` writes one: start_time, record.t_ms_at_time_0, errors_pending), starting 600 s into the twin run,
so which sweeps go in and at which run times is known without the board."""
import csv
import json
import os
import shutil

import pytest

from host.cli import main as tcomp

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TWIN = os.path.join(ROOT, "data", "demo", "mixed")
MAPPING = os.path.join(ROOT, "examples", "import", "laser_sweeps.mapping.json")
START_S = 600.0  # the recording's time 0 is this far into the twin run
END_S = 9000.0  # ... and it ends here


def _laser_export(argv):
    from tools.laser_export import main
    return main(argv)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture
def recording(tmp_path):
    """A run as `tcomp record` leaves it: the twin's temperatures from START_S to END_S on their own clock."""
    rec = tmp_path / "rec"
    rec.mkdir()
    with open(os.path.join(TWIN, "temperatures.csv"), newline="") as fh:
        rows = list(csv.reader(fh))
    with open(rec / "temperatures.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rows[0])
        for r in rows[1:]:
            t = float(r[0])
            if START_S <= t <= END_S:
                w.writerow(["%.3f" % (t - START_S)] + r[1:])
    (rec / "errors.csv").write_text("time_s,position_mm,error_um\n")
    meta = json.loads(open(os.path.join(TWIN, "meta.json")).read())
    meta.update(errors_pending=True, start_time="2026-11-26T07:10:00.250+00:00",
                record={"port": "test", "period_s": 1.0, "t_ms_at_time_0": int(START_S * 1000)})
    meta.pop("error_reference", None)
    (rec / "meta.json").write_text(json.dumps(meta))
    assert tcomp(["validate", str(rec)]) == 0
    return rec


def test_the_export_merges_back_as_the_twins_sweeps_on_the_recordings_clock(recording, tmp_path, capsys):
    laser = str(tmp_path / "laser.csv")
    assert _laser_export([TWIN, "--clock-of", str(recording), "--out", laser]) == 0
    printed = capsys.readouterr().out
    twin = _rows(os.path.join(TWIN, "errors.csv"))
    times = sorted({float(r["time_s"]) for r in twin})
    n_points = sum(1 for r in twin if float(r["time_s"]) == times[0])
    inside = [t for t in times if START_S <= t and t + (n_points - 1) * 4.0 <= END_S]
    assert 0 < len(inside) < len(times)
    assert "%d sweeps, %d points; %d sweeps left out" % (len(inside), len(inside) * n_points,
                                                          len(times) - len(inside)) in printed, printed
    with open(laser, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    assert lines[6].startswith("Run,Point,Target (mm),Direction,Date/Time,Error (µm)")  # the example's header line 7
    assert lines[7].split(",")[4] == "2026-11-26T07:%02d:%06.3f+00:00" % divmod(10 * 60 + 0.25 + inside[0] - START_S, 60)
    assert tcomp(["import", "--errors", laser, "--mapping", MAPPING, "--into", str(recording)]) == 0
    got = _rows(recording / "errors.csv")
    want = [r for r in twin if float(r["time_s"]) in inside]
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert float(g["time_s"]) == pytest.approx(float(w["time_s"]) - START_S, abs=1e-6)
        assert float(g["position_mm"]) == float(w["position_mm"])
        assert float(g["error_um"]) == pytest.approx(float(w["error_um"]), abs=1e-9)
    assert tcomp(["validate", str(recording)]) == 0


def test_a_given_start_time_writes_every_sweep(tmp_path, capsys):
    laser = str(tmp_path / "laser.csv")
    assert _laser_export([TWIN, "--start-time", "2026-11-26T08:00:00+01:00", "--point-s", "2", "--out", laser]) == 0
    twin = _rows(os.path.join(TWIN, "errors.csv"))
    rows = list(csv.reader(open(laser, encoding="utf-8").read().splitlines()[6:]))
    assert len(rows) - 1 == len(twin)
    assert rows[1][4] == "2026-11-26T08:00:00.000+01:00" and rows[2][4] == "2026-11-26T08:00:02.000+01:00"


def test_refusals_name_what_is_wrong(tmp_path, recording, capsys):
    laser = str(tmp_path / "laser.csv")
    assert _laser_export([TWIN, "--start-time", "2026-11-26T08:00:00", "--out", laser]) == 2
    assert "not an ISO 8601 date-time with its offset" in capsys.readouterr().err
    assert _laser_export([TWIN, "--clock-of", TWIN, "--out", laser]) == 2
    assert "has no start_time and record.t_ms_at_time_0: not a run tcomp record wrote" in capsys.readouterr().err
    probes = tmp_path / "probes"
    shutil.copytree(TWIN, probes)
    rows = _rows(probes / "errors.csv")
    with open(probes / "errors.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, list(rows[0]) + ["channel"])
        w.writeheader()
        for r in rows:
            w.writerow(dict(r, channel="X1"))
    assert _laser_export([str(probes), "--start-time", "2026-11-26T08:00:00+00:00", "--out", laser]) == 2
    assert "errors.csv has a channel column (several probes)" in capsys.readouterr().err
    meta = json.loads((recording / "meta.json").read_text())
    meta["record"]["t_ms_at_time_0"] = 10 ** 9  # a recording long after the twin run ended
    (recording / "meta.json").write_text(json.dumps(meta))
    assert _laser_export([TWIN, "--clock-of", str(recording), "--out", laser]) == 2
    assert "no sweep of %s lies inside the recording" % TWIN in capsys.readouterr().err
    assert not os.path.exists(laser)
