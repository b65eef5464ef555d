"""$TC frames: CRC, formatting/parsing round trips, commands, rejection of bad input."""
import zlib

import pytest
from hypothesis import given, settings, strategies as st, HealthCheck

import hashlib

from fwhelpers import TEST_NONCE, tagged_chunk, cmd, frames, rig_app, run_cycles, make_table, scmd
from fwfakes import FakeSerial
from firmware import frame as fr
from firmware.crc16 import crc16_ccitt, crc16_modbus
from firmware.wire import NO_TABLE


def test_crc16_check_values():
    # CRC-16/CCITT-FALSE and CRC-16/MODBUS catalogue check values
    assert crc16_ccitt(b"123456789") == 0x29B1
    assert crc16_modbus(b"123456789") == 0x4B37
    assert crc16_ccitt(b"xx123456789", 2) == 0x29B1
    assert crc16_ccitt(b"") == 0xFFFF


@given(st.binary(max_size=64))
def test_crc16_incremental(data):
    k = len(data) // 2
    assert crc16_ccitt(data, k, -1, crc16_ccitt(data, 0, k)) == crc16_ccitt(data)


def parse_one(line):
    r = fr.LineReader()
    done = [r.feed(c) for c in line]
    assert done[-1] and sum(done) == 1
    return r


@settings(max_examples=300)
@given(st.integers(-10 ** 9, 10 ** 9), st.integers(0, 5), st.integers(0, 0xFFFFFFFF))
def test_writer_reader_round_trip(v, dec, status):
    s = FakeSerial()
    w = fr.FrameWriter(s)
    w.seq = 65535
    w.begin(status, ord("O"))
    w.int(v)
    w.fixed(v, dec)
    w.hex(status, 8)
    w.end()
    line = s.take()
    assert w.seq == 0  # wraps
    f = frames(line)[0]
    assert f[:4] == ["TC", "65535", "%08X" % status, "O"]
    assert int(f[4]) == v
    whole, _, frac = f[5].partition(".")
    assert len(frac) == dec
    assert int(f[5].replace(".", "")) == v
    assert int(f[6], 16) == status
    # a device frame is also syntactically a valid line for the reader
    r = parse_one(line)
    assert r.status == fr._LINE_OK
    assert r.int(3, -10 ** 9, 10 ** 9) == v  # reader fields start after "TC"


def test_fixed_formats_small_and_negative():
    s = FakeSerial()
    w = fr.FrameWriter(s)
    w.begin(0, ord("O"))
    for v, d in [(5, 1), (-5, 1), (0, 2), (-123, 3), (7, 0)]:
        w.fixed(v, d)
    w.end()
    assert frames(s.take())[0][4:] == ["0.5", "-0.5", "0.00", "-0.123", "7"]


def test_reader_rejects_bad_lines():
    good = cmd(b"TC,P,100")
    assert parse_one(good).status == fr._LINE_OK
    bad_crc = good.replace(b"100", b"101")
    assert parse_one(bad_crc).status == fr._LINE_CRC
    assert parse_one(b"$TC,P,100\r\n").status == fr._LINE_SYNTAX
    assert parse_one(b"$XX,P,100*0000\r\n").status == fr._LINE_SYNTAX
    assert parse_one(b"garbage\n").status == fr._LINE_SYNTAX
    assert parse_one(b"$TC," + b"9" * 300 + b"*0000\n").status == fr._LINE_OVERFLOW
    # a new '$' cuts a line short: the stub is reported, the next line still parses
    r = fr.LineReader()
    ends = [(r.feed(c), r.status) for c in b"$TC,P,1" + good]
    assert ends[7] == (True, fr._LINE_SYNTAX)
    assert ends[-1] == (True, fr._LINE_OK)


def app_out(app, board, data):
    board.serial.take()
    board.serial.feed(data)
    app.link.poll(board.clock.t)
    return frames(board.serial.take())


def state(app):
    t = app.table
    return (app.pos, app.have_pos, app.ev.pos_ref if app.ev else None, app.enabled, app.slot,
            t.crc if t else None, app.store.uploading)


