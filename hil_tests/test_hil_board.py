"""`tcomp board`: a simulated board a user starts, on a pty, until Ctrl-C (host/cli/verbs/board.py,
hil_tests/rig/liveboard.py). End to end as a user runs it: start it in its own process, read the pty's
link from its first line, `tcomp monitor --port LINK --duration 3` reads offsets from it, Ctrl-C stops it
cleanly (exit 0, link removed, no process left)."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from hil_tests.rig.boards import export, poly_slope_for_run

pytestmark = [pytest.mark.rig, pytest.mark.micropython]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _start(argv):
    p = subprocess.Popen([sys.executable, "-m", "host", "board"] + argv, cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    first = p.stdout.readline()
    return p, first


def _stop(p):
    p.send_signal(signal.SIGINT)
    try:
        out, err = p.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise AssertionError("tcomp board did not stop within 30 s of Ctrl-C")
    return out, err


def test_board_monitor_reads_offsets_then_ctrl_c_stops_it(tmp_path, demo_run, capsys):
    from hil_tests.rig import interpreters
    from host.cli import main as tcomp
    interpreters.get().require()
    sensors = ["T1", "T2", "T4"]
    (tmp_path / "t.bin").write_bytes(export(poly_slope_for_run(demo_run, sensors, seed=41)).table)
    link = str(tmp_path / "ttyBOARD")
    key = tmp_path / "board.key"
    p, first = _start(["--port", link, "--run", os.path.join(ROOT, "data", "demo", "mixed"),
                       "--table", str(tmp_path / "t.bin"), "--key", str(key)])
    try:
        assert first.startswith("board: /dev/pts/"), first + (p.stderr.read() if p.poll() is not None else "")
        pty = first.split()[1]
        assert os.path.realpath(link) == os.path.realpath(pty)
        assert len(bytes.fromhex(key.read_text().strip())) == 32 and key.stat().st_mode & 0o777 == 0o600
        time.sleep(2.0)  # frames nobody read meanwhile are dropped, not queued for the monitor
        capsys.readouterr()
        rc = tcomp(["monitor", "--port", link, "--duration", "3", "--json", str(tmp_path / "m.json")])
        text = capsys.readouterr().out
        assert rc == 0, text
        got = json.loads((tmp_path / "m.json").read_text())
        rows = [line.split() for line in text.splitlines() if " O " in line]
        assert got["bad"] == [] and got["malformed"] == 0, got
        assert len(rows) >= 2, text  # one O frame per simulated second, in real time
        t_ms = [int(r[3]) for r in rows]
        assert all(b - a == 1000 for a, b in zip(t_ms, t_ms[1:])), t_ms
        assert min(t_ms) >= 2000  # the board's present, not a backlog from its boot
        assert all(r[5] not in ("nan", "0.0") for r in rows), rows  # offsets: the table's, from the run's temperatures
    finally:
        out, err = _stop(p)
    assert p.returncode == 0, err
    assert "board stopped" in out, out
    assert not os.path.lexists(link)
    assert "Traceback" not in err, err


@pytest.mark.parametrize("interpreter,example", [("micropython", "rig.json"), ("qemu", "mps2_an385.json")])
def test_board_steady_room_from_an_example_config_without_table(interpreter, example):
    """--config examples/boards/X.json without a table, --room-c: the board boots from the example, runs with no
    table, and its sensors read the room (S -> T); on the 32-bit port and on the emulated Cortex-M3."""
    import serial

    from host.board.link import StreamDecoder, command_line
    config = os.path.join(ROOT, "examples", "boards", example)
    names = [c["name"] for c in json.load(open(config))["channels"]]
    p, first = _start(["--config", config, "--room-c", "31.5", "--interpreter", interpreter])
    try:
        assert first.startswith("board: /dev/pts/") and "no table" in first, first + p.stderr.read()
        with serial.Serial(first.split()[1], 115200, timeout=0) as ser:
            dec = StreamDecoder()
            frames = []
            end = time.monotonic() + 20
            while time.monotonic() < end and len([f for f in frames if f.kind == "O"]) < 2:
                frames += dec.feed(ser.read(4096))  # two seconds of the board: every channel has read
                time.sleep(0.05)
            ser.write(command_line("S"))
            while time.monotonic() < end and not any(f.kind == "T" for f in frames):
                frames += dec.feed(ser.read(4096))
                time.sleep(0.05)
        temps = [f for f in frames if f.kind == "T"]
        assert temps, frames
        assert all(f.status & 0x200000 for f in frames if f.kind == "O")  # NO_TABLE (firmware/wire.py)
        # T,<t_ms>,<ch0>,<ch1>,... in deg C (docs/protocol.md): every channel reads the room within the noise
        values = [float(v) for v in temps[0].fields[1:]]
        assert len(values) == len(names) and all(abs(v - 31.5) < 0.05 for v in values), temps[0].fields
    finally:
        out, err = _stop(p)
    assert p.returncode == 0, err


def test_board_names_the_make_target_when_the_interpreter_is_not_built(tmp_path, monkeypatch, capsys):
    from hil_tests.rig import interpreters, liveboard
    from host.cli import main as tcomp
    monkeypatch.delenv("TCOMP_MICROPYTHON", raising=False)
    monkeypatch.setattr(interpreters.KINDS["linux32"], "path", str(tmp_path / "nothing" / "micropython"))
    assert tcomp(["board", "--room-c", "20", "--config", str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err
    assert "make setup" in err and "not built" in err, err
    monkeypatch.setattr(liveboard, "QEMU_IMAGE", str(tmp_path / "no-image.elf"))
    assert tcomp(["board", "--interpreter", "qemu", "--config", str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err
    assert "make qemu-image" in err, err


def _quick_start():
    """The commands of README.md's quick start block, comments dropped."""
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    block = text.split("## Quick start", 1)[1].split("```", 2)[1]
    return [line.split("  #", 1)[0].strip() for line in block.splitlines()
            if line.strip() and not line.lstrip().startswith("#")]


