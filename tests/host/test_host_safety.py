"""The host never loses a user's input nor leaves half an output (issue 14, part 2).

Every finding of the hostile test is one case here: exit status 2, one clear line naming what and where,
no traceback, no output file left behind and the inputs byte-identical. In-process through host.cli.main,
as in tests/cli/test_cli_badinput.py.
"""
import json
import os
import shutil
import subprocess
import sys
import warnings

import pytest

from host.cli import main
from host.errors import UserError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEMO_RUN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")
FEW = "T1,T2"


def _fail(capsys, argv):
    """Run ``tcomp argv``; assert exit status 2 and one error line; return it."""
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert err.startswith("tcomp %s: error: " % argv[0]), err
    assert "Traceback" not in err
    assert "\n" not in err, err  # one line: no warning or listing around it
    return err


def _files(folder):
    """Every file below ``folder`` (relative paths), staging leftovers included."""
    return sorted(os.path.relpath(os.path.join(r, f), folder) for r, _, fs in os.walk(folder) for f in fs)


def _snapshot(*paths):
    out = {}
    for p in paths:
        for f in ([p] if os.path.isfile(p) else [os.path.join(p, x) for x in _files(p)]):
            with open(f, "rb") as fh:
                out[f] = fh.read()
    return out


@pytest.fixture
def run(tmp_path):
    """A copy of the demo run: a test that failed to refuse must not damage the repository's data."""
    folder = str(tmp_path / "run")
    shutil.copytree(DEMO_RUN, folder)
    return folder


@pytest.fixture(scope="module")
def model_doc(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("model") / "mlr.json")
    assert main(["fit", "--model", "mlr", DEMO_RUN, "--sensors", FEW, "--out", path]) == 0
    with open(path) as fh:
        return json.load(fh)


@pytest.fixture
def model(tmp_path, model_doc):
    path = str(tmp_path / "m.json")
    with open(path, "w") as fh:
        json.dump(model_doc, fh)
    return path


def _edited_model(tmp_path, doc, fn, name="edited.json"):
    doc = json.loads(json.dumps(doc))
    fn(doc)
    path = str(tmp_path / name)
    with open(path, "w") as fh:
        json.dump(doc, fh)
    return path


# ------------------------------------------------------------ outputs over inputs, refused before any work

def _link(tmp_path, target):
    link = str(tmp_path / "link.json")
    os.symlink(target, link)
    return link


def _hard(tmp_path, target):
    hard = str(tmp_path / "hard.json")
    os.link(target, hard)
    return hard


@pytest.mark.parametrize("argv, words", [
    (["predict", "{model}", "{run}", "--out", "{model}"], "--out {model}: is the input {model}"),
    (["export", "{model}", "--out", "{model}"], "--out {model}: is the input {model}"),
    (["export", "{model}", "--out", "{tmp}/t.bin", "--report", "{tmp}/t.bin"], "--out {tmp}/t.bin and --report {tmp}/t.bin: the same place"),
    (["export", "{model}", "--out", "{tmp}/t.bin", "--json", "{tmp}/r.json", "--report", "{tmp}/r.json"], "--json {tmp}/r.json: the same place"),
    (["fit", "--model", "mlr", "{run}", "--out", "{run}/errors.csv"], "--out {run}/errors.csv: would overwrite a file of the input folder {run}"),
    (["fit", "--model", "mlr", "{run}", "--out", "{tmp}/m2.json", "--json", "{run}/meta.json"], "--json {run}/meta.json: would overwrite a file of the input folder"),
    (["predict", "{model}", "{run}", "--out", "{link}"], "--out {link}: is the input {model}"),
    (["predict", "{model}", "{run}", "--out", "{hard}"], "--out {hard}: is the input {model}"),
    (["predict", "{model}", "{run}", "--out", "{tmp}/p.csv", "--json", "{tmp}/p.csv"], "the same place"),
    (["validate", "{run}", "--json", "{run}/temperatures.csv"], "would overwrite a file of the input folder"),
    (["discrepancy", "{run}", "--json", "{tmp}/d.json", "--report", "{tmp}"], "--report {tmp}: the folder holds the input {run}"),
    (["discrepancy", "{run}", "--json", "{tmp}/x", "--report", "{tmp}/x"], "--json {tmp}/x and --report {tmp}/x: the same place"),
    (["compare", "{run}", "--split-h", "3", "--json", "{tmp}/c.json", "--plots", "{run}"], "--plots {run}: is the input {run}"),
    (["import", "{run}/temperatures.csv", "--time", "time_s", "--temp", "T1", "--error", "T2", "--out", "{run}"], "the folder holds the input {run}/temperatures.csv"),
    (["select", "--method", "stepwise", "{run}", "--json", "{run}/errors.csv"], "would overwrite a file of the input folder"),
])
def test_an_output_onto_an_input_or_another_output_is_refused(capsys, tmp_path, run, model, argv, words):
    fmt = dict(model=model, run=run, tmp=tmp_path)
    fmt.update(link=_link(tmp_path, model) if "{link}" in argv else "", hard=_hard(tmp_path, model) if "{hard}" in argv else "")
    before = _snapshot(run, model)
    listing = _files(str(tmp_path))
    err = _fail(capsys, [a.format(**fmt) for a in argv])
    assert words.format(**fmt) in err
    assert _snapshot(run, model) == before and _files(str(tmp_path)) == listing


