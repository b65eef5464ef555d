"""`tcomp upload` against a running `tcomp board` (the firmware under the 32-bit MicroPython port, on a pty, in its
own process): the new table is in force by the board's own hello, read here on a link of the test's; each refusal
is one line naming its cause and leaves the old table in force; an upload interrupted on the controller's side
(Ctrl-C, a lost link) leaves the old table in force."""
import os
import signal
import subprocess
import sys
import time

import pytest

from hil_tests.rig.boards import export, poly_slope_for_run

pytestmark = [pytest.mark.rig, pytest.mark.micropython]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SENSORS = ["T1", "T2", "T4"]


@pytest.fixture
def tables(tmp_path, demo_run):
    """Two tables of the same sensors (the board's and a new one) and their CRCs as the hello prints them."""
    out = []
    for seed in (51, 52):
        table = export(poly_slope_for_run(demo_run, SENSORS, seed=seed)).table
        path = tmp_path / ("t%d.bin" % seed)
        path.write_bytes(table)
        from firmware.table import parse_table
        out.append((str(path), "%08X" % parse_table(table).crc))
    assert out[0][1] != out[1][1]
    return out


@pytest.fixture
def board(tmp_path, tables):
    """A `tcomp board` holding the first table, with a key; (link path, key path)."""
    from hil_tests.rig import interpreters
    interpreters.get().require()
    link, key = str(tmp_path / "ttyB"), str(tmp_path / "board.key")
    p = subprocess.Popen([sys.executable, "-m", "host", "board", "--room-c", "22", "--table", tables[0][0], "--key", key,
                          "--port", link, "--speed", "10"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True)
    first = p.stdout.readline()
    try:
        assert first.startswith("board: "), first + (p.stderr.read() if p.poll() is not None else "")
        yield link, key
    finally:
        p.send_signal(signal.SIGINT)
        try:
            p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.communicate()


def _hello(link):
    """The board's hello read on a link of the test's own (not the verb's word for it)."""
    from host.board.client import BoardLink
    bl = BoardLink.open(link)
    try:
        return bl.read_hello(timeout=10)
    finally:
        bl.close()


def _upload(capsys, *argv):
    from host.cli import main as tcomp
    capsys.readouterr()
    rc = tcomp(["upload"] + list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_upload_puts_the_new_table_in_force(board, tables, tmp_path, capsys):
    link, key = board
    assert _hello(link).table_crc == tables[0][1]
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key,
                           "--json", str(tmp_path / "u.json"))
    assert rc == 0, err
    assert "table %s in force in slot B (was table %s in slot A)" % (tables[1][1], tables[0][1]) in out, out
    h = _hello(link)
    assert (h.table_crc, h.slot) == (tables[1][1], "B")
    import json
    got = json.loads((tmp_path / "u.json").read_text())
    assert got["before"]["table_crc"] == tables[0][1] and got["after"]["table_crc"] == tables[1][1] and got["uploaded"]
    # the same table again: nothing sent (no flash write spent)
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key)
    assert rc == 0 and "already runs table %s" % tables[1][1] in out, out + err
    # and back to the first, into slot A
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[0][0], "--key", key)
    assert rc == 0, err
    assert (_hello(link).table_crc, _hello(link).slot) == (tables[0][1], "A")


def test_refusals_name_their_cause_and_keep_the_old_table(board, tables, tmp_path, capsys, monkeypatch):
    link, key = board
    other = tmp_path / "other.key"
    other.write_text(os.urandom(32).hex() + "\n")
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", str(other))
    assert rc == 2
    assert err.count("\n") == 1 and "(E,8,auth,bad tag): %s is not this board's key" % other in err, err
    assert "the board keeps its old table (table %s in slot A)" % tables[0][1] in err, err
    assert _hello(link).table_crc == tables[0][1]

    # another controller used the counters after our hello: the board refuses the replay
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key)  # counters now used
    assert rc == 0, err
    from host.board.linkauth import LinkSigner
    real = LinkSigner.observe_hello
    monkeypatch.setattr(LinkSigner, "observe_hello", lambda self, fields: (real(self, fields),
                                                                           setattr(self, "counter", 0)))
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[0][0], "--key", key)
    assert rc == 2 and "(E,8,auth,replayed counter): another controller signed" in err, err
    monkeypatch.undo()
    assert _hello(link).table_crc == tables[1][1]

    # the flash-write budget (4 writes, one more a minute): uploads back and forth until the board says busy
    msgs = []
    for i in range(8):
        rc, out, err = _upload(capsys, "--port", link, "--table", tables[i % 2][0], "--key", key)
        msgs.append((rc, err))
        if rc:
            break
    assert rc == 2 and "the board is busy (E,9,busy): its flash-write budget is used up" in err, msgs
    in_force = _hello(link).table_crc
    assert in_force == tables[(i + 1) % 2][1]  # the table of the last upload that went through


def test_an_interrupted_upload_leaves_the_old_table_in_force(board, tables, capsys, monkeypatch):
    """Ctrl-C mid-upload: the verb closes the upload (U,X), the old table stays, the next upload goes through at once.
    A lost link mid-upload: the old table stays; the board holds the upload open until it times out, and says so."""
    link, key = board
    from host.board.client import BoardLink
    real_write = BoardLink.write

    def cut_after(n, exc):
        count = {"lines": 0}

        def write(self, data, flush=True):
            if data.startswith(b"$TC,U,D"):
                count["lines"] += 1
                if count["lines"] > n:
                    raise exc
            return real_write(self, data, flush)
        return write

    monkeypatch.setattr(BoardLink, "write", cut_after(2, KeyboardInterrupt()))
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key)
    monkeypatch.undo()
    assert rc == 2 and "interrupted: the upload is incomplete, so the board keeps its old table (table %s in slot A)" \
        % tables[0][1] in err, err
    assert _hello(link).table_crc == tables[0][1]

    import serial
    monkeypatch.setattr(BoardLink, "write", cut_after(2, serial.SerialException("device reports readiness to read "
                                                                                  "but returned no data")))
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key)
    monkeypatch.undo()
    assert rc == 2 and "the link failed mid-upload" in err and "keeps its old table (table %s" % tables[0][1] in err, err
    h = _hello(link)
    assert h.table_crc == tables[0][1]
    rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", key)
    assert rc == 2 and "another upload is open on the board (E,5,state,upload open)" in err, err
    assert _hello(link).table_crc == tables[0][1]


def test_a_board_without_key_is_named_before_anything_is_sent(tmp_path, tables, capsys):
    from hil_tests.rig import interpreters
    interpreters.get().require()
    link = str(tmp_path / "ttyN")
    p = subprocess.Popen([sys.executable, "-m", "host", "board", "--room-c", "22", "--table", tables[0][0],
                          "--port", link], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    try:
        assert p.stdout.readline().startswith("board: ")
        key = tmp_path / "k.key"
        key.write_text(os.urandom(32).hex() + "\n")
        rc, out, err = _upload(capsys, "--port", link, "--table", tables[1][0], "--key", str(key))
        assert rc == 2 and "the board has no key (its hello's counter is '-')" in err, err
        assert out == ""
        t = time.monotonic()
        rc, out, err = _upload(capsys, "--port", str(tmp_path / "nothing"), "--table", tables[1][0], "--key", str(key))
        assert rc == 2 and "cannot open %s" % (tmp_path / "nothing") in err and time.monotonic() - t < 5, err
    finally:
        p.send_signal(signal.SIGINT)
        p.communicate(timeout=30)