def test_readme_quick_start_runs_as_written(tmp_path, capsys):
    """Every command of the README's quick start, in order, with out/ and /tmp/ttyTC moved into tmp_path:
    fit, export, hil (judged), board in its own process, monitor on it, Ctrl-C."""
    import shlex

    from hil_tests.rig import interpreters
    from host.cli import main as tcomp
    interpreters.get().require()
    commands = _quick_start()
    assert commands[0] == "mkdir -p out" and [c.split()[1] for c in commands[1:]] == [
        "fit", "export", "hil", "board", "monitor"], commands
    os.makedirs(tmp_path / "out")
    board = None
    try:
        for line in commands[1:]:
            argv = [w.replace("out/", str(tmp_path / "out") + "/").replace("/tmp/ttyTC", str(tmp_path / "ttyTC"))
                    .replace("data/demo", os.path.join(ROOT, "data", "demo")) for w in shlex.split(line)[1:]]
            if argv[0] == "board":
                board, first = _start(argv[1:])
                assert first.startswith("board: /dev/pts/"), first
                time.sleep(1.0)
                continue
            if argv[0] == "monitor":
                argv[argv.index("--duration") + 1] = "3"  # the README's 10 s, shortened
            capsys.readouterr()
            assert tcomp(argv) == 0, line
            printed = capsys.readouterr().out
            if argv[0] == "hil":
                assert "board vs host model" in printed and "board vs measured" in printed
            if argv[0] == "monitor":
                assert len([r for r in printed.splitlines() if " O " in r]) >= 2, printed
    finally:
        if board is not None:
            _stop(board)
    assert board is not None and board.returncode == 0


