"""Bad input to every `tcomp` verb: exit status 2 and one clear line naming what and where, never a traceback.

Most cases call host.cli.main in-process (an uncaught exception fails the test just as a traceback would,
and it is ten times faster than a subprocess); test_no_traceback_in_a_subprocess checks the real command.
"""
import json
import os
import subprocess
import sys

import pytest

from host.cli import main
from host.errors import UserError, open_output

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEMO = os.path.join(ROOT, "data", "demo")
RUN = os.path.join(DEMO, "v8000_r210_490")
FEW = "T1,T2,T3,T4,T5"  # a small sensor set keeps the fits quick
NOWHERE = "/nonexistent-tcomp-dir/out"


def _fail(capsys, argv):
    """Run ``tcomp argv``; assert exit status 2 and return the one-line error message."""
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert err.startswith("tcomp %s: error: " % argv[0]), err
    assert "Traceback" not in err
    assert "\n" not in err, err  # one line
    return err


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("model") / "mlr.json")
    assert main(["fit", "--model", "mlr", RUN, "--sensors", FEW, "--out", path]) == 0
    return path


@pytest.fixture
def binary(tmp_path):
    path = tmp_path / "t.bin"
    path.write_bytes(bytes(range(128, 256)) * 3)
    return str(path)


def _edited(model, tmp_path, fn):
    with open(model) as fh:
        doc = json.load(fh)
    fn(doc)
    path = str(tmp_path / "edited.json")
    with open(path, "w") as fh:
        json.dump(doc, fh)
    return path


# ------------------------------------------------------------ 1. model path is a folder or a binary file

def test_model_path_that_is_a_folder(capsys, tmp_path):
    err = _fail(capsys, ["predict", RUN, RUN, "--out", str(tmp_path / "p.csv")])
    assert RUN in err and "is a folder" in err


def test_model_path_that_is_a_binary_file(capsys, tmp_path, binary):
    err = _fail(capsys, ["export", binary, "--out", str(tmp_path / "x.bin")])
    assert binary in err and "not a text file" in err


# ------------------------------------------------------------ 2. unwritable outputs, checked before the work

@pytest.mark.parametrize("argv, flag", [
    (["predict", "{model}", RUN, "--out", NOWHERE], "--out"),
    (["predict", "{model}", RUN, "--out", "{tmp}/p.csv", "--json", NOWHERE], "--json"),
    (["fit", "--model", "mlr", RUN, "--out", NOWHERE], "--out"),
    (["fit", "--model", "mlr", RUN, "--out", "{tmp}/m.json", "--json", NOWHERE], "--json"),
    (["fit", "--model", "screw", RUN, "--out", NOWHERE], "--out"),
    (["select", "--method", "stepwise", RUN, "--json", NOWHERE], "--json"),
    (["select", "--method", "stepwise", RUN, "--json", "{tmp}/s.json", "--plot", NOWHERE + ".png"], "--plot"),
    (["compare", RUN, "--split-h", "3", "--json", NOWHERE], "--json"),
    (["export", "{model}", "--out", NOWHERE], "--out"),
    (["export", "{model}", "--out", "{tmp}/x.bin", "--json", NOWHERE], "--json"),
    (["simulate", "--out", "{tmp}/sim", "--json", NOWHERE], "--json"),
    (["validate", RUN, "--json", NOWHERE], "--json"),
    (["import", os.path.join(ROOT, "data", "fl_thermal", "spindle.csv"), "--time", "time_s", "--temp", "rpm",
      "--error", "rpm", "--out", "{tmp}/i", "--json", NOWHERE], "--json"),
])
def test_unwritable_output_is_named_before_the_work(capsys, tmp_path, model, argv, flag):
    argv = [a.format(model=model, tmp=tmp_path) for a in argv]
    err = _fail(capsys, argv)
    assert flag in err and "does not exist" in err and os.path.dirname(NOWHERE) in err
    assert os.listdir(tmp_path) == []  # nothing written before the check


def test_output_path_that_is_a_folder(capsys, tmp_path, model):
    err = _fail(capsys, ["predict", model, RUN, "--out", str(tmp_path)])
    assert "--out %s: is a folder" % tmp_path in err


