"""host/board/client.py: the board's clock across its 2^30 ms wrap, and request/answer, hello and its protocol check
against a fake board on a socket:// URL that answers commands as docs/protocol.md says (written here, not the
firmware's code)."""
import socket
import threading
import time

import pytest

from host.board.client import WRAP_MS, BoardClock, BoardLink, ClockError, LinkError
from host.board.link import command_line


def test_wrap_is_exactly_two_to_the_thirty():
    assert WRAP_MS == 1073741824  # MicroPython's ticks_ms period (docs/protocol.md, Units)


def test_board_clock_counts_on_across_the_wrap():
    clock = BoardClock()
    raw = [WRAP_MS - 1500, WRAP_MS - 500, WRAP_MS - 1, 0, 499, 100000]
    assert [clock.extend(t) for t in raw] == [0, 1000, 1499, 1500, 1999, 101500]
    assert clock.wraps == 1
    clock.extend(500000000)  # a second wrap, 12.4 days later, in steps of less than half the wrap
    clock.extend(1000000000)
    clock.extend(WRAP_MS - 1)
    assert clock.extend(10) == WRAP_MS + 1500 + 10 and clock.wraps == 2


def test_board_clock_refuses_a_clock_that_went_back():
    clock = BoardClock()
    clock.extend(5000000)
    with pytest.raises(ClockError, match="went back from t_ms 5000000 to 100: the board restarted"):
        clock.extend(100)
    with pytest.raises(ClockError, match="outside the board's clock range"):
        clock.extend(WRAP_MS)
    assert clock.extend("5000100") == 100  # a frame's field is text


def _hello(protocol):
    return command_line(0, "00800000", "H", protocol, "0.1.0", "A", "0ABCAE5F", "0001020304050607", "poly_slope", "X",
                        3, "S", 41, "0A0B0C0D", "start")


def _board(answers):
    """A fake board on a socket: each received command line gets the answer ``answers[letter]`` (bytes)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)

    def run():
        conn, _ = server.accept()
        buf = b""
        conn.settimeout(5)
        try:
            while True:
                data = conn.recv(1024)
                if not data:
                    break
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    answer = answers.get(line[4:5].decode())
                    if answer:
                        conn.sendall(answer)
        except OSError:
            pass
        finally:
            conn.close()
            server.close()

    threading.Thread(target=run, daemon=True).start()
    time.sleep(0.05)
    return "socket://127.0.0.1:%d" % server.getsockname()[1]


def test_request_returns_the_answer_and_read_hello_names_the_fields():
    t = command_line(5, "00000000", "T", WRAP_MS - 3, "20.125", "!40", "21.000")
    port = _board({"V": _hello(2), "S": command_line(4, "00000000", "O", 1, 0, "0.0", "0.0", "0.00") + t})
    link = BoardLink.open(port)
    try:
        time.sleep(0.35)  # pySerial's socket:// drops what arrives while it opens
        hello = link.read_hello(timeout=3)
        assert (hello.firmware, hello.channels, hello.axis, hello.error_reference) == ("0.1.0", 3, "X", "start")
        assert "nonce" not in hello.as_dict() and hello.as_dict()["kind"] == "poly_slope"
        f = link.request("S", kinds="T", timeout=3)  # the O frame before it is not the answer
        assert f.kind == "T" and f.fields == [str(WRAP_MS - 3), "20.125", "!40", "21.000"]
    finally:
        link.close()


def test_read_hello_refuses_another_protocol_and_a_silent_board_is_named():
    port = _board({"V": _hello(1)})
    link = BoardLink.open(port)
    try:
        time.sleep(0.35)
        with pytest.raises(LinkError, match="hello frame says protocol version 1; this tcomp speaks 2"):
            link.read_hello(timeout=3)
        with pytest.raises(LinkError, match=r"socket://127.0.0.1:\d+: no reply to S within 0.3 s"):
            link.request("S", kinds="T", timeout=0.3)
    finally:
        link.close()


def test_open_names_the_port_it_cannot_open():
    with pytest.raises(LinkError, match="cannot open nosuch://x"):
        BoardLink.open("nosuch://x")