def test_hello_at_boot(tmp_path):
    app, board = rig_app(tmp_path)
    f = frames(board.serial.take())
    h = f[0]
    assert h[3] == "H" and h[4] == "2" and h[5] == "0.1.0" and h[6] == "A"
    assert int(h[7], 16) == app.table.crc
    assert h[8] == app.table.provenance[:8].hex().upper()
    # "-": fixed reference temperatures; "0": the last authorisation counter (a key is provisioned);
    # then the session nonce the fakes' board drew at boot, then the error reference (issue 19)
    assert h[9:] == ["poly_slope", "X", "11", "-", "0", TEST_NONCE.hex().upper(), "start"]


def test_no_table_hello_and_reason(tmp_path):
    (tmp_path / "table_a.bin").write_bytes(b"TCTB" + b"\0" * 80)
    app, board = rig_app(tmp_path, table=False)
    f = frames(board.serial.take())
    assert f[0][6:11] == ["-"] * 5
    assert f[1][3] == "E" and f[1][5] == "table" and f[1][6].startswith("A ")
    run_cycles(app, board, 3)
    assert app.status & NO_TABLE and app.total == 0  # zero output


def test_periodic_offset_frames_and_sequence(tmp_path):
    app, board = rig_app(tmp_path)
    board.serial.take()
    run_cycles(app, board, 20)
    f = frames(board.serial.take())
    assert [x[3] for x in f] == ["O"] * 20
    seqs = [int(x[1]) for x in f]
    assert seqs == list(range(seqs[0], seqs[0] + 20))
    last = f[-1]
    assert int(last[4]) == app.last_t
    assert float(last[6]) == round(app.total / 10) / 10


def test_position_query_reference_temperatures(tmp_path):
    app, board = rig_app(tmp_path)
    run_cycles(app, board, 80)
    assert app_out(app, board, cmd(b"TC,P,250000")) == []
    assert app.pos == 250000 and app.have_pos
    run_cycles(app, board, 1)
    q = app_out(app, board, cmd(b"TC,Q,400000"))[0]
    assert q[3] == "Q" and q[5] == "400000"
    assert round(float(q[6]) * 100) == pytest.approx(app.total_at(400000), abs=5)
    a = app_out(app, board, cmd(b"TC,R,100000"))[0]
    assert a[3:] == ["A", "R", "100000"] and app.ev.pos_ref == 100000
    t = app_out(app, board, cmd(b"TC,S"))[0]
    assert t[3] == "T" and len(t) == 5 + 11
    for i, v in enumerate(t[5:]):
        assert abs(float(v) - (20.0 + i)) < 0.05
    v = app_out(app, board, cmd(b"TC,V"))[0]
    assert v[3] == "H"


BAD = [
    b"$TC,P,100*0000\r\n",  # wrong CRC
    b"$TC,P,100\r\n",  # no CRC
    b"TC,P,100*1234\r\n",  # no $
    cmd(b"TC,Z"),  # unknown command
    cmd(b"TC,PP,100"),  # unknown (two letters)
    cmd(b"TC,P"),  # missing field
    cmd(b"TC,P,1,2,3"),  # extra field (P,<pos>,<rpm> is the longest P)
    cmd(b"TC,P,abc"),  # not a number
    cmd(b"TC,P,--5"),
    cmd(b"TC,P,99999999999"),  # out of range
    cmd(b"TC,Q,"),
    cmd(b"TC,R,1e5"),
    cmd(b"TC,M,100,0"),
    cmd(b"TC,M,-1,0,1000"),
    cmd(b"TC,S,1"),
    cmd(b"TC,V,x"),
    cmd(b"TC,X,now"),
    cmd(b"TC,U"),
    cmd(b"TC,U,Q"),
    cmd(b"TC,U,B,100"),
    cmd(b"TC,U,B,100,XYZ"),
    cmd(b"TC,U,B,10,00000000"),  # too small for a table
    cmd(b"TC,U,D,0,00"),  # no upload open
    cmd(b"TC,U,C"),  # no upload open
    cmd(b"TC,U,D,0,0G"),
    b"$" + b"A" * 400 + b"\r\n",  # overflow
    cmd(b"tc,P,100"),
]


@pytest.mark.parametrize("line", BAD)
def test_bad_commands_answered_with_error_and_change_nothing(tmp_path, line):
    app, board = rig_app(tmp_path)
    run_cycles(app, board, 3)
    before = state(app)
    out = app_out(app, board, line)
    assert len(out) == 1 and out[0][3] == "E", out
    assert state(app) == before


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.one_of(st.binary(max_size=40),
                          st.sampled_from([cmd(b"TC,P,1000"), cmd(b"TC,S"), b"\r\n", b"$", b"*"])),
                max_size=12))