def test_open_output_names_the_path():
    with pytest.raises(UserError, match="cannot write %s: " % NOWHERE):
        open_output(NOWHERE)


def test_an_unexpected_oserror_is_one_line(capsys, monkeypatch):
    import host.cli.verbs.validate as validate

    def boom(args):
        raise PermissionError(13, "Permission denied", "/some/where.json")

    monkeypatch.setattr(validate, "run", boom)
    err = _fail(capsys, ["validate", RUN])
    assert err == "tcomp validate: error: /some/where.json: Permission denied"


# ------------------------------------------------------------ 3. simulate --out onto a regular file

def test_simulate_out_on_an_existing_file(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    err = _fail(capsys, ["simulate", "--out", str(f)])
    assert str(f) in err and "not a folder" in err
    err = _fail(capsys, ["simulate", "--out", str(f / "sub")])
    assert str(f) in err and "is a file" in err


def test_write_run_onto_a_file_names_it(tmp_path, make_run):
    from host.data.runs import write_run

    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="not a folder") as info:
        write_run(make_run(), str(f))
    assert info.value.filename == str(f)


# ------------------------------------------------------------ 4. export --ref-position-mm

@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_export_reference_position_must_be_finite(capsys, tmp_path, model, value):
    err = _fail(capsys, ["export", model, "--out", str(tmp_path / "x.bin"), "--ref-position-mm=" + value])
    assert "--ref-position-mm" in err and "finite" in err


def test_export_reference_position_outside_the_envelope_says_the_envelope(capsys, tmp_path, model):
    err = _fail(capsys, ["export", model, "--out", str(tmp_path / "x.bin"), "--ref-position-mm", "1e6"])
    assert model in err and "outside envelope.position_mm 0.0..700.0 mm" in err


def test_certify_rejects_a_non_finite_reference_position(model):
    from host.learning.documents import read_document
    from models_export import ExportError, export_model

    with pytest.raises(ExportError, match="finite"):
        export_model(read_document(model), ref_position_mm=float("nan"))


# ------------------------------------------------------------ 5, 6. import: binary source, mapping values, flags, BOM

def _csv(tmp_path, text=b"time_s,a,b,c\n0,20,1,x\n60,21,2,y\n", name="s.csv"):
    path = tmp_path / name
    path.write_bytes(text)
    return str(path)


def _mapping(tmp_path, doc):
    path = tmp_path / "map.json"
    path.write_text(json.dumps(doc))
    return str(path)


def test_import_binary_source(capsys, tmp_path, binary):
    err = _fail(capsys, ["import", binary, "--mapping", os.path.join(ROOT, "data", "fl_thermal_mapping.json"),
                         "--out", str(tmp_path / "i")])
    assert binary in err and "not a UTF-8 text CSV" in err


def test_import_mapping_with_a_text_position(capsys, tmp_path):
    m = _mapping(tmp_path, {"time": "time_s", "temperatures": ["a"], "errors": {"b": {"position_mm": "x"}}, "ignore": ["c"]})
    err = _fail(capsys, ["import", _csv(tmp_path), "--mapping", m, "--out", str(tmp_path / "i")])
    assert m in err and "errors.b.position_mm must be a number, found 'x'" in err


def test_import_mapping_with_numeric_column_names(capsys, tmp_path):
    m = _mapping(tmp_path, {"time": "time_s", "temperatures": [1, 2], "errors": ["b"], "ignore": ["c"]})
    err = _fail(capsys, ["import", _csv(tmp_path), "--mapping", m, "--out", str(tmp_path / "i")])
    assert m in err and "'temperatures'" in err and "must be strings" in err


