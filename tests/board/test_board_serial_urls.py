"""Serial ports are opened with pySerial's serial_for_url: its URL handlers are the test doubles
(socket://, loop://) for `tcomp monitor`, the Linux board adapter and the real-port rig backend."""
import json
import socket
import threading
import time

import pytest

from firmware.linux_adapters import make_linux_board
from host.board.link import command_line
from hil_tests.rig.realport import RealDut
from host.cli import main

FRAMES = [command_line(7, "00000000", "O", 1000, 25000, "1.50", "1.20", "3.00"),
          command_line(8, "00080000", "W", "sensor")]


def test_monitor_reads_a_socket_url(tmp_path):
    out = tmp_path / "m.json"
    port = _serve(b"".join(FRAMES) + b"$TC,garbage*0000\r\n")
    assert main(["monitor", "--port", port, "--count", "2", "--duration", "5", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [r["seq"] for r in doc["rows"]] == [7, 8]
    assert doc["rows"][0]["total_um"] == "1.50" and doc["rows"][1]["flags"] == "HELD"


def test_monitor_on_a_loop_url_hears_its_own_hello_request(tmp_path):
    # loop:// echoes what is written: the V request comes back and is counted as malformed (not a board frame)
    out = tmp_path / "m.json"
    assert main(["monitor", "--port", "loop://", "--hello", "--duration", "0.3", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["frames"] == 0 and doc["malformed"] == 1 and "bad header" in doc["bad"][0]


def test_monitor_refuses_an_unknown_url_scheme(capsys):
    assert main(["monitor", "--port", "nosuch://x", "--count", "1"]) == 2
    assert "cannot open nosuch://x" in capsys.readouterr().err


def test_linux_board_serial_on_a_loop_url():
    board = make_linux_board({"channels": []}, "loop://")
    buf = bytearray(FRAMES[0])
    assert board.serial.write(buf, len(buf)) == len(buf)
    rx = bytearray(64)
    n = board.serial.readinto(rx)
    assert bytes(rx[:n]) == FRAMES[0][:n] and n == min(64, len(FRAMES[0]))


def test_real_port_backend_decodes_from_a_loop_url():
    dut = RealDut("loop://")
    try:
        dut.write(b"".join(FRAMES))
        deadline = time.monotonic() + 5
        while len(dut.frames) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [(f.seq, f.kind) for f in dut.take_frames()] == [(7, "O"), (8, "W")]
    finally:
        dut.close()


def _serve(payload):
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)

    def board():
        conn, _ = server.accept()
        time.sleep(0.3)  # pySerial's socket:// discards what arrives while it opens (reset_input_buffer)
        conn.sendall(payload)
        time.sleep(0.5)
        conn.close()
        server.close()

    threading.Thread(target=board, daemon=True).start()
    return "socket://127.0.0.1:%d" % server.getsockname()[1]


def test_monitor_refuses_a_hello_with_an_unknown_protocol_version(capsys):
    from firmware.wire import PROTOCOL_VERSION
    hello = command_line(0, "00000000", "H", PROTOCOL_VERSION + 1, "9.9.9", "-", "-", "-", "-", "-", 3, "-")
    assert main(["monitor", "--port", _serve(hello), "--count", "1", "--duration", "5"]) == 2
    err = capsys.readouterr().err
    assert "protocol version %d" % (PROTOCOL_VERSION + 1) in err and "speaks %d" % PROTOCOL_VERSION in err


def test_monitor_accepts_a_hello_with_its_protocol_version(tmp_path):
    from firmware.wire import FIRMWARE_VERSION, PROTOCOL_VERSION
    hello = command_line(0, "00200000", "H", PROTOCOL_VERSION, FIRMWARE_VERSION, "-", "-", "-", "-", "-", 3, "-")
    out = tmp_path / "m.json"
    assert main(["monitor", "--port", _serve(hello), "--count", "1", "--duration", "5", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["rows"][0]["flags"] == "NO_TABLE"


@pytest.mark.parametrize("counter", ["1000000063", "12x", "-5"])
def test_monitor_latch_refuses_a_bad_hello_counter_in_one_line(tmp_path, capsys, counter):
    """Issue 24 hole 5: a hello counter above MAX (after a power cut at counter 999,999,999 on an older
    firmware) or not a number: one clear error naming the counter, no traceback."""
    from firmware.wire import FIRMWARE_VERSION, PROTOCOL_VERSION
    from host.board.linkauth import write_key
    write_key(str(tmp_path / "k"), bytes(range(32)))
    hello = command_line(0, "00200000", "H", PROTOCOL_VERSION, FIRMWARE_VERSION, "-", "-", "-", "-", "-", 3, "-",
                    counter, "0A0B0C0D")
    assert main(["monitor", "--port", _serve(hello), "--latch", "--key", str(tmp_path / "k"),
                 "--duration", "5"]) == 2
    err = capsys.readouterr().err
    assert "counter" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