def test_a_symlinked_output_is_written_through_its_link(capsys, tmp_path, model):
    real = tmp_path / "real.csv"
    real.write_text("old\n")
    link = tmp_path / "link.csv"
    os.symlink(str(real), str(link))
    assert main(["predict", model, DEMO_RUN, "--out", str(link)]) == 0
    assert os.path.islink(str(link)) and real.read_text().startswith("time_s,position_mm,predicted_um")


# ------------------------------------------------------------ disk full: one line, nothing left

@pytest.mark.parametrize("argv", [
    ["predict", "{model}", DEMO_RUN, "--out", "{tmp}/p.csv", "--json", "/dev/full"],
    ["fit", "--model", "mlr", DEMO_RUN, "--sensors", FEW, "--out", "{tmp}/m2.json", "--json", "/dev/full"],
    ["fit", "--model", "screw", DEMO_RUN, "--out", "{tmp}/s.json", "--json", "/dev/full"],
    ["simulate", "--out", "{tmp}/sim", "--protocol", "idle", "--json", "/dev/full"],
    ["validate", DEMO_RUN, "--json", "/dev/full"],
    ["export", "{model}", "--out", "/dev/full"],
    ["export", "{model}", "--out", "{tmp}/q.bin", "--json", "{tmp}/q.json", "--c-header", "/dev/full"],
    ["import", os.path.join(DEMO_RUN, "temperatures.csv"), "--time", "time_s", "--temp", "T1", "--error", "T2", "--ignore",
     ",".join("T%d" % i for i in range(3, 14)), "--out", "{tmp}/imp", "--json", "/dev/full"],
])
def test_disk_full_leaves_no_output(capsys, tmp_path, model, argv):
    argv = [a.format(model=model, tmp=tmp_path) for a in argv]
    if argv[0] == "import":  # --ignore is one column per flag
        i = argv.index("--ignore")
        argv[i:i + 2] = [x for c in argv[i + 1].split(",") for x in ("--ignore", c)]
    listing = _files(str(tmp_path))
    rc = main(argv)
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert rc == 2 and err.startswith("tcomp %s: error: " % argv[0]) and "Traceback" not in err, err
    assert err.endswith("cannot write /dev/full: No space left on device; no output was written") and "\n" not in err, err
    assert "wrote" not in cap.out  # nothing announces an output that the failure took back
    assert _files(str(tmp_path)) == listing


def test_a_writer_failing_mid_way_leaves_no_output(tmp_path):
    from host.outputs import Outputs

    with pytest.raises(UserError, match="no output was written"):
        with Outputs() as out:
            out.file(str(tmp_path / "a.json"), "--out")
            out.folder(str(tmp_path / "dir"), "--report")
            with out.open(str(tmp_path / "a.json")) as fh:
                fh.write("half")
            os.makedirs(os.path.join(out.path(str(tmp_path / "dir")), "sub"))
            raise OSError(28, "No space left on device")
    assert os.listdir(str(tmp_path)) == []


def test_outputs_appear_together_with_the_modes_of_the_files_they_replace(tmp_path):
    from host.outputs import Outputs

    old = tmp_path / "old.txt"
    old.write_text("old")
    os.chmod(str(old), 0o640)
    with Outputs() as out:
        for name in ("old.txt", "new.txt"):
            out.file(str(tmp_path / name))
            with out.open(str(tmp_path / name)) as fh:
                fh.write("new")
        assert old.read_text() == "old" and not (tmp_path / "new.txt").exists()  # nothing before the commit
        out.commit()
    assert sorted(os.listdir(str(tmp_path))) == ["new.txt", "old.txt"] and old.read_text() == "new"
    assert os.stat(str(old)).st_mode & 0o777 == 0o640


# ------------------------------------------------------------ CSV that cannot be read unambiguously

