"""tcomp select: run-folder form on digital-twin runs, --corr form, CSV readers, user errors."""
import json

import numpy as np
import pytest

from host.cli import main
from host.learning.empirical.selectors.corrcsv import read_corr_csv, read_target_corr_csv

PROTOCOLS = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490")


@pytest.fixture(scope="module")
def twin_runs(tmp_path_factory):
    from host.data.runs import write_run
    from host.twin import simulate_run

    root = tmp_path_factory.mktemp("twin")
    return [write_run(simulate_run(protocol=p, seed=i), str(root / p)) for i, p in enumerate(PROTOCOLS)]


@pytest.mark.parametrize("method, options", [("maxtree", []), ("stepwise", ["--option", "f_enter=20", "--option", "f_remove=10"]), ("hclust-ga", ["--option", "seed=2"])])
def test_select_on_runs_writes_json_and_plot(twin_runs, tmp_path, method, options, capsys):
    out, png = tmp_path / "sel.json", tmp_path / "sel.png"
    rc = main(["select", "--method", method, *twin_runs, "--json", str(out), "--plot", str(png), *options])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == method and doc["sensors"]
    names = ["T%d" % i for i in range(1, 14)]
    assert set(doc["sensors"]) <= set(names)
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert ", ".join(doc["sensors"]) in capsys.readouterr().out


def test_select_sensor_subset_and_user_errors(twin_runs, tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["select", "--method", "maxtree", *twin_runs, "--sensors", "T1,T2,T3,T4", "--json", str(out)]) == 0
    assert set(json.loads(out.read_text())["sensors"]) <= {"T1", "T2", "T3", "T4"}
    assert main(["select", "--method", "hclust-ga", twin_runs[0], "--json", str(out)]) == 2
    assert "hclust-ga needs runs" in capsys.readouterr().err
    assert main(["select", "--method", "maxtree", *twin_runs, "--option", "alpha", "--json", str(out)]) == 2
    assert "expected KEY=VALUE" in capsys.readouterr().err
    assert main(["select", "--method", "maxtree", *twin_runs, "--option", "alfa=0.1", "--json", str(out)]) == 2
    assert "unknown parameter" in capsys.readouterr().err
    assert main(["select", "--method", "maxtree", str(tmp_path / "nope"), "--json", str(out)]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["select", "--method", "maxtree", "--json", str(out)]) == 2


CORR = "T1,T2,T3,T4,T5\n1,0.95,0.60,0.55,0.30\n0.95,1,0.70,0.50,0.35\n0.60,0.70,1,0.85,0.40\n0.55,0.50,0.85,1,0.45\n0.30,0.35,0.40,0.45,1\n"