@pytest.mark.parametrize("mapping, words", [
    ({"time": "time_s", "temperatures": ["a"], "errors": ["time_s"], "ignore": ["b", "c"]}, "column 'time_s' is mapped more than once (as time and errors)"),
    ({"time": "time_s", "temperatures": ["a"], "errors": ["b"], "spindle": "a", "ignore": ["c"]}, "column 'a' is mapped more than once (as temperatures and spindle)"),
    ({"time": "time_s", "temperatures": ["a", "a"], "errors": ["b"], "ignore": ["c"]}, "'temperatures' lists column(s) a more than once"),
    ({"time": "time_s", "temperatures": ["a"], "errors": {"b": {"channel": "x"}, "c": {"channel": "x"}}}, "error channel name(s) used twice: x"),
    ({"time": "time_s", "temperatures": ["a"], "errors": {"b": {"channel": None}}, "ignore": ["c"]}, "errors.b.channel must be a non-empty string"),
    ({"time": "time_s", "temperatures": ["a"], "errors": ["b"], "ignore": ["c"], "meta": {"sensors": {}}}, "'meta' may not set sensors"),
    ({"time": "time_s", "temperatures": ["a"], "errors": ["b"], "ignore": "c"}, "'ignore' must be a list of column names"),
    ({"time": 0, "temperatures": ["a"], "errors": ["b"], "ignore": ["c"]}, "'time' must be a column name (a string)"),
    ({"time": "time_s", "temperatures": {"a": "x"}, "errors": ["b"], "ignore": ["c"]}, "temperatures.a must be an object of settings"),
    ({"time": "time_s", "time_scale": "abc", "temperatures": ["a"], "errors": ["b"], "ignore": ["c"]}, "time_scale must be a number, found 'abc'"),
])
def test_import_mapping_mistakes(capsys, tmp_path, mapping, words):
    m = _mapping(tmp_path, mapping)
    err = _fail(capsys, ["import", _csv(tmp_path), "--mapping", m, "--out", str(tmp_path / "i")])
    assert m in err and words in err
    assert not (tmp_path / "i").exists()


def test_import_duplicate_header_column(capsys, tmp_path):
    src = _csv(tmp_path, b"time_s,a,a,b\n0,20,21,1\n60,21,22,2\n")
    err = _fail(capsys, ["import", src, "--time", "time_s", "--temp", "a", "--error", "b", "--out", str(tmp_path / "i")])
    assert src + " line 1" in err and "'a' appear more than once" in err


def test_import_error_flag_with_a_text_position(capsys, tmp_path):
    err = _fail(capsys, ["import", _csv(tmp_path), "--time", "time_s", "--temp", "a", "--error", "b=c@abc", "--ignore", "c",
                         "--out", str(tmp_path / "i")])
    assert "--error 'b=c@abc'" in err and "'abc' is not a number" in err


@pytest.mark.parametrize("scale", ["0", "-1", "nan"])
def test_import_time_scale_must_be_positive(capsys, tmp_path, scale):
    err = _fail(capsys, ["import", _csv(tmp_path), "--time", "time_s", "--temp", "a", "--error", "b", "--ignore", "c",
                         "--out", str(tmp_path / "i"), "--time-scale=" + scale])
    assert "--time-scale" in err and "positive" in err


def test_import_mapping_time_scale_must_be_positive(capsys, tmp_path):
    m = _mapping(tmp_path, {"time": "time_s", "time_scale": 0, "temperatures": ["a"], "errors": ["b"], "ignore": ["c"]})
    err = _fail(capsys, ["import", _csv(tmp_path), "--mapping", m, "--out", str(tmp_path / "i")])
    assert m in err and "time_scale must be > 0" in err


