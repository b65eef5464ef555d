"""``tcomp record`` on the rig: a board (the firmware under the 32-bit MicroPython port) whose simulated chips follow a
temperature ramp, recorded by the real command in its own process over the pty, as on a controller.

The recorded run validates; its temperatures are the ramp the chips were given (within the RTD chain); its
time_s runs on across the board clock's 2^30 ms wrap; a recorder stopped by SIGINT, killed by SIGKILL, cut off by
a lost board or by a full disk (a file-size limit) leaves a valid run holding every sample up to the last one
written (docs/recording.md)."""
import json
import os
import resource
import signal
import subprocess
import sys
import time

import pytest

from hil_tests.rig.boards import rig_config

pytestmark = pytest.mark.rig
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WRAP = 1 << 30
SENSORS = ["T1", "T2", "T4"]
START = {"T1": 21.0, "T2": 22.5, "T4": 20.0}
END = {"T1": 26.0, "T2": 24.0, "T4": 19.0}
RAMP_MS = 60000
# Pt100 chain on the rig's chips: MAX31865 15-bit codes (~0.03 degC) and ADS122C04 24-bit; the board rounds to
# milli-degC; a T frame holds the last cycle's (100 ms) reading, which lags a 5 K/min ramp by < 0.01 degC
TOLERANCE_C = 0.05


def _start_recorder(rig, out, *extra, period="0.05", preexec_fn=None, sensors=None):
    if sensors is None:
        sensors = [a for s, r in zip(SENSORS, ("nut", "base", "ambient")) for a in ("--sensor", "%s=%s" % (s, r))]
    argv = [sys.executable, "-m", "host", "record", "--port", rig.port, "--out", str(out), "--period", period,
            "--link-timeout", "3"] + sensors
    return subprocess.Popen(argv + list(extra), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=preexec_fn)


def _wait_rows(out, n, p, timeout=60):
    """Until the recorder has written ``n`` rows (the recorder's start-up takes real time the board does not wait)."""
    path = os.path.join(out, "temperatures.csv")
    end = time.monotonic() + timeout
    while time.monotonic() < end and p.poll() is None:
        if os.path.exists(path) and open(path).read().count("\n") > n:
            return
        time.sleep(0.05)
    raise AssertionError("the recorder wrote fewer than %d rows (exit %r)" % (n, p.poll()))


def _rig(make_rig, start_ms=0):
    rig = make_rig(rig_config(SENSORS), temps=START, start_ms=start_ms, open_port=False)
    rig.run(2000)
    rig.ramp(rig.t_ms + RAMP_MS, END)
    return rig, rig.t_ms


def _expected(rig_ms, ramp_from_ms):
    """The temperature each simulated chip was given at power-on time ``rig_ms``."""
    a = min(max((rig_ms - ramp_from_ms) / RAMP_MS, 0.0), 1.0)
    return {s: START[s] + a * (END[s] - START[s]) for s in SENSORS}


def _rows(out):
    with open(os.path.join(out, "temperatures.csv")) as fh:
        lines = fh.read().split("\n")
    assert lines[0] == "time_s," + ",".join(SENSORS) and lines[-1] == "", lines[:1] + lines[-2:]  # whole lines only
    return [[float(c) for c in line.split(",")] for line in lines[1:-1]]


def _valid(out):
    from host.cli import main as tcomp
    from host.data.runs import check_run
    assert check_run(str(out)) == []
    assert tcomp(["validate", str(out)]) == 0


def _check_against_chips(out, rows, ramp_from_ms, start_ms):
    meta = json.loads(open(os.path.join(out, "meta.json")).read())
    t0 = meta["record"]["t_ms_at_time_0"]
    zero_rig_ms = (t0 - start_ms) % WRAP  # power-on time of time_s 0
    worst = 0.0
    for r in rows:
        want = _expected(zero_rig_ms + r[0] * 1000.0, ramp_from_ms)
        worst = max(worst, max(abs(v - want[s]) for s, v in zip(SENSORS, r[1:])))
    assert worst <= TOLERANCE_C, worst
    return meta


@pytest.mark.parametrize("interpreter", ["micropython"], indirect=True)
def test_record_follows_the_chips_across_the_clock_wrap(make_rig, tmp_path):
    """A 40-simulated-second slice of the ramp, the board clock wrapping in the middle of it."""
    start_ms = WRAP - 20000
    rig, ramp_from = _rig(make_rig, start_ms)
    out = tmp_path / "rec"
    p = _start_recorder(rig, out)
    with rig.free_run(chunk_ms=20, pace_s=0.001):
        while p.poll() is None and rig.t_ms < 45000:
            time.sleep(0.05)
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=20)
    assert p.returncode == 0, stderr
    _valid(out)
    rows = _rows(out)
    assert len(rows) >= 20, stdout
    times = [r[0] for r in rows]
    assert all(b > a for a, b in zip(times, times[1:]))
    meta = _check_against_chips(out, rows, ramp_from, start_ms)
    t0 = meta["record"]["t_ms_at_time_0"]
    assert t0 + 1000 * times[0] < WRAP < t0 + 1000 * times[-1], (t0, times[0], times[-1])  # the wrap is inside
    from firmware.wire import FIRMWARE_VERSION
    assert meta["board"]["firmware"] == FIRMWARE_VERSION and meta["board"]["channel_names"] == SENSORS
    assert meta["sensors"]["T1"]["role"] == "nut" and meta["start_time"].endswith("+00:00")
    assert "%d samples in" % len(rows) in stdout