@pytest.mark.parametrize("tcorr", ["sensor,r\nT1,0.8\nT2,0.9\nT3,0.6\nT4,0.7\nT5,0.5\n", "T5,0.5\nT1,0.8\nT2,-0.9\nT3,0.6\nT4,0.7\n"])
def test_corr_form_json(tmp_path, tcorr):
    c, t, out, png = tmp_path / "c.csv", tmp_path / "t.csv", tmp_path / "o.json", tmp_path / "o.png"
    c.write_text(CORR)
    t.write_text(tcorr)
    assert main(["select", "--method", "maxtree", "--corr", str(c), "--target-corr", str(t), "--json", str(out), "--plot", str(png)]) == 0
    doc = json.loads(out.read_text())
    assert doc["edges"] == [["T1", "T2", 0.95], ["T2", "T3", 0.7], ["T3", "T4", 0.85], ["T4", "T5", 0.45]]
    lam = [(p["lambda_low"], p["lambda_high"]) for p in doc["partitions"]]
    assert lam == [(0.0, 0.45), (0.45, 0.7), (0.7, 0.85), (0.85, 0.95), (0.95, 1.0)]
    assert doc["partitions"][2] == {"lambda_low": 0.7, "lambda_high": 0.85, "clusters": [["T1", "T2"], ["T3", "T4"], ["T5"]], "representatives": ["T2", "T4", "T5"]}
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_corr_form_without_target_and_misuse(tmp_path, capsys):
    c, out = tmp_path / "c.csv", tmp_path / "o.json"
    c.write_text(CORR)
    assert main(["select", "--method", "maxtree", "--corr", str(c), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["representative_rule"].startswith("max mean similarity")
    assert main(["select", "--method", "stepwise", "--corr", str(c), "--json", str(out)]) == 2
    assert "--method maxtree only" in capsys.readouterr().err


def test_corr_csv_with_row_labels(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("sensor,a,b\na,1,0.5\nb,0.5,1\n")
    M, names = read_corr_csv(str(p))
    assert names == ["a", "b"] and np.allclose(M, [[1, 0.5], [0.5, 1]])
    p.write_text("a,b\na,1,0.5\nb,0.5,1\n")
    assert read_corr_csv(str(p))[1] == ["a", "b"]


@pytest.mark.parametrize(
    "text, message",
    [
        ("a,b\n1,0.5\n0.5,x\n", "line 3 column 2: not a number: 'x'"),
        ("a,b\n1,0.5\n0.5\n", "line 3: 1 values, expected 2"),
        ("a,b,c\n1,0.5,0.1\n0.5,1,0.2\n", "3 sensor names in the header but 2 matrix rows"),
        ("a,a\n1,0.5\n0.5,1\n", "appear more than once"),
        ("a,b\n1,0.5\n\n0.5,1\n", "line 3: blank line"),
        ("sensor,a,b\na,1,0.5\nc,0.5,1\n", "line 3: row is labelled 'c'"),
        ("a,b\n1,0.5\n0.6,1\n", "not symmetric"),
        ("", "file is empty"),
        ("a,b\n", "no matrix rows"),
    ],
)
def test_corr_csv_errors_name_file_and_line(tmp_path, capsys, text, message):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    assert main(["select", "--method", "maxtree", "--corr", str(p), "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err
    assert message in err
    if "line" in message:
        assert str(p) in err


@pytest.mark.parametrize(
    "text, message",
    [
        ("a,0.5\nb,x\n", "line 2 column 2: not a number"),
        ("a,0.5\nc,0.1\n", "line 2: sensor 'c' is not in the correlation matrix"),
        ("a,0.5\na,0.1\n", "line 2: sensor 'a' appears a second time"),
        ("sensor,r\na,0.5\n", "no target correlation for sensor(s) b"),
        ("a,0.5,1\n", "line 1: expected 2 cells"),
        ("a,1.5\nb,0\n", "outside [-1, 1]"),
    ],
)
def test_target_corr_errors(tmp_path, text, message):
    from host.learning.empirical.selectors import SelectionError

    p = tmp_path / "t.csv"
    p.write_text(text)
    with pytest.raises(SelectionError, match=None) as exc:
        read_target_corr_csv(str(p), ["a", "b"])
    assert message in str(exc.value) and str(p) in str(exc.value)


def test_library_on_runs_and_run_arrays_names_the_runs(twin_runs):
    from host.learning.empirical.selectors import select
    from host.learning.empirical.targets import training_arrays
    from host.data.runs import load_runs

    runs = load_runs(twin_runs)
    via_runs = select("hclust-ga", runs, seed=5, population=8, generations=3)
    via_arrays = select("hclust-ga", training_arrays(runs), seed=5, population=8, generations=3)
    assert via_runs.sensors == via_arrays.sensors
    assert via_runs.reason["train_run"] == PROTOCOLS[0]
    assert via_arrays.reason["test_runs"] == list(PROTOCOLS[1:])
    # plain tuples carry no start temperatures, so they are clustered as given (rises here):
    # the same choice as the runs clustered on rises (labels differ only)
    plain = select("hclust-ga", [tuple(a) for a in training_arrays(runs)], seed=5, population=8, generations=3)
    on_rises = select("hclust-ga", runs, seed=5, population=8, generations=3, distance_on="rises")
    assert plain.sensors == on_rises.sensors and plain.reason["test_runs"] == ["run 2", "run 3"]
    assert plain.reason["distance_on"].startswith("values as given") and via_runs.reason["distance_on"] == "values"


def test_split_one_long_run_into_windows(twin_runs, tmp_path):
    out = tmp_path / "split.json"
    assert main(["select", "--method", "hclust-ga", twin_runs[0], "--split", "3", "--option", "population=8", "--option", "generations=3", "--json", str(out)]) == 0
    r = json.loads(out.read_text())["reason"]
    assert r["train_run"].startswith(PROTOCOLS[0] + "[0-") and len(r["test_runs"]) == 2
    # windows partition the run's sweeps: 21 sweeps -> 7 + 7 + 7
    assert r["samples_train"] == 7
    assert main(["select", "--method", "maxtree", twin_runs[0], "--split", "0", "--json", str(out)]) == 2


def test_runs_path_is_blind_to_a_sensor_offset(twin_runs):
    """From run folders the features are temperature rises, so a sensor read 3.7 K too high
    (a calibration offset) changes nothing in any method, hclust-ga's Euclidean part included when it
    clusters rises. (Its default D_e on measured values sees the offset by design, Li 2017: a gap in value
    says where a sensor sits; on the whole temperature log that shows, issue 23.)"""
    from host.learning.empirical.selectors import select
    from host.data.runs import load_runs

    runs = load_runs(twin_runs)
    shifted = load_runs(twin_runs)
    for r in shifted:
        r.temperatures.values[:, r.temperatures.names.index("T4")] += 3.7
    for method, params in (("maxtree", {}), ("stepwise", {"f_enter": 20.0, "f_remove": 10.0}),
                           ("hclust-ga", {"seed": 1, "distance_on": "rises"})):
        assert select(method, runs, **params).sensors == select(method, shifted, **params).sensors, method


def test_correlations_and_distances_use_the_whole_temperature_log(twin_runs):
    """Li 2021 Eq. 11 and Li 2017's D_e/D_r are computed on the temperature series: every logged sample, not
    only the ~21 sweep times; the target stays at the sweeps (it is not interpolated)."""
    from host.learning.empirical.selectors import select
    from host.data.runs import load_runs

    runs = load_runs(twin_runs)
    sel = select("maxtree", runs)
    names = sel.reason["tree"]["sensors"]
    # independent: rises over each run's start of every temperatures.csv row, runs pooled
    L = np.vstack([r.temperatures.values[:, [r.temperatures.names.index(s) for s in names]]
                   - r.temperatures.values[0, [r.temperatures.names.index(s) for s in names]] for r in runs])
    C = np.abs(np.corrcoef(L, rowvar=False))
    for a, b, w in sel.reason["tree"]["edges"]:
        assert w == pytest.approx(C[names.index(a), names.index(b)], abs=1e-12)
    assert sel.reason["similarity_on"].startswith("temperature log: %d samples" % L.shape[0])
    old = select("maxtree", runs, correlation_on="targets")
    assert old.reason["similarity_on"].startswith("target times") and old.reason["tree"]["edges"] != sel.reason["tree"]["edges"]
    ga = select("hclust-ga", runs, seed=1, k=3, alpha=0.5)
    assert ga.reason["series"] == "temperature log of the training run: %d samples" % runs[0].temperatures.time_s.size
    assert select("hclust-ga", runs, seed=1, k=3, alpha=0.5, series="targets").reason["series"].startswith("target times")
