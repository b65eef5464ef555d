"""tcomp import: mapping strictness, and the bundled real data equals its source."""
import csv
import hashlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from host.data.importer import LogImportError, import_csv
from host.data.runs import load_run

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SOURCE = os.path.join(ROOT, "..", "shared", "data", "fl_thermal", "fl_thermal.csv")
BUNDLED = os.path.join(ROOT, "data", "fl_thermal")


def _write(path, rows):
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return str(path)


def test_bundled_real_run_is_valid_and_complete():
    run = load_run(BUNDLED)
    assert run.temperatures.names == ["t%d" % i for i in range(1, 17)]
    assert run.errors.channels() == ["ch%d" % i for i in range(1, 6)]
    assert run.temperatures.time_s.size == 11115
    assert len(run.errors) == 5 * 11115
    assert os.path.exists(os.path.join(BUNDLED, "LICENSE"))
    assert run.meta["source"]["licence"] == "MIT"


# The source's values, fingerprinted: sha256 of the int64 (little-endian) array round(value * 1e6) of
# fl_thermal.csv, rows in file order, columns in SOURCE_COLUMNS order (6 decimals is the source's precision).
# Recorded from ../shared/data/fl_thermal/fl_thermal.csv; the test checks the bundled run against it in any
# clone, and the fingerprint against the source itself wherever the source is beside the repo.
SOURCE_COLUMNS = ["time_s", "spindle_rpm"] + ["ch%d_um" % i for i in range(1, 6)] + ["t%d_C" % i for i in range(1, 17)]
SOURCE_VALUES_SHA256 = "adafe292d299edc3df5e7027bae1f7b24cb46c06d0591474952bd76ed08ef9bc"


def _values_sha256(columns):
    micro = np.rint(np.column_stack(columns) * 1e6).astype("<i8")
    return hashlib.sha256(np.ascontiguousarray(micro).tobytes()).hexdigest()


def test_bundled_real_run_equals_source():
    run = load_run(BUNDLED)
    channel_rows = [run.errors.channel == "ch%d" % i for i in range(1, 6)]
    for rows_ in channel_rows:  # one measurement per channel at every temperature time, in order
        np.testing.assert_array_equal(run.errors.time_s[rows_], run.temperatures.time_s)
    np.testing.assert_array_equal(run.spindle.time_s, run.temperatures.time_s)
    bundled = ([run.temperatures.time_s, run.spindle.rpm] + [run.errors.error_um[r] for r in channel_rows]
               + [run.temperatures.column("t%d" % i) for i in range(1, 17)])
    assert _values_sha256(bundled) == SOURCE_VALUES_SHA256
    if os.path.exists(SOURCE):  # the fingerprint is the source's (the shared reference copy is beside the repo)
        with open(SOURCE) as fh:
            rows = list(csv.reader(fh))
        src = np.array(rows[1:], dtype=float)
        assert _values_sha256([src[:, rows[0].index(c)] for c in SOURCE_COLUMNS]) == SOURCE_VALUES_SHA256


def test_unmapped_column_is_an_error(tmp_path):
    src = _write(tmp_path / "log.csv", [["t", "a", "d", "extra"], [0, 20, 1, 5], [1, 21, 2, 6]])
    with pytest.raises(LogImportError, match="column 'extra' is neither mapped nor listed in 'ignore'"):
        import_csv(src, {"time": "t", "temperatures": ["a"], "errors": ["d"]})
    run = import_csv(src, {"time": "t", "temperatures": ["a"], "errors": ["d"], "ignore": ["extra"]})
    assert run.meta["import"]["ignored_columns"] == ["extra"]


def test_bad_cells_and_time(tmp_path):
    src = _write(tmp_path / "log.csv", [["t", "a", "d"], [0, 20, 1], [2, "oops", 2], [1, 21, 3]])
    with pytest.raises(LogImportError) as exc:
        import_csv(src, {"time": "t", "temperatures": ["a"], "errors": ["d"]})
    assert "line 3 column 'a': not a number: 'oops'" in str(exc.value)
    src = _write(tmp_path / "log2.csv", [["t", "a", "d"], [0, 20, 1], [2, 20, 2], [1, 21, 3]])
    with pytest.raises(LogImportError, match="line 4 column 't': time goes backwards"):
        import_csv(src, {"time": "t", "temperatures": ["a"], "errors": ["d"]})


def test_mapping_errors(tmp_path):
    src = _write(tmp_path / "log.csv", [["t", "a", "d"], [0, 20, 1]])
    with pytest.raises(LogImportError, match="mapped column 'b' is not in the header"):
        import_csv(src, {"time": "t", "temperatures": ["a", "b"], "errors": ["d"]})
    with pytest.raises(LogImportError, match="role 'hot'"):
        import_csv(src, {"time": "t", "temperatures": {"a": {"role": "hot"}}, "errors": ["d"]})
    with pytest.raises(LogImportError, match="unknown mapping key"):
        import_csv(src, {"time": "t", "temps": ["a"], "errors": ["d"]})


def test_import_cli_with_flags(tmp_path):
    src = _write(tmp_path / "log.csv", [["min", "nut", "air", "probe", "rpm"], [0, 20, 19, 1.5, 0], [1, 21, 19, 2.5, 1000]])
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "host", "import", src, "--out", str(out), "--time", "min", "--time-scale", "60",
                          "--temp", "nut=T1:nut", "--temp", "air=T2:ambient", "--error", "probe=Z@12.5", "--spindle", "rpm",
                          "--json", str(tmp_path / "s.json")], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    run = load_run(str(out))
    assert run.meta["sensors"]["T1"]["role"] == "nut"
    np.testing.assert_array_equal(run.temperatures.time_s, [0, 60])
    assert run.errors.position_mm.tolist() == [12.5, 12.5]
    assert json.load(open(tmp_path / "s.json"))["channels"] == ["Z"]
    bad = subprocess.run([sys.executable, "-m", "host", "import", src, "--out", str(out), "--time", "min", "--temp", "nut", "--error", "probe"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "neither mapped" in bad.stderr


def test_bundled_real_run_regenerates_byte_identical(tmp_path):
    """The documented command (data/fl_thermal/README.md) rebuilds data/fl_thermal byte for byte: the importer's
    handling of real files (dialects, date-times, gaps, units) leaves a plain CSV's import as it was."""
    if not os.path.exists(SOURCE):
        pytest.skip("the shared reference copy %s is not beside this clone" % SOURCE)
    from host.data.importer import import_to_folder

    out = str(tmp_path / "fl")
    with open(os.path.join(ROOT, "data", "fl_thermal_mapping.json")) as fh:
        import_to_folder(SOURCE, json.load(fh), out)
    for f in ("meta.json", "temperatures.csv", "errors.csv", "spindle.csv"):
        with open(os.path.join(out, f), "rb") as a, open(os.path.join(BUNDLED, f), "rb") as b:
            assert a.read() == b.read(), f