def test_import_out_on_an_existing_file(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    err = _fail(capsys, ["import", _csv(tmp_path), "--time", "time_s", "--temp", "a", "--error", "b", "--ignore", "c", "--out", str(f)])
    assert str(f) in err and "not a folder" in err


def test_import_accepts_a_byte_order_mark(capsys, tmp_path):
    src = _csv(tmp_path, b"\xef\xbb\xbftime_s,a,b\n0,20,1\n60,21,2\n", "excel.csv")
    assert main(["import", src, "--time", "time_s", "--temp", "a", "--error", "b", "--out", str(tmp_path / "i")]) == 0
    from host.data.runs import load_run

    assert load_run(str(tmp_path / "i")).temperatures.names == ["a"]


def test_run_folder_with_byte_order_marks_loads(tmp_path, make_run):
    from host.data.runs import load_run, write_run

    folder = write_run(make_run(), str(tmp_path / "run"))
    for name in ("meta.json", "temperatures.csv", "errors.csv", "motion.csv"):
        path = os.path.join(folder, name)
        with open(path, "rb") as fh:
            body = fh.read()
        with open(path, "wb") as fh:
            fh.write(b"\xef\xbb\xbf" + body)
    run = load_run(folder)
    assert run.temperatures.names == ["T1", "T2", "T3", "T4"] and run.motion is not None


# ------------------------------------------------------------ 7. compare --split-h

@pytest.mark.parametrize("hours, words", [("-1", "positive"), ("0", "positive"), ("99", "inside the measured span"),
                                          ("nan", "positive")])
def test_compare_split_outside_the_run(capsys, tmp_path, hours, words):
    err = _fail(capsys, ["compare", RUN, "--split-h=" + hours, "--methods", "mlr", "--json", str(tmp_path / "c.json")])
    assert "--split-h" in err and words in err
    if words.startswith("inside"):
        assert RUN in err and "0..5 h" in err


def test_compare_exits_non_zero_when_every_method_failed(capsys, tmp_path):
    out = tmp_path / "c.json"
    err = _fail(capsys, ["compare", RUN, "--split-h", "0.3", "--methods", "mlr,pcr", "--json", str(out)])
    assert "every method failed" in err and str(out) in err
    assert all(r["error"] for r in json.loads(out.read_text())["results"])  # the details are still written


# ------------------------------------------------------------ 8. model documents with wrong fields

@pytest.mark.parametrize("edit, words", [
    (lambda d: d["thermal"].update(coefficients_um_per_mm_per_K="abc"), "thermal.coefficients_um_per_mm_per_K must be an object"),
    (lambda d: d["thermal"]["coefficients_um_per_mm_per_K"].update(T1="x"), "thermal.coefficients_um_per_mm_per_K.T1 must be a finite number"),
    (lambda d: d.update(kind="linear_direct"), "lacks the field thermal.coefficients_um_per_K (it has thermal.coefficients_um_per_mm_per_K"),
    (lambda d: d.pop("thermal"), "lacks the field 'thermal'"),
    (lambda d: d.update(reference_C=[1, 2]), "field 'reference_C' must be an object"),
    (lambda d: d["thermal"].update(intercept_um_per_mm="0.1"), "thermal.intercept_um_per_mm must be a finite number"),
    (lambda d: d["thermal"]["coefficients_um_per_mm_per_K"].update(T1=float("nan")), "coefficients_um_per_mm_per_K.T1 must be a finite number"),
    (lambda d: d.update(sensors="T1"), "field 'sensors' must be a list of sensor names"),
    (lambda d: d.update(channel=5), "field 'channel' must be a channel name"),
    (lambda d: d.update(geometric=5), "geometric.coefficients_um must be a list of finite numbers"),
    (lambda d: d["thermal"].update(reference=5), "thermal.reference must be one of"),
])
def test_model_document_errors_name_file_and_field(capsys, tmp_path, model, edit, words):
    path = _edited(model, tmp_path, edit)
    err = _fail(capsys, ["predict", path, RUN, "--out", str(tmp_path / "p.csv")])
    assert path in err and words in err


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(geometric=5), "geometric must be an object, found int"),
    (lambda d: d.update(thermal="x"), "thermal must be an object, found str"),
    (lambda d: d.update(envelope=[]), "envelope must be an object, found list"),
    (lambda d: d["thermal"].update(reference="latched"), "thermal.reference must be 'fixed' or 'run_start'"),
    (lambda d: d.update(sensors=[1, 2]), "sensors must be a list of sensor names"),
])
def test_export_document_errors_name_file_and_field(capsys, tmp_path, model, edit, words):
    path = _edited(model, tmp_path, edit)
    err = _fail(capsys, ["export", path, "--out", str(tmp_path / "x.bin")])
    assert path in err and words in err


