"""docs/commissioning.md, run as written: every ```sh block of the page, in order, as one bash script (set -e), in an
empty folder, with TCOMP (the checkout) and PATH (its .venv/bin first) set as the page says. The twin is the machine,
`tcomp board` the board (the firmware under the 32-bit MicroPython port), and every step is the real verb in its own
process: simulate, board, record, laser export, import --errors --into, validate, fit, export, hil, upload, monitor,
check, report.

Then what the steps produced is checked against what they should be, from outside the verbs that made it: the merged
sweeps are the twin's own errors at the twin's times on the recording's clock; the board's hello names the uploaded
table; the board log's offsets at the check day's rows come from the uploaded table (they match the host model); the
check passes, and it FAILS when another table is uploaded instead (the same commands, one file swapped)."""
import csv
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.rig, pytest.mark.micropython]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(ROOT, "docs", "commissioning.md")


def doc_blocks():
    """The ```sh blocks of docs/commissioning.md, in order (a heredoc's lines stay in their block)."""
    with open(DOC, encoding="utf-8") as fh:
        text = fh.read()
    return re.findall(r"^```sh\n(.*?)^```$", text, re.S | re.M)


def _env():
    env = dict(os.environ)
    env["TCOMP"] = ROOT
    env["PATH"] = os.path.join(ROOT, ".venv", "bin") + os.pathsep + os.path.dirname(sys.executable) + os.pathsep + \
        env.get("PATH", "")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


# a step that fails ends the script (set -e): the boards it started in the background are stopped then (Ctrl-C),
# as the reader's would be, so that a failing step fails the test at once instead of leaving a board running
STOP_BOARDS_ON_EXIT = "trap 'for p in $(jobs -p); do kill -INT $p 2>/dev/null; done; wait' EXIT\n"


def run_script(folder, script, timeout=600):
    """bash -e of ``script`` in ``folder``; (exit code, output, wall seconds). On a timeout every process of the
    script (its own session) is killed."""
    t = time.monotonic()
    p = subprocess.Popen(["bash", "-c", "set -euo pipefail\n" + STOP_BOARDS_ON_EXIT + script], cwd=str(folder),
                         env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         start_new_session=True)
    try:
        out, _ = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, _ = p.communicate()
        raise AssertionError("docs/commissioning.md's script did not end within %d s:\n%s" % (timeout, out[-3000:]))
    return p.returncode, out, time.monotonic() - t


@pytest.fixture(scope="module")
def walked(tmp_path_factory):
    from hil_tests.rig import interpreters
    interpreters.get().require()
    folder = tmp_path_factory.mktemp("commissioning")
    blocks = doc_blocks()
    rc, out, wall = run_script(folder, "\n".join(blocks))
    print("\ndocs/commissioning.md: %d blocks, exit %d, %.1f s wall" % (len(blocks), rc, wall))
    return folder, rc, out, wall


def test_the_page_covers_the_whole_path():
    """The verbs of the path, in this order, each in a block the test runs (a step taken out of the page, or put
    outside an sh block, fails here)."""
    words = [shlex.split(line)[1] for b in doc_blocks() for line in b.splitlines()
             if line.startswith("tcomp ")]
    assert words == ["simulate", "simulate", "board", "record", "import", "validate", "fit", "export", "hil", "board",
                     "upload", "monitor", "check", "report"], words
    assert any("tools/laser_export.py" in b for b in doc_blocks())


def test_the_walkthrough_runs_as_written(walked):
    folder, rc, out, wall = walked
    assert rc == 0, out[-4000:]
    assert "Traceback" not in out, out[-4000:]
    print("the walkthrough's wall time: %.1f s" % wall)