@pytest.mark.parametrize("interpreter", ["micropython"], indirect=True)
@pytest.mark.parametrize("how", ["SIGINT", "SIGKILL"])
def test_an_interrupted_recording_is_a_valid_run(make_rig, tmp_path, how):
    """Worst case for SIGKILL: the sample whose S was sent and not yet written; every earlier one is in the file."""
    rig, ramp_from = _rig(make_rig)
    out = tmp_path / "rec"
    p = _start_recorder(rig, out)
    with rig.free_run(chunk_ms=20, pace_s=0.001):
        _wait_rows(out, 15, p)
        p.send_signal(getattr(signal, how))
        p.communicate(timeout=20)
        killed_at = rig.t_ms
    assert p.returncode == (0 if how == "SIGINT" else -signal.SIGKILL)
    _valid(out)
    rows = _rows(out)
    assert len(rows) >= 10
    meta = _check_against_chips(out, rows, ramp_from, 0)
    steps = sorted(b[0] - a[0] for a, b in zip(rows, rows[1:]))
    step_ms = 1000 * steps[len(steps) // 2]
    # no gap inside, and nothing missing at the end but the samples in flight when the signal came
    assert 1000 * steps[-1] <= 10 * step_ms + 500, steps[-5:]
    last_ms = meta["record"]["t_ms_at_time_0"] + 1000 * rows[-1][0]
    assert killed_at - last_ms <= 10 * step_ms + 500, (killed_at, last_ms, step_ms)


@pytest.mark.parametrize("interpreter", ["micropython"], indirect=True)
def test_a_lost_board_ends_the_recording_with_a_message_and_a_valid_run(make_rig, tmp_path):
    rig, ramp_from = _rig(make_rig)
    out = tmp_path / "rec"
    p = _start_recorder(rig, out)
    with rig.free_run(chunk_ms=20, pace_s=0.001):
        _wait_rows(out, 10, p)
    rig.kill()  # power cut: the board answers nothing more
    t = time.monotonic()
    stdout, stderr = p.communicate(timeout=30)
    assert p.returncode == 1 and time.monotonic() - t < 15
    assert "no answer to S from %s within 3 s: the link is lost" % rig.port in stderr, stderr
    assert "the run holds every sample recorded before" in stderr
    _valid(out)
    rows = _rows(out)
    assert len(rows) >= 5
    _check_against_chips(out, rows, ramp_from, 0)


@pytest.mark.parametrize("interpreter", ["cpython"], indirect=True)
def test_a_full_disk_ends_the_recording_with_whole_lines(make_rig, tmp_path):
    """RLIMIT_FSIZE makes the kernel refuse writes past 3000 bytes (EFBIG, as ENOSPC on a full disk): the row that
    does not fit is cut back, the run validates with the rows before it."""
    rig, ramp_from = _rig(make_rig)
    out = tmp_path / "rec"
    limit = 3000

    def limit_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    p = _start_recorder(rig, out, preexec_fn=limit_files)
    with rig.free_run(chunk_ms=20, pace_s=0.001):
        stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 1, stderr
    assert "temperatures.csv: cannot write (" in stderr and "the run holds the" in stderr, stderr
    _valid(out)
    rows = _rows(out)
    size = os.path.getsize(os.path.join(out, "temperatures.csv"))
    assert limit - 60 < size <= limit and len(rows) >= 20
    _check_against_chips(out, rows, ramp_from, 0)


@pytest.mark.parametrize("interpreter", ["cpython"], indirect=True)
def test_channel_names_come_from_the_board_config_and_must_match_the_board(make_rig, tmp_path):
    rig, _ = _rig(make_rig)
    cfg = tmp_path / "board.json"
    cfg.write_text(json.dumps(rig_config(SENSORS)))
    roles = ["--sensor", "T4=ambient:air", "--sensor", "T1=nut", "--sensor", "T2=base"]  # by name, any order

    def record(out, *argv):
        return subprocess.run([sys.executable, "-m", "host", "record", "--port", rig.port, "--out", str(out)]
                              + list(argv), cwd=ROOT, capture_output=True, text=True, timeout=60)
    with rig.free_run(chunk_ms=20, pace_s=0.001):
        few = record(tmp_path / "few", "--sensor", "T1=nut", "--duration", "1")
        missing = record(tmp_path / "m", "--config", str(cfg), "--sensor", "T1=nut", "--sensor", "T9=base")
        p = _start_recorder(rig, tmp_path / "rec", "--config", str(cfg), "--duration", "3", sensors=roles)
        stdout, stderr = p.communicate(timeout=60)
    assert few.returncode == 2 and not os.path.exists(tmp_path / "few")
    assert "the board reports 3 channels; give one --sensor NAME=ROLE per channel, in channel order (1 given: T1)" \
        in few.stderr, few.stderr
    assert missing.returncode == 2 and "missing T2, T4; not a channel of the board config: T9" in missing.stderr, \
        missing.stderr
    assert p.returncode == 0, stderr
    _valid(tmp_path / "rec")
    meta = json.loads(open(os.path.join(tmp_path / "rec", "meta.json")).read())
    assert meta["board"]["channel_names"] == SENSORS and meta["errors_pending"] is True
    assert meta["sensors"]["T4"] == {"role": "ambient", "location": "air"}
    assert _rows(tmp_path / "rec")  # the config's channel order: time_s,T1,T2,T4
