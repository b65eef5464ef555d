"""tcomp check: compensated against uncompensated residual of a check run, pass/fail against a limit.

The board logs here are written by the test from chosen residuals (offset = measured − residual), so the
compensated figures the verb reports are checked against numbers the test knows, not against the model."""
import csv
import json
import os
import shutil

import numpy as np
import pytest

from host.cli import main
from host.data.boardlog import T_MS_WRAP

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRAIN = os.path.join(ROOT, "data", "demo", "v8000_r210_490")
CHECK = os.path.join(ROOT, "data", "demo", "v8000_r0_700")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("chk") / "mlr.json")
    assert main(["fit", "--model", "mlr", TRAIN, "--sensors", "T1,T2,T3,T4,T5", "--out", path]) == 0
    return path


def _errors():
    with open(os.path.join(CHECK, "errors.csv")) as fh:
        rows = list(csv.DictReader(fh))
    return (np.array([float(r["time_s"]) for r in rows]), np.array([float(r["position_mm"]) for r in rows]),
            np.array([float(r["error_um"]) for r in rows]))


def _monitor_log(path, t0_ms, residual, time_shift_s=0.0):
    """A tcomp monitor --csv log whose offsets leave ``residual`` at every row, with H frames in between."""
    t, p, e = _errors()
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["seq", "kind", "status", "flags", "t_ms", "pos_um", "total_um", "ref_offset_um", "slope_um_per_m", "fields"])
        for i in range(t.size):
            tick = (t0_ms + int(round((t[i] + time_shift_s) * 1000)) + i) % T_MS_WRAP  # + i ms: a sweep's positions in turn
            w.writerow([i, "H", "00000000", "", "", "", "", "", "", "1,2"])
            w.writerow([i, "O", "00000000", "", tick, int(round(p[i] * 1000)), "%.1f" % (e[i] - residual[i]), "0.0", "0.00", ""])
    return path


def test_check_with_a_board_log_reports_the_residuals_it_leaves(model, tmp_path, capsys):
    t, _, e = _errors()
    residual = 0.5 * np.sin(np.arange(t.size))  # what the board's offsets leave
    t0 = T_MS_WRAP - 1_000_000  # the tick counter wraps 1000 s into the check
    log = _monitor_log(str(tmp_path / "log.csv"), t0, residual)
    out = str(tmp_path / "c.json")
    rc = main(["check", "--model", model, "--run", CHECK, "--board-log", log, "--board-t0-ms", str(t0),
               "--limit-um", "1", "--json", out])
    assert rc == 0, capsys.readouterr().err
    doc = json.load(open(out))
    c = doc["channels"]["error"]
    r = e - np.round(e - residual, 1)  # the log holds the offsets to 0.1 µm, as the wire does
    assert c["compensated"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(r ** 2)), rel=1e-9)
    assert c["compensated"]["max_abs_residual_um"] == pytest.approx(np.abs(r).max(), rel=1e-9)
    assert c["uncompensated"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(e ** 2)), rel=1e-9)
    assert c["uncompensated"]["max_abs_residual_um"] == pytest.approx(np.abs(e).max(), rel=1e-9)
    assert doc["pass"] is True and doc["compensation"] == "board_log"
    # the same log against a tighter limit fails, exit 1
    assert main(["check", "--model", model, "--run", CHECK, "--board-log", log, "--board-t0-ms", str(t0),
                 "--limit-um", "0.3"]) == 1
    assert "FAIL" in capsys.readouterr().out


def test_check_without_a_board_log_uses_the_host_model(model, tmp_path, capsys):
    pred_csv = str(tmp_path / "p.csv")
    assert main(["predict", model, CHECK, "--out", pred_csv]) == 0
    with open(pred_csv) as fh:
        pred = np.array([float(r["predicted_um"]) for r in csv.DictReader(fh)])
    _, _, e = _errors()
    r = e - pred
    out = str(tmp_path / "c.json")
    limit = float(np.abs(r).max())
    assert main(["check", "--model", model, "--run", CHECK, "--limit-um", "%.6f" % (limit * 1.001), "--json", out]) == 0
    doc = json.load(open(out))
    assert doc["compensation"] == "host_model"
    assert doc["channels"]["error"]["compensated"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(r ** 2)), rel=1e-3)
    assert main(["check", "--model", model, "--run", CHECK, "--limit-um", "%.6f" % (limit * 0.99)]) == 1