def _log(tmp_path, rows=200, quote_row=None, big_row=None):
    lines = ["time_s,temp,err,note"]
    for i in range(rows):
        note = "ok"
        if i + 2 == quote_row:
            note = '"see notes'  # a cell that opens a quote and never closes it
        if i + 2 == big_row:
            note = "x" * (128 * 1024 + 1)
        lines.append("%d,%.1f,%.2f,%s" % (60 * i, 20 + i / 100, i / 50, note))
    path = tmp_path / "log.csv"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _import(src, tmp_path):
    return ["import", src, "--time", "time_s", "--temp", "temp", "--error", "err", "--ignore", "note", "--out", str(tmp_path / "r")]


def test_import_a_stray_quote_in_an_ignored_column_is_an_error_not_lost_rows(capsys, tmp_path):
    src = _log(tmp_path, quote_row=11)
    err = _fail(capsys, _import(src, tmp_path))
    assert "%s line 11: a quote opened on this line is never closed" % src in err
    assert not (tmp_path / "r").exists()


def test_import_a_quoted_cell_over_several_lines_names_them(capsys, tmp_path):
    src = tmp_path / "log.csv"
    src.write_text('time_s,temp,err,note\n0,20,1,"a\n60,21,2,b"\n120,22,3,c\n')
    err = _fail(capsys, _import(str(src), tmp_path))
    assert "%s lines 2-3: one quoted cell runs over 2 lines" % src in err


def test_import_a_cell_over_128_kib(capsys, tmp_path):
    src = _log(tmp_path, rows=5, big_row=4)
    err = _fail(capsys, _import(src, tmp_path))
    assert "%s line 4: a cell is longer than 131072 characters (128 KiB" % src in err


@pytest.mark.parametrize("cell, verb", [('"20.5', "validate"), ("x" * (128 * 1024 + 1), "fit")])
def test_run_csv_that_cannot_be_split_into_cells(capsys, tmp_path, run, cell, verb):
    path = os.path.join(run, "temperatures.csv")
    with open(path) as fh:
        lines = fh.read().splitlines()
    lines[5] = lines[5].split(",", 1)[0] + "," + cell + "," + lines[5].split(",", 2)[2]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    if verb == "validate":
        assert main(["validate", run]) == 1  # validate lists problems and exits 1 (docs/data-format.md)
        out = capsys.readouterr().out
        assert "%s line 6: a quote opened on this line is never closed" % path in out
    else:
        err = _fail(capsys, ["fit", "--model", "mlr", run, "--out", str(tmp_path / "m.json")])
        assert "%s line 6: a cell is longer than 131072 characters" % path in err