def test_fuzz_never_crashes_and_only_valid_commands_act(tmp_path_factory, chunks):
    app, board = rig_app(tmp_path_factory.mktemp("fz"))
    run_cycles(app, board, 2)
    for c in chunks:
        board.serial.feed(c)
        app.link.poll(board.clock.t)
    board.serial.feed(b"\r\n")
    app.link.poll(board.clock.t)
    run_cycles(app, board, 1)
    frames(board.serial.take())  # every emitted frame is well formed
    if app.have_pos:
        assert app.pos == 1000  # the only position any valid command carried


def upload(app, board, data, chunk=48, cut=None):
    out = app_out(app, board, scmd(app, "U", "B", len(data), "%08X" % zlib.crc32(data)))
    assert out[-1][3:5] == ["A", "U"], out
    for off in range(0, len(data), chunk):
        if cut is not None and off >= cut:
            return None
        out = app_out(app, board, tagged_chunk(app, off, data[off:off + chunk]))
        assert out[-1][3:6] == ["A", "U", "D"], out
        assert int(out[-1][6]) == min(off + chunk, len(data))
    return app_out(app, board, scmd(app, "U", "C", extra=hashlib.sha256(data).digest()))


def test_table_upload_switches_slot(tmp_path):
    app, board = rig_app(tmp_path)
    names = ["T%d" % i for i in range(1, 12)]
    new = make_table(kind="linear_direct", sensors=names, S0=1234)
    out = upload(app, board, new)
    assert out[0][3:7] == ["A", "U", "C", "B"]
    assert out[1][3] == "H" and out[1][6] == "B"
    assert app.table.kind == "linear_direct" and app.slot == 1
    assert (tmp_path / "active").read_bytes() == b"B"
    # a fresh boot runs the new table
    from firmware.app import App
    board.serial.take()
    app2 = App(board)
    assert app2.slot == 1 and app2.table.crc == app.table.crc


def test_cut_off_upload_leaves_old_table(tmp_path):
    app, board = rig_app(tmp_path)
    old = app.table.crc
    names = ["T%d" % i for i in range(1, 12)]
    new = make_table(kind="linear_direct", sensors=names)
    upload(app, board, new, cut=96)
    from firmware.app import App
    app2 = App(board)  # power cut: restart with the partial slot B on flash
    assert app2.slot == 0 and app2.table.crc == old


def test_corrupt_upload_refused_with_reason(tmp_path):
    app, board = rig_app(tmp_path)
    old = app.table.crc
    names = ["T%d" % i for i in range(1, 12)]
    bad = bytearray(make_table(kind="linear_direct", sensors=names))
    bad[70] ^= 1  # table CRC-32 no longer matches (the upload CRC is of these bytes)
    out = upload(app, board, bytes(bad))
    assert out[0][3] == "E" and out[0][5] == "table" and "CRC" in out[0][6]
    assert app.table.crc == old and app.slot == 0
    # a table for sensors this board does not have
    other = make_table(kind="linear_direct", sensors=["Q1", "Q2"])
    out = upload(app, board, other)
    assert out[0][3] == "E" and "sensor" in out[0][6]
    assert app.table.crc == old


def test_upload_chunk_out_of_order_rejected(tmp_path):
    app, board = rig_app(tmp_path)
    data = make_table(kind="linear_direct", sensors=["T1"])
    app_out(app, board, scmd(app, "U", "B", len(data), "%08X" % zlib.crc32(data)))
    out = app_out(app, board, tagged_chunk(app, 10, data[10:20]))
    assert out[0][3] == "E" and out[0][5] == "state"
    out = app_out(app, board, scmd(app, "U", "X"))
    assert out[0][3:6] == ["A", "U", "X"] and not app.store.uploading


def test_reset_command_restarts(tmp_path):
    from firmware.app import Restart
    app, board = rig_app(tmp_path)
    board.serial.feed(scmd(app, "X"))
    with pytest.raises(Restart):
        app.link.poll(board.clock.t)
    assert frames(board.serial.take())[-1][3:5] == ["A", "X"]
