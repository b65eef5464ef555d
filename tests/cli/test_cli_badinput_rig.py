"""Bad flags and configs of `tcomp hil` and `tcomp discrepancy` are named before any work starts."""
import json
import os

import pytest

from host.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RUN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    d = tmp_path_factory.mktemp("t")
    assert main(["fit", "--model", "mlr", RUN, "--sensors", "T1,T2", "--out", str(d / "m.json")]) == 0
    assert main(["export", str(d / "m.json"), "--out", str(d / "t.bin")]) == 0
    return str(d / "t.bin")


@pytest.mark.parametrize("cfg,message", [
    ([], "a board config is a JSON object"),
    ({"channels": "x"}, "channels: expected a list of 1..16 channels"),
])
def test_hil_config_is_checked_by_the_firmware_validator(tmp_path, table, capsys, cfg, message):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(cfg))
    assert main(["hil", "--run", RUN, "--table", table, "--config", str(path)]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("flag,value", [("--warmup-s", "-5"), ("--noise-uohm", "-1")])
def test_hil_negative_settings(table, capsys, flag, value):
    assert main(["hil", "--run", RUN, "--table", table, flag, value]) == 2
    assert "%s must be >= 0" % flag in capsys.readouterr().err


@pytest.mark.parametrize("flag,value,message", [
    ("--jobs", "0", "--jobs must be at least 1"),
    ("--max-effects", "-1", "--max-effects must be at least 1"),
    ("--min-gain", "1.5", "--min-gain must be in [0, 1)"),
])
def test_discrepancy_bad_settings(tmp_path, capsys, flag, value, message):
    rc = main(["discrepancy", RUN, flag, value, "--json", str(tmp_path / "d.json"), "--report", str(tmp_path / "r")])
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()