def test_board_refuses_bad_input_before_starting(tmp_path, demo_run, capsys):
    """One line naming what is wrong, before any board starts, and nothing written."""
    from hil_tests.rig import interpreters
    from hil_tests.rig.boards import rig_config
    from host.cli import main as tcomp
    interpreters.get().require()
    (tmp_path / "t.bin").write_bytes(export(poly_slope_for_run(demo_run, ["T1", "T2", "T4"], seed=41)).table)
    (tmp_path / "ab.json").write_text(json.dumps(rig_config(["A", "B"])))
    (tmp_path / "taken").write_text("a file of the user's")
    (tmp_path / "bad.key").write_text("not a key\n")
    table, ab = str(tmp_path / "t.bin"), str(tmp_path / "ab.json")
    cases = [
        (["--table", table, "--port", str(tmp_path / "taken")], "exists and is not a symlink"),
        (["--table", table, "--config", ab], "sensor(s) T1, T2, T4 have no channel in the board config"),
        (["--config", ab, "--run", os.path.join(ROOT, "data", "demo", "mixed")],
         "the board's channel(s) A, B are not columns of its temperatures.csv"),
        (["--table", table, "--speed", "0"], "--speed 0: must be above 0"),
        (["--table", table, "--key", str(tmp_path / "bad.key")], "not a board key"),
        (["--room-c", "20"], "give --config"),
        (["--table", table, "--room-c", "95"], "--room-c 95: outside the board's plausible range -20..80 deg C"),
    ]
    before = sorted(os.listdir(tmp_path))
    for argv, words in cases:
        assert tcomp(["board"] + argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, (argv, err)
    assert sorted(os.listdir(tmp_path)) == before
    assert (tmp_path / "taken").read_text() == "a file of the user's"


def test_board_in_modbus_mode_answers_a_modbus_master_in_real_time(tmp_path, demo_run):
    """examples/boards/rig.json switched to Modbus RTU: a pymodbus master (as `tcomp linuxcnc --mode modbus`
    uses) reads the table in force, the room's temperatures and a cycle counter that runs at the wall clock."""
    from pymodbus.client import ModbusSerialClient

    from hil_tests.rig import interpreters
    interpreters.get().require()
    cfg = json.load(open(os.path.join(ROOT, "examples", "boards", "rig.json")))
    cfg["serial"]["mode"] = "modbus"
    (tmp_path / "mb.json").write_text(json.dumps(cfg))
    table = export(poly_slope_for_run(demo_run, ["T1", "T2", "T4"], seed=41)).table
    (tmp_path / "t.bin").write_bytes(table)
    p, first = _start(["--config", str(tmp_path / "mb.json"), "--table", str(tmp_path / "t.bin"), "--room-c", "24"])
    try:
        assert first.startswith("board: /dev/pts/") and "modbus" in first, first
        time.sleep(2.0)
        client = ModbusSerialClient(first.split()[1], baudrate=115200, timeout=1.0, retries=1)
        assert client.connect()
        try:
            info = client.read_input_registers(10, count=5, device_id=1)
            temps = client.read_input_registers(16, count=3, device_id=1)
            seq = []
            for _ in range(2):
                rr = client.read_input_registers(2, count=1, device_id=1)
                assert not rr.isError(), rr
                seq.append((time.monotonic(), rr.registers[0]))
                time.sleep(1.0)
        finally:
            client.close()
        assert not info.isError() and not temps.isError(), (info, temps)
        from firmware.table import parse_table
        crc = parse_table(table).crc
        assert info.registers[:4] == [crc >> 16, crc & 0xFFFF, 1, 3], info.registers  # the table in slot A, 3 channels
        assert all(abs(v - 2400) <= 5 for v in temps.registers), temps.registers  # 0.01 deg C: the room's 24
        (t0, s0), (t1, s1) = seq
        rate = ((s1 - s0) % 65536) / (t1 - t0)  # cycles per wall second: 10 at cycle_ms 100 in real time
        assert 7 <= rate <= 13, rate
    finally:
        _stop(p)
    assert p.returncode == 0


def test_monitor_query_logs_the_offsets_at_the_given_positions(tmp_path, demo_run, capsys):
    """tcomp monitor --query: a board whose controller reports no position answers Q at each listed position; the
    CSV log holds those Q frames (what tcomp check aligns with a laser's target positions)."""
    import csv

    from hil_tests.rig import interpreters
    from host.cli import main as tcomp
    interpreters.get().require()
    (tmp_path / "t.bin").write_bytes(export(poly_slope_for_run(demo_run, ["T1", "T2", "T4"], seed=43)).table)
    link = str(tmp_path / "ttyQ")
    assert tcomp(["monitor", "--port", link, "--query", "0,abc"]) == 2
    assert "--query 0,abc: 'abc' is not a position in mm" in capsys.readouterr().err
    p, first = _start(["--port", link, "--run", os.path.join(ROOT, "data", "demo", "mixed"), "--table",
                       str(tmp_path / "t.bin"), "--speed", "20"])
    try:
        assert first.startswith("board: "), first
        rc = tcomp(["monitor", "--port", link, "--csv", str(tmp_path / "log.csv"), "--query", "0,350.5,700",
                    "--query-every", "0.5", "--duration", "2.5"])
        assert rc == 0
    finally:
        _stop(p)
    with open(tmp_path / "log.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["kind"] == "Q"]
    assert len(rows) >= 9, rows  # 3 positions, every 0.5 s for 2.5 s
    assert {r["pos_um"] for r in rows} == {"0", "350500", "700000"}
    by_time = {}
    for r in rows:
        by_time.setdefault(r["t_ms"], {})[r["pos_um"]] = float(r["total_um"])
    # the table's offset depends on the position: the answers are the board's, at the position asked
    assert any(len(set(v.values())) > 1 for v in by_time.values()), by_time