def _fails(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "\n" not in err and "Traceback" not in err
    return err


def test_check_names_a_misaligned_log(model, tmp_path, capsys):
    t, _, _ = _errors()
    log = _monitor_log(str(tmp_path / "log.csv"), 5000, np.zeros(t.size), time_shift_s=600.0)
    err = _fails(capsys, ["check", "--model", model, "--run", CHECK, "--board-log", log, "--board-t0-ms", "5000",
                          "--limit-um", "5"])
    assert "row 1 (time 0 s, position 0 mm)" in err and "600 s away" in err and "--board-t0-ms" in err
    err = _fails(capsys, ["check", "--model", model, "--run", CHECK, "--board-log", log, "--limit-um", "5"])
    assert "give --board-t0-ms" in err


def test_check_names_a_missing_channel_and_position(model, tmp_path, capsys):
    log = str(tmp_path / "aligned.csv")
    with open(log, "w") as fh:
        fh.write("time_s,position_mm,offset_um\n0,0,1.0\n")
    err = _fails(capsys, ["check", "--model", model, "--run", CHECK, "--board-log", log, "--limit-um", "5"])
    assert "row 2 (time 0 s, position 50 mm)" in err and "no offset at this position" in err
    doc = json.load(open(model))
    doc["channel"] = "Y"
    doc.pop("provenance")
    other = str(tmp_path / "y.json")
    json.dump(doc, open(other, "w"))
    run = str(tmp_path / "run")
    shutil.copytree(CHECK, run)
    with open(os.path.join(run, "errors.csv")) as fh:
        lines = fh.read().splitlines()
    with open(os.path.join(run, "errors.csv"), "w") as fh:
        fh.write("\n".join([lines[0] + ",channel"] + [ln + ",X1" for ln in lines[1:]]) + "\n")
    err = _fails(capsys, ["check", "--model", other, "--run", run, "--limit-um", "5"])
    assert "errors.csv has no channel 'Y'" in err and "its channels: X1" in err
    err = _fails(capsys, ["check", "--model", model, "--run", CHECK, "--limit-um", "0"])
    assert "--limit-um 0.0: must be a positive number" in err


def test_check_reads_the_answers_of_tcomp_hil(model, tmp_path, capsys):
    t, p, e = _errors()
    residual = 0.2 * np.cos(np.arange(t.size))
    answers = [{"time_s": float(a), "position_mm": float(b), "offset_um": round(float(c - r), 1), "status": "00800000"}
               for a, b, c, r in zip(t, p, e, residual)]
    log = str(tmp_path / "hil.json")
    json.dump({"answers": answers, "frames": 1}, open(log, "w"))
    out = str(tmp_path / "c.json")
    assert main(["check", "--model", model, "--run", CHECK, "--board-log", log, "--limit-um", "1", "--json", out]) == 0
    c = json.load(open(out))["channels"]["error"]
    r = e - np.array([a["offset_um"] for a in answers])
    assert c["compensated"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(r ** 2)), rel=1e-9)
    assert c["board_vs_model"]["rows"] == t.size
    answers[7]["offset_um"] = None
    json.dump({"answers": answers}, open(log, "w"))
    err = _fails(capsys, ["check", "--model", model, "--run", CHECK, "--board-log", log, "--limit-um", "1"])
    assert "answers[7].offset_um is None" in err


def test_check_window_checks_only_its_rows_and_counts_the_others(model, tmp_path, capsys):
    """--t-min/--t-max: a log that begins after the run's first sweeps; without the window the first row is an
    error, with it the figures are those of the rows inside [S, S') and the rows left out are counted."""
    t, _, e = _errors()
    times = np.unique(t)
    s, s2 = float(times[2]), float(times[-2])
    inside = (t >= s) & (t < s2)
    residual = np.where(inside, 0.25, 50.0)  # outside the window the log's offsets are far off
    log = _monitor_log(str(tmp_path / "log.csv"), 5000, residual)
    argv = ["check", "--model", model, "--run", CHECK, "--board-log", log, "--board-t0-ms", "5000", "--limit-um", "1"]
    assert main(argv) == 1  # the whole run: the rows outside fail it
    capsys.readouterr()
    out = str(tmp_path / "c.json")
    assert main(argv + ["--t-min", repr(s), "--t-max", repr(s2), "--json", out]) == 0
    text = capsys.readouterr().out
    doc = json.load(open(out))
    c = doc["channels"]["error"]
    assert c["rows"] == int(inside.sum()) and doc["rows_outside_window"] == int((~inside).sum())
    assert "%d rows of the model's channel outside it not checked" % (~inside).sum() in text, text
    assert c["uncompensated"]["rmse_um"] == pytest.approx(np.sqrt(np.mean(e[inside] ** 2)), rel=1e-9)
    assert c["compensated"]["max_abs_residual_um"] == pytest.approx(
        np.abs(e[inside] - np.round(e[inside] - 0.25, 1)).max(), rel=1e-9)
    assert main(argv + ["--t-min", "1e9"]) == 2
    assert "no errors.csv row of the model's channel in the window 1e+09..- s" in capsys.readouterr().err
    assert main(argv + ["--t-min", "10", "--t-max", "5"]) == 2
    assert "the window is empty" in capsys.readouterr().err