@pytest.fixture(scope="module")
def screw_model(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("screw") / "screw.json")
    assert main(["fit", "--model", "screw", RUN, "--out", path]) == 0
    return path


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(thermal="x"), "field 'thermal' must be an object, found str"),
    (lambda d: d["thermal"].update(geometry=[1]), "field 'thermal.geometry' must be an object"),
    (lambda d: d["thermal"].update(effects="x"), "thermal.effects must be a list"),
    (lambda d: d["thermal"].update(effects=[{"name": "nope"}]), "thermal.effects has unknown effect 'nope'"),
    (lambda d: d["thermal"].pop("segments"), "missing or invalid field 'segments'"),
])
def test_screw_document_errors_name_file_and_field(capsys, tmp_path, screw_model, edit, words):
    path = _edited(screw_model, tmp_path, edit)
    err = _fail(capsys, ["predict", path, RUN, "--out", str(tmp_path / "p.csv")])
    assert path in err and "screw model document" in err and words in err


def test_load_model_prefixes_the_path(tmp_path, model):
    from host.learning.documents import ModelFormatError, load_model

    path = _edited(model, tmp_path, lambda d: d.pop("sensors"))
    with pytest.raises(ModelFormatError, match="^%s: poly_slope model document lacks the field 'sensors'" % path):
        load_model(path)


# ------------------------------------------------------------ 9. values accepted silently before

@pytest.mark.parametrize("argv", [
    ["fit", "--model", "mlr", RUN, "--out", "{tmp}/m.json"],
    ["fit", "--model", "screw", RUN, "--out", "{tmp}/m.json"],
    ["select", "--method", "stepwise", RUN, "--json", "{tmp}/s.json"],
    ["compare", RUN, "--split-h", "3", "--json", "{tmp}/c.json"],
])
@pytest.mark.parametrize("empty", ["", " , "])
def test_an_empty_sensor_list(capsys, tmp_path, argv, empty):
    err = _fail(capsys, [a.format(tmp=tmp_path) for a in argv] + ["--sensors", empty])
    assert "--sensors %r: empty sensor list" % empty in err


@pytest.mark.parametrize("option, words", [
    ("envelope_margin_K=-1", "must be >= 0"),
    ("geometric_max_degree=0", "must be >= 1"),
    ("t_min_s=nan", "must be a finite number"),
    ("t_max_s=inf", "must be a finite number"),
])
def test_fit_option_out_of_range(capsys, tmp_path, option, words):
    err = _fail(capsys, ["fit", "--model", "mlr", RUN, "--sensors", FEW, "--out", str(tmp_path / "m.json"), "--option", option])
    assert "--option %s" % option.partition("=")[0] in err and words in err


def test_fit_empty_training_window(capsys, tmp_path):
    err = _fail(capsys, ["fit", "--model", "mlr", RUN, "--out", str(tmp_path / "m.json"),
                         "--option", "t_min_s=5000", "--option", "t_max_s=100"])
    assert "training window is empty" in err


def test_geometric_max_degree_below_one():
    import numpy as np

    from host.learning.empirical import EmpiricalDataError
    from host.learning.empirical.geometric import GeometricPolynomial

    with pytest.raises(EmpiricalDataError, match="max_degree must be >= 1"):
        GeometricPolynomial(0).fit(np.arange(10.0), np.arange(10.0))


@pytest.mark.parametrize("extra, words", [
    (["--repeats", "0"], "--repeats 0: must be >= 1"),
    (["--noise-C", "-1"], "--noise-C -1.0: must be a finite number >= 0"),
    (["--offset-C=nan"], "--offset-C nan: must be a finite number >= 0"),
    (["--methods", ","], "empty method list"),
    (["--methods", "pcr", "--option", "pcr.variance_threshold=abc"], "pcr.variance_threshold must be a number, got 'abc'"),
])
def test_compare_flag_out_of_range(capsys, tmp_path, extra, words):
    err = _fail(capsys, ["compare", RUN, "--split-h", "3", "--json", str(tmp_path / "c.json")] + extra)
    assert words in err
    assert not (tmp_path / "c.json").exists()