def test_the_merged_sweeps_are_the_twins_on_the_recordings_clock(walked):
    """errors.csv of the recorded run, after the laser's export went through import --errors --into: the twin's
    errors, positions and directions, at the twin's sweep times minus the twin time of the recording's time 0."""
    folder, rc, out, _ = walked
    assert rc == 0, out[-3000:]
    meta = json.loads((folder / "test" / "meta.json").read_text())
    t0_s = meta["record"]["t_ms_at_time_0"] / 1000.0  # the board started with the twin's time 0

    def rows(path):
        with open(path, newline="") as fh:
            return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    twin = rows(folder / "twin-test" / "errors.csv")
    got = rows(folder / "test" / "errors.csv")
    assert len(got) >= 5 * 15, len(got)  # at least 5 of the 9 sweeps lie inside the recording
    by_key = {(round(r["time_s"], 3), r["position_mm"]): r["error_um"] for r in twin}
    for r in got:
        key = (round(r["time_s"] + t0_s, 3), r["position_mm"])
        assert key in by_key, (r, t0_s)
        assert abs(r["error_um"] - by_key[key]) <= 1e-9, (r, by_key[key])  # the twin writes 4 decimals, so does the export
    temps = rows(folder / "test" / "temperatures.csv")
    assert got[0]["time_s"] >= temps[0]["time_s"] and got[-1]["time_s"] + 14 * 4.0 <= temps[-1]["time_s"]


def test_the_uploaded_table_is_in_force_and_drives_the_check(walked):
    folder, rc, out, _ = walked
    assert rc == 0, out[-3000:]
    from firmware.table import parse_table
    crc = "%08X" % parse_table((folder / "table.bin").read_bytes()).crc
    assert "ttyTC: table %s in force in slot A (was no table)" % crc in out, out[-3000:]
    check = json.loads((folder / "check.json").read_text())
    assert check["pass"] is True and check["compensation"] == "board_log"
    (ch,) = check["channels"].values()
    # the board's offsets are the uploaded table's: they match the model it was exported from (the table's
    # quantisation and the board's sensor noise), and they take most of the error away
    assert ch["board_vs_model"]["max_abs_residual_um"] < 0.5, ch
    assert ch["compensated"]["rmse_um"] < 0.5 * ch["uncompensated"]["rmse_um"], ch
    assert ch["rows"] >= 30 and check["rows_outside_window"] == 15, check
    print("production check: %d rows; uncompensated RMSE %.2f um (max %.2f), compensated by the board RMSE %.2f um "
          "(max %.2f); board - model max %.3f um" % (
              ch["rows"], ch["uncompensated"]["rmse_um"], ch["uncompensated"]["max_abs_residual_um"],
              ch["compensated"]["rmse_um"], ch["compensated"]["max_abs_residual_um"],
              ch["board_vs_model"]["max_abs_residual_um"]))
    report = folder / "report"
    assert (report / "report.html").stat().st_size > 1000 and json.loads((report / "report.json").read_text())


def test_the_check_fails_when_another_table_is_uploaded(walked, demo_run):
    """Steps 7 and 8 of the page again, with another table in table.bin's place (a poly_slope table of the same
    sensors that is not this machine's): the check must say FAIL (exit 1)."""
    folder, rc, out, _ = walked
    assert rc == 0, out[-3000:]
    from hil_tests.rig.boards import export, poly_slope_for_run
    (folder / "wrong.bin").write_bytes(export(poly_slope_for_run(demo_run, ["T1", "T2", "T4"], seed=7)).table)
    blocks = doc_blocks()
    start = next(i for i, b in enumerate(blocks) if "tcomp upload" in b)
    script = "\n".join(b.replace("--table table.bin", "--table wrong.bin").replace("board-log.csv", "wrong-log.csv")
                       .replace("check.json", "wrong-check.json") for b in blocks[start:start + 2])
    assert "--table wrong.bin" in script and "tcomp check" in script and "tcomp report" not in script
    rc2, out2, _ = run_script(folder, script)
    assert rc2 == 1, out2[-3000:]  # tcomp check's FAIL, the last command
    assert "tcomp check: FAIL" in out2, out2[-3000:]
    wrong = json.loads((folder / "wrong-check.json").read_text())
    assert wrong["pass"] is False