@pytest.mark.parametrize("cell", ["2_0", "\uff12\uff10", "\u0662\u0660"])
def test_cells_that_python_reads_as_numbers_but_no_logger_writes(capsys, tmp_path, run, cell):
    path = os.path.join(run, "temperatures.csv")
    with open(path, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    first, rest = lines[3].split(",", 1)
    lines[3] = first + "," + cell + "," + rest.split(",", 1)[1]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    err = _fail(capsys, ["fit", "--model", "mlr", run, "--out", str(tmp_path / "m.json")])
    assert "%s line 4 column 'T1': not a number: %r" % (path, cell) in err


def test_a_wide_header_is_checked_in_linear_time_and_summarised(capsys, tmp_path, run):
    n = 50000
    path = os.path.join(run, "temperatures.csv")
    with open(path) as fh:
        lines = fh.read().splitlines()[:3]
    lines[0] += "," + ",".join("u%d" % i for i in range(n))
    lines[1:] = [line + ",20" * n for line in lines[1:]]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    assert main(["validate", run]) == 1
    out = capsys.readouterr().out
    assert "line 1 column 15: sensor 'u0' is not declared" in out
    assert "... and %d more undeclared sensor columns (%d in all)" % (n - 10, n) in out
    assert len(out.splitlines()) < 20


# ------------------------------------------------------------ values accepted silently before

@pytest.mark.parametrize("edit, words", [
    ({"stroke_mm": float("inf")}, "key 'stroke_mm' must be a positive finite number (found inf)"),
    ({"stroke_mm": "1e400"}, "key 'stroke_mm' must be a positive finite number (found inf)"),
    ({"screw.lead_mm": float("inf")}, "screw.lead_mm must be a positive finite number (found inf)"),
    ({"screw.fixed_end_mm": float("nan")}, "screw.fixed_end_mm must be a finite number (found nan)"),
])
def test_meta_numbers_must_be_finite(capsys, tmp_path, run, edit, words):
    path = os.path.join(run, "meta.json")
    with open(path) as fh:
        meta = json.load(fh)
    (key, value), = edit.items()
    block, _, key = key.rpartition(".")
    (meta[block] if block else meta)[key] = 0.0 if value == "1e400" else value
    text = json.dumps(meta)
    if value == "1e400":  # json reads 1e400 as Infinity
        text = text.replace('"%s": 0.0' % key, '"%s": 1e400' % key)
    with open(path, "w") as fh:
        fh.write(text)
    assert main(["validate", run]) == 1
    assert words in capsys.readouterr().out


@pytest.mark.parametrize("file, column, value, words", [
    ("errors.csv", 2, "1e300", "column 'error_um': error 1e+300 um is outside -10000..10000 um"),
    ("temperatures.csv", 1, "1e308", "column 'T1': temperature 1e+308 degC is outside -200..850 degC, the range of a Pt100"),
])
def test_physically_impossible_values_name_their_row(capsys, tmp_path, run, file, column, value, words):
    path = os.path.join(run, file)
    with open(path) as fh:
        lines = fh.read().splitlines()
    cells = lines[7].split(",")
    cells[column] = value
    lines[7] = ",".join(cells)
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy overflow warnings on the way
        err = _fail(capsys, ["fit", "--model", "mlr", run, "--out", str(tmp_path / "m.json")])
    assert "%s line 8 %s" % (path, words) in err and "collinear" not in err
    assert not (tmp_path / "m.json").exists()


def test_the_same_run_twice_is_refused(capsys, tmp_path, run):
    err = _fail(capsys, ["fit", "--model", "mlr", run, run + "/", "--out", str(tmp_path / "m.json")])
    assert "%s/: the same run folder as %s, given twice" % (run, run) in err


# ------------------------------------------------------------ model documents

@pytest.mark.parametrize("edit, words", [
    (lambda d: d["geometric"].update(coefficients_um=[]), "geometric.coefficients_um is empty"),
    (lambda d: d.update(sensors=["T1", "T1", "T2"]), "sensors lists T1 more than once"),
    (lambda d: d["thermal"]["coefficients_um_per_mm_per_K"].update(T3=0.1),
     "thermal.coefficients_um_per_mm_per_K has T3, which is not in sensors (T1, T2); the coefficient would be dropped"),
    (lambda d: d["geometric"].update(degree=5), "geometric.degree is 5 but geometric.coefficients_um has 3 coefficients (degree 2)"),
    (lambda d: d["envelope"]["temperature_C"].update(T1=[18, float("inf")]), "envelope.temperature_C.T1[1] must be a finite number"),
])
@pytest.mark.parametrize("verb", ["predict", "export"])
def test_model_documents_that_say_something_else_than_what_is_used(capsys, tmp_path, model_doc, edit, words, verb):
    path = _edited_model(tmp_path, model_doc, edit)
    argv = ["predict", path, DEMO_RUN, "--out", str(tmp_path / "p.csv")] if verb == "predict" else ["export", path, "--out", str(tmp_path / "t.bin")]
    err = _fail(capsys, argv)
    assert "%s: %s" % (path, words) in err
    assert sorted(os.listdir(str(tmp_path))) == ["edited.json"]


@pytest.mark.parametrize("field", ["reduced", "geometry"])
def test_export_of_a_screw_model_with_a_nan_fixed_end(capsys, tmp_path, field):
    import random

    from hil_tests.fixtures.samples import screw_doc

    doc = screw_doc(random.Random(3), segments=8)
    doc.setdefault("thermal", {}).setdefault(field, {})["fixed_end_mm"] = float("nan")
    path = str(tmp_path / "screw.json")
    with open(path, "w") as fh:
        json.dump(doc, fh)
    err = _fail(capsys, ["export", path, "--out", str(tmp_path / "t.bin")])
    assert "thermal.%s.fixed_end_mm must be a finite number" % field in err


def test_export_plan_names_a_nan_fixed_end_when_called_as_a_library():
    import random

    from models_export import ExportError, export_model
    from hil_tests.fixtures.samples import screw_doc

    doc = screw_doc(random.Random(3), segments=8)
    doc["thermal"]["reduced"]["fixed_end_mm"] = float("nan")
    with pytest.raises(ExportError, match="fixed_end_mm, dt_s, state_max_K and edges_mm must be finite"):
        export_model(doc)


def test_export_names_a_non_ascii_axis(capsys, tmp_path, model_doc):
    path = _edited_model(tmp_path, model_doc, lambda d: d.update(axis="\u00c4"))
    err = _fail(capsys, ["export", path, "--out", str(tmp_path / "t.bin")])
    assert "axis name '\u00c4' must be 1..8 ASCII characters" in err and "codec" not in err


def test_the_firmware_refuses_a_table_naming_one_sensor_twice(model_doc):
    from firmware.table import REASON_FIELD, TableError, parse_table
    from models_export import export_model
    from models_export.tableformat import pack

    fields = dict(export_model(model_doc).fields)
    fields["sensors"] = ["T1", "T1"]
    with pytest.raises(TableError) as info:
        parse_table(pack(fields))
    assert info.value.reason == REASON_FIELD and "T1 twice" in str(info.value)


# ------------------------------------------------------------ flags

def test_monitor_negative_baud(capsys):
    err = _fail(capsys, ["monitor", "--port", "/dev/null", "--baud", "-5"])
    assert "--baud -5: must be a positive rate in bit/s" in err


@pytest.fixture(scope="module")
def table(tmp_path_factory, model_doc):
    from models_export import export_model

    path = tmp_path_factory.mktemp("table") / "t.bin"
    path.write_bytes(export_model(model_doc).table)
    return str(path)


@pytest.mark.parametrize("flags, words", [
    (["--fault", "open:T1@99999-999999"], "starts at 99999 s, after the run ends at 18000 s"),
    (["--warmup-s", "1e12"], "--warmup-s 1e+12: longer than the run %s itself (18000 s)" % DEMO_RUN),
    (["--print-every", "-1"], "--print-every -1: must be >= 0"),
    (["--fault", "open:T1@1.2.3-5"], "START and END must be numbers of seconds"),
])
def test_hil_settings_bounded_by_the_run(capsys, table, flags, words):
    err = _fail(capsys, ["hil", "--run", DEMO_RUN, "--table", table] + flags)
    assert words in err


def test_hil_fault_past_the_run_end_is_cut_with_a_warning(capsys):
    from host.cli.verbs.hil import _faults

    (f,) = _faults(["open:T1@600-999999"], ["T1"], 18000.0)
    assert f["end_s"] == 18000.0 and f["start_s"] == 600.0
    assert "the fault lasts to the end of the run" in capsys.readouterr().err


def test_hil_names_a_table_sensor_the_config_does_not_wire(capsys, tmp_path, table):
    from hil_tests.rig.boards import rig_config

    cfg = rig_config(["T1", "T9"], n_ads=0)
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(cfg))
    err = _fail(capsys, ["hil", "--run", DEMO_RUN, "--table", table, "--config", str(path)])
    assert "table sensor(s) T2 have no channel in the board config %s (channels: T1, T9)" % path in err
    assert "count mismatch" not in err