def test_cv_subset_max_sensors_below_one():
    import numpy as np

    from host.learning.empirical import EmpiricalDataError
    from host.learning.empirical.regression import BestSubsetCV

    X = np.random.default_rng(0).normal(size=(20, 3))
    with pytest.raises(EmpiricalDataError, match="max_sensors must be an integer >= 1, got 0"):
        BestSubsetCV(max_sensors=0).fit(X, X[:, 0], None, groups=np.repeat([0, 1], 10))


@pytest.mark.parametrize("effect", ["ambient_expansion=-5", "speed_dependent_heat=-0.1", "bearing_heat=-1", "sensor_lag=-3"])
def test_simulate_negative_effect_magnitude(capsys, tmp_path, effect):
    err = _fail(capsys, ["simulate", "--out", str(tmp_path / "s"), "--effects", effect])
    assert repr(effect.partition("=")[0]) in err and "must be >= 0" in err
    assert not os.path.exists(tmp_path / "s")


def test_signed_effects_keep_their_documented_meaning():
    from host.twin.effects import resolve_effects

    # reversal_error is the signed reversal value B; moving_convection only needs h > 0
    assert resolve_effects({"reversal_error": -4, "moving_convection": -0.5}) == {"moving_convection": -0.5, "reversal_error": -4.0}


# ------------------------------------------------------------ 10. hclust-ga on a split feed-axis run

def test_compare_split_hclust_ga_on_a_feed_axis_run(capsys, tmp_path):
    out = tmp_path / "c.json"
    assert main(["compare", RUN, "--split-h", "3", "--methods", "hclust-ga", "--sensors", FEW, "--repeats", "1",
                 "--json", str(out)]) == 0
    capsys.readouterr()
    (res,) = json.loads(out.read_text())["results"]
    assert not res.get("error") and res["sensors"]
    assert "feed-axis run" in res["note"] and "3 equal windows" in res["note"] and "spindle.csv" not in res.get("error", "")


# ------------------------------------------------------------ 11. export --json

def test_export_json_is_the_certificate(capsys, tmp_path, model):
    j, r = tmp_path / "e.json", tmp_path / "r.json"
    assert main(["export", model, "--out", str(tmp_path / "x.bin"), "--json", str(j), "--report", str(r)]) == 0
    capsys.readouterr()
    doc = json.loads(j.read_text())
    assert j.read_text() == r.read_text() and doc["model_kind"] == "poly_slope" and doc["max_error_um"] < doc["limit_um"]


# ------------------------------------------------------------ the real command

