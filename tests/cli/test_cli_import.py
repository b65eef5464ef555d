"""tcomp import's flags for real files, and the merge form (--errors FILE --into RUN): its outputs never land on its inputs."""
import json
import os

import pytest

from host.cli import main
from host.data.runs import load_run

LOG = "zeit;nut_mm;a;rpm\n2026-11-26 08:00:00;0,001;20,5;0\n2026-11-26 08:00:30;;21;0\n2026-11-26 08:01:00;0,003;21,5;100\n"
SWEEPS = "when,x,e\n2026-11-26T07:00:10Z,0,0\n2026-11-26T07:00:20Z,100,1.5\n"
SWEEPS_MAP = {"layout": "long", "time": "when", "time_format": "iso8601", "position": {"column": "x", "unit": "mm"},
              "error": {"column": "e", "unit": "um"}}


def _fail(capsys, argv):
    assert main(argv) == 2
    return capsys.readouterr().err


def _tree(folder):
    out = {}
    for root, _, files in os.walk(folder):
        for f in files:
            p = os.path.join(root, f)
            out[os.path.relpath(p, folder)] = open(p, "rb").read()
    return out


@pytest.fixture
def log(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text(LOG)
    return str(p)


FLAGS = ["--time", "zeit", "--time-format", "%Y-%m-%d %H:%M:%S", "--timezone", "Europe/Berlin", "--temp", "a=T1:nut",
         "--error", "nut_mm=probe@350", "--unit", "nut_mm=mm", "--spindle", "rpm", "--location", "a=nut housing", "--axis", "X"]


def test_flags_for_a_real_file(tmp_path, log, capsys):
    out = str(tmp_path / "run")
    assert main(["import", log, "--out", out, "--delimiter", "semicolon", "--gaps", "drop", "--json", str(tmp_path / "s.json")] + FLAGS) == 0
    said = capsys.readouterr().out
    assert "cells split at semicolon (declared), decimal comma (detected)" in said
    assert "gaps: 1 rows dropped (empty cells: nut_mm 1)" in said
    run = load_run(out)
    assert run.errors.error_um.tolist() == [1.0, 3.0]  # 0,001 mm and 0,003 mm
    assert run.temperatures.time_s.tolist() == [0, 60]
    assert run.meta["sensors"] == {"T1": {"role": "nut", "location": "nut housing"}} and run.meta["axis"] == "X"
    assert run.meta["start_time"] == "2026-11-26T07:00:00Z"
    summary = json.load(open(tmp_path / "s.json"))
    assert summary["dialect"] == {"delimiter": ";", "decimal": ",", "detected": ["decimal"]} and summary["gaps"]["rows_dropped"] == 1


def test_header_line_flag_skips_a_preamble(tmp_path, capsys):
    src = tmp_path / "pre.csv"
    src.write_text("logger 7 export\n\n" + LOG)
    out = str(tmp_path / "run")
    assert main(["import", str(src), "--out", out, "--gaps", "drop", "--header-line", "3"] + FLAGS) == 0
    assert load_run(out).meta["import"]["header_line"] == 3
    assert "pre.csv line 2: cannot tell how the cells are separated" in _fail(
        capsys, ["import", str(src), "--out", out, "--gaps", "drop", "--header-line", "2"] + FLAGS)


def test_a_mm_column_without_unit_flag_is_refused(tmp_path, log, capsys):
    argv = ["import", log, "--out", str(tmp_path / "run"), "--gaps", "interpolate"] + FLAGS
    i = argv.index("--unit")
    err = _fail(capsys, argv[:i] + argv[i + 2:])
    assert "error column 'nut_mm' has no declared unit, and its name says mm" in err


def test_flags_that_clash_with_or_are_ignored_by_a_mapping_are_refused(tmp_path, log, capsys):
    m = tmp_path / "m.json"
    m.write_text(json.dumps({"time": "zeit", "gaps": "drop", "temperatures": ["a"], "errors": ["nut_mm"]}))
    out = str(tmp_path / "run")
    assert "--gaps interpolate: the mapping %s says 'drop'; give it in one place" % m in _fail(
        capsys, ["import", log, "--mapping", str(m), "--out", out, "--gaps", "interpolate"])
    assert "--time: the mapping %s gives the columns" % m in _fail(capsys, ["import", log, "--mapping", str(m), "--out", out, "--time", "zeit"])
    assert "--unit: the mapping" in _fail(capsys, ["import", log, "--mapping", str(m), "--out", out, "--unit", "nut_mm=mm"])
    assert "--unit x=mm: 'x' is neither a --temp nor an --error column" in _fail(
        capsys, ["import", log, "--out", out, "--time", "zeit", "--temp", "a", "--error", "nut_mm", "--unit", "x=mm"])


def test_merge_form_usage_errors(tmp_path, log, capsys):
    run = str(tmp_path / "run")
    assert "--errors FILE.csv and --into RUN go together" in _fail(capsys, ["import", "--errors", log])
    assert "do one at a time" in _fail(capsys, ["import", log, "--errors", log, "--into", run])
    assert "--clock-offset aligns an --errors file" in _fail(capsys, ["import", log, "--out", run, "--clock-offset", "3"])
    assert "--into %s: not a folder" % run in _fail(capsys, ["import", "--errors", log, "--into", run, "--mapping", log])
    assert "give a log and --out RUN" in _fail(capsys, ["import", log])


@pytest.fixture
def world(tmp_path, log):
    run = str(tmp_path / "run")
    assert main(["import", log, "--out", run, "--gaps", "drop"] + FLAGS) == 0
    (tmp_path / "laser.csv").write_text(SWEEPS)
    (tmp_path / "laser.json").write_text(json.dumps(dict(SWEEPS_MAP, channel="laser")))  # the run has a probe channel
    return tmp_path


def test_merge_cli_and_its_summary(world, capsys):
    run = str(world / "run")
    capsys.readouterr()
    assert main(["import", "--errors", str(world / "laser.csv"), "--mapping", str(world / "laser.json"), "--into", run,
                 "--json", str(world / "s.json")]) == 0
    assert "1 sweeps (2 points), clock aligned by start times" in capsys.readouterr().out
    assert main(["validate", run]) == 0
    s = json.load(open(world / "s.json"))
    assert s["clock"]["offset_s"] == 10 and (s["rows_before"], s["rows_after"]) == (2, 4)
    assert load_run(run).errors.channel.tolist() == ["probe", "laser", "laser", "probe"]  # by time: 0, 10, 10, 60 s


def test_merge_outputs_never_land_on_inputs(world, capsys):
    """--into and --json against --errors and --mapping: refused before any work, nothing written."""
    run = str(world / "run")
    inside = os.path.join(run, "laser.csv")
    with open(inside, "w") as fh:
        fh.write(SWEEPS)
    attacks = [
        (["--errors", inside, "--mapping", str(world / "laser.json"), "--into", run], "the folder holds the input"),
        (["--errors", str(world / "laser.csv"), "--mapping", str(world / "laser.json"), "--into", run, "--json", str(world / "laser.csv")],
         "is the input"),
        (["--errors", str(world / "laser.csv"), "--mapping", str(world / "laser.json"), "--into", run, "--json", str(world / "laser.json")],
         "is the input"),
        (["--errors", str(world / "laser.csv"), "--mapping", str(world / "laser.json"), "--into", run, "--json", os.path.join(run, "meta.json")],
         "the same place"),
    ]
    before = _tree(str(world))
    for argv, why in attacks:
        assert why in _fail(capsys, ["import"] + argv), argv
        assert _tree(str(world)) == before, argv


def test_a_refused_merge_leaves_the_run_as_it_was(world, capsys):
    run = str(world / "run")
    (world / "late.csv").write_text(SWEEPS.replace("07:00:", "09:00:"))
    before = _tree(run)
    err = _fail(capsys, ["import", "--errors", str(world / "late.csv"), "--mapping", str(world / "laser.json"), "--into", run])
    assert "late.csv spans run time 7210.000..7220.000 s" in err and "they do not overlap" in err
    assert _tree(run) == before