def test_flash_names_a_table_sensor_the_config_does_not_wire(capsys, tmp_path, table):
    from hil_tests.rig.boards import rig_config

    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(rig_config(["T1", "T9"], n_ads=0)))
    err = _fail(capsys, ["flash", "--port", "/dev/null", "--table", table, "--config", str(path), "--dry-run"])
    assert "table sensor(s) T2 have no channel in the board config" in err


# ------------------------------------------------------------ leftovers

def test_the_rig_build_leaves_only_its_cache_folder(tmp_path):
    """The rig's .mpy files live in the build cache (host/board/fwbuild.py), one folder per content;
    a process leaves no temporary folder (.tmp-*) behind in it."""
    cache = tmp_path / "cache"
    code = "from hil_tests.rig.mpybuild import rig_build; print(rig_build().root)"
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, TCOMP_MPY_CACHE=str(cache)))
    assert p.returncode == 0, p.stderr
    folder = p.stdout.strip()
    assert os.listdir(cache) == [os.path.basename(folder)] and os.path.isfile(
        os.path.join(folder, "hil_tests", "rig", "dut.mpy"))


def test_hil_disk_full_leaves_no_output(capsys, tmp_path, table):
    from host.data.runs import Errors, Run, Temperatures, load_run, write_run

    demo = load_run(DEMO_RUN)
    t, e = demo.temperatures, demo.errors
    kt, ke = t.time_s <= 900, e.time_s <= 900  # the first 15 minutes: two sweeps, seconds on the rig
    short = write_run(Run(demo.meta, Temperatures(t.time_s[kt], t.names, t.values[kt]),
                          Errors(e.time_s[ke], e.position_mm[ke], e.error_um[ke])), str(tmp_path / "short"))
    listing = _files(str(tmp_path))
    err = _fail(capsys, ["hil", "--run", short, "--table", table, "--interpreter", "cpython", "--print-every", "0",
                         "--json", "/dev/full"])
    assert err.endswith("cannot write /dev/full: No space left on device; no output was written")
    assert _files(str(tmp_path)) == listing