def test_no_traceback_in_a_subprocess(tmp_path, binary):
    p = subprocess.run([sys.executable, "-m", "host", "export", binary, "--out", str(tmp_path / "x.bin")],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines() == ["tcomp export: error: %s: not a text file (a binary file? expected a model "
                                             "document, tcomp-model/1 JSON)" % binary]


def test_select_plot_in_an_unknown_format(capsys, tmp_path):
    corr = tmp_path / "c.csv"
    corr.write_text("a,b\n1,0.5\n0.5,1\n")
    err = _fail(capsys, ["select", "--method", "maxtree", "--corr", str(corr), "--json", str(tmp_path / "s.json"),
                         "--plot", str(tmp_path / "p.txt")])
    assert "--plot %s: cannot draw a .txt file" % (tmp_path / "p.txt") in err and "png" in err
    assert not (tmp_path / "s.json").exists()


def test_select_hclust_ga_on_one_run_says_how_to_split(capsys, tmp_path):
    err = _fail(capsys, ["select", "--method", "hclust-ga", RUN, "--json", str(tmp_path / "s.json")])
    assert "got 1 run" in err and "--split 3" in err


def test_compare_plots_onto_a_file(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    err = _fail(capsys, ["compare", RUN, "--split-h", "3", "--json", str(tmp_path / "c.json"), "--plots", str(f)])
    assert "--plots %s: exists and is not a folder" % f in err


@pytest.fixture
def short_log(tmp_path):
    """The demo run with its temperature log cut to the first 30 s of a 5 h test."""
    import shutil

    run = tmp_path / "short"
    shutil.copytree(RUN, run)
    with open(os.path.join(RUN, "temperatures.csv")) as fh:
        lines = fh.read().splitlines()[:5]
    (run / "temperatures.csv").write_text("\n".join(lines) + "\n")
    return str(run)


def test_predict_outside_the_temperature_log(capsys, tmp_path, model, screw_model, short_log):
    err = _fail(capsys, ["predict", model, short_log, "--out", str(tmp_path / "p.csv")])
    assert "outside the temperature log 0..30 s (no extrapolation)" in err
    err = _fail(capsys, ["predict", screw_model, short_log, "--out", str(tmp_path / "p.csv")])
    assert "outside the temperature log 0..30 s (sensor T3; no extrapolation)" in err  # the air: E_e (T2) is off by default


def test_fit_screw_outside_the_temperature_log(capsys, tmp_path, short_log):
    err = _fail(capsys, ["fit", "--model", "screw", short_log, "--out", str(tmp_path / "m.json")])
    assert short_log in err and "outside the temperature log 0..30 s" in err


# ------------------------------------------------------------ export --envelope (issue 13)

@pytest.mark.parametrize("value, words", [
    ("T9=10:60", "sensor T9: not an input of this model (its sensors: T1, T2, T3, T4, T5)"),
    ("T1=60:10", "T1=60:10: the low end 60 degC must be below the high end 10 degC"),
    ("T1=20:20", "the low end 20 degC must be below the high end 20 degC"),
    ("T1=nan:60", "T1=nan:60: temperatures must be finite numbers"),
    ("T1=10:inf", "temperatures must be finite numbers"),
    ("T1=ten:60", "is not a pair of temperatures in degC"),
    ("T1", "expected SENSOR=LO:HI in degC"),
    ("T1=10", "expected SENSOR=LO:HI in degC"),
    ("T1=10:60,T1=5:70", "sensor T1 given twice"),
    ("T1=25:26", "does not contain the training range"),
])
def test_export_envelope_errors_are_one_line(capsys, tmp_path, model, value, words):
    out = tmp_path / "x.bin"
    err = _fail(capsys, ["export", model, "--out", str(out), "--envelope", value])
    assert "--envelope" in err or "envelope for sensor" in err, err
    assert words in err, err
    assert not out.exists() and os.listdir(tmp_path) == []


@pytest.mark.parametrize("value", ["nan", "-1", "inf"])
def test_export_envelope_margin_must_be_finite_and_not_negative(capsys, tmp_path, model, value):
    err = _fail(capsys, ["export", model, "--out", str(tmp_path / "x.bin"), "--envelope-margin=" + value])
    assert "--envelope-margin" in err


def test_export_envelope_is_set_per_sensor_and_reported(capsys, tmp_path, model):
    import json
    from firmware.table import parse_table
    with open(model) as fh:
        train = json.load(fh)["envelope"]["temperature_C"]
    j = tmp_path / "r.json"
    out = tmp_path / "x.bin"
    assert main(["export", model, "--out", str(out), "--json", str(j), "--envelope", "T1=10:60",
                 "--envelope", "T2=5:45,T3=0:50"]) == 0
    r = json.loads(j.read_text())["envelope"]
    t = parse_table(out.read_bytes())
    assert r["temperature_mC"]["T1"] == [10000, 60000] and r["temperature_mC"]["T3"] == [0, 50000]
    assert r["temperature_source"]["T1"] == "--envelope" and r["temperature_source"]["T4"] == "training range +- 15 K"
    for i, s in enumerate(t.sensors):
        lo, hi = train[s]
        assert r["training_temperature_mC"][s] == [t.train_lo[i], t.train_hi[i]]
        assert abs(t.train_lo[i] - lo * 1000) <= 1 and abs(t.train_hi[i] - hi * 1000) <= 1
        assert r["temperature_mC"][s] == [t.env_lo[i], t.env_hi[i]]
    i4 = t.sensors.index("T4")
    assert (t.env_lo[i4], t.env_hi[i4]) == (t.train_lo[i4] - 15000, t.train_hi[i4] + 15000)
    assert main(["export", model, "--out", str(out), "--json", str(j), "--envelope-margin", "0"]) == 0
    t = parse_table(out.read_bytes())
    assert (t.env_lo, t.env_hi) == (t.train_lo, t.train_hi)
