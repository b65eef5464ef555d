"""Who may change the output (firmware/auth.py, docs/protocol.md "Who may change the output"):
the key, the counter across resets, the flash budget, upload ownership and time-out, the
table certificate, and the pure-Python SHA-256 against hashlib on both interpreters."""
import hashlib
import hmac
import os
import struct
import zlib

import pytest
from hypothesis import given, settings, strategies as st

from firmware.wire import UPLOADING
from fwhelpers import HELLO_COUNTER_AT
from fwhelpers import (tagged_chunk, cmd, compile_mpy, frames, make_table, provision, rig_app, run_cycles, run_micropython,
                       scmd, table_fields, TEST_KEY)

NAMES = ["T%d" % i for i in range(1, 12)]


def send(app, board, line):
    board.serial.take()  # whatever the cycles sent before
    board.serial.feed(line)
    app.link.poll(board.clock.t)
    return frames(board.serial.take())


def state(app, tmp_path):
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    return (app.slot, app.table.crc if app.table else None, app.store.uploading, app.auth.last, list(app.ev.ref), files)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 300))
def test_fallback_sha256_is_hashlib(data, cut):
    from firmware.sha256 import sha256
    h = sha256(data[:cut])
    h.update(data[cut:])
    assert h.digest() == hashlib.sha256(data).digest()
    assert h.digest() == hashlib.sha256(data).digest()  # digest twice: the same


SHA_SCRIPT = r"""
from firmware.sha256 import sha256
import hashlib
n = 0
for size in (0, 1, 55, 56, 63, 64, 65, 127, 128, 300, 1000):
    data = bytes((i * 7 + size) & 0xFF for i in range(size))
    for cut in (0, size // 3, size):
        h = sha256(data[:cut])
        h.update(data[cut:])
        assert h.digest() == hashlib.sha256(data).digest(), (size, cut)
        n += 1
print("OK", n)
"""


@pytest.mark.micropython
def test_fallback_sha256_on_micropython(tmp_path):
    mpy = compile_mpy()
    assert run_micropython(SHA_SCRIPT, str(tmp_path), mpy).split() == ["OK", "33"]


def test_tag_is_rfc2104_hmac(tmp_path):
    from firmware.auth import Auth
    from firmware.slots import TableStore
    provision(tmp_path)
    a = Auth(TableStore(str(tmp_path)), lambda: True)
    msg = b"TC,L,17"
    assert a.mac(msg, b"xy") == hmac.new(TEST_KEY, msg + b"xy", hashlib.sha256).digest()[:16]


@pytest.mark.parametrize("line", [b"TC,L", b"TC,X", b"TC,U,X", b"TC,U,C", b"TC,U,B,300,0000ABCD"])
def test_unsigned_commands_are_refused_and_change_nothing(tmp_path, line):
    app, board = rig_app(tmp_path)
    run_cycles(app, board, 5)
    board.serial.take()
    before = state(app, tmp_path)
    out = send(app, board, cmd(line))
    assert len(out) == 1 and out[0][3] == "E" and out[0][4] in ("8", "5"), out
    assert state(app, tmp_path) == before


def test_board_without_key_refuses_even_a_signed_command(tmp_path):
    app, board = rig_app(tmp_path, key=None)
    assert frames(board.serial.take())[0][HELLO_COUNTER_AT] == "-"  # the hello: no key
    out = send(app, board, scmd(app, "U", "X"))
    assert out[0][3:7] == ["E", "8", "auth", "no key"]


def test_counter_survives_a_reset_with_one_write_per_64(tmp_path):
    from firmware.app import App
    app, board = rig_app(tmp_path)
    board.serial.take()
    lines = [scmd(app, "U", "X", counter=c) for c in range(1, 71)]
    writes = []
    replace = app.store.replace_file
    app.store.replace_file = lambda n, d: writes.append(n) or replace(n, d)
    for k in range(70):
        if k == 60:
            board.clock.t += 60000
            app.cycle()  # one more flash token
        assert send(app, board, lines[k])[0][3:6] == ["A", "U", "X"]
    assert writes == ["auth.bin", "auth.bin"] and app.auth.last == 70
    app = App(board)  # reset
    hello = frames(board.serial.take())[0]
    assert hello[HELLO_COUNTER_AT] == "130"  # the stored mark: 64 ahead of counter 66, the first beyond the mark of 65
    assert send(app, board, lines[-1])[0][3:7] == ["E", "8", "auth", "replayed counter"]
    assert send(app, board, scmd(app, "U", "X", counter=130))[0][3:7] == ["E", "8", "auth", "replayed counter"]
    assert send(app, board, scmd(app, "U", "X"))[0][3:6] == ["A", "U", "X"]


def test_L_and_flash_writes_are_rate_limited(tmp_path):
    f = table_fields(kind="linear_direct", sensors=NAMES)
    f["ref_mode"] = 1
    from models_export.tableformat import pack
    (tmp_path / "table_a.bin").write_bytes(pack(f))
    app, board = rig_app(tmp_path, table=False)
    run_cycles(app, board, 5)
    board.serial.take()
    writes = []
    replace = app.store.replace_file
    app.store.replace_file = lambda n, d: writes.append(n) or replace(n, d)
    out = [o for _ in range(300) for o in send(app, board, scmd(app, "L"))]
    assert sum(o[3] == "A" for o in out) == 3  # 4 tokens: the counter mark, then 3 latches
    # the other 297 are refused busy (their E frames as far as the error-frame rate limit lets them out)
    assert all(o[3:5] == ["E", "9"] for o in out if o[3] != "A") and len(out) > 3
    assert writes.count("refs.bin") == 3 and len(writes) == 4
    for _ in range(121):  # two minutes later two more: a new counter mark, and the latch
        app.cycle()
        board.clock.t += 1000
    assert send(app, board, scmd(app, "L"))[0][3:5] == ["A", "L"]


def _upload_head(app, board, data):
    return send(app, board, scmd(app, "U", "B", len(data), "%08X" % zlib.crc32(data)))


def test_second_begin_does_not_restart_an_open_upload_and_idle_upload_times_out(tmp_path):
    app, board = rig_app(tmp_path)
    board.serial.take()
    data = make_table(kind="linear_direct", sensors=NAMES, S0=5)
    assert _upload_head(app, board, data)[0][3:6] == ["A", "U", "B"]
    assert send(app, board, tagged_chunk(app, 0, data[:48]))[0][3:7] == ["A", "U", "D", "48"]
    assert _upload_head(app, board, data)[0][3:7] == ["E", "5", "state", "upload open"]
    assert app.store._up[3] == 48  # the open upload kept its bytes
    run_cycles(app, board, 2)
    assert app.status & UPLOADING
    run_cycles(app, board, 600)  # 60 s without a chunk
    assert not app.store.uploading and not app.status & UPLOADING
    assert _upload_head(app, board, data)[0][3:6] == ["A", "U", "B"]


def test_commit_tag_covers_the_table(tmp_path):
    app, board = rig_app(tmp_path)
    board.serial.take()
    data = make_table(kind="linear_direct", sensors=NAMES, S0=5)
    _upload_head(app, board, data)
    for off in range(0, len(data), 48):
        send(app, board, tagged_chunk(app, off, data[off:off + 48]))
    other = hashlib.sha256(data[:-1] + b"\x00").digest()
    assert send(app, board, scmd(app, "U", "C", extra=other))[0][3:7] == ["E", "8", "auth", "bad tag"]
    assert app.store.uploading and app.slot == 0  # still open, old table in force
    out = send(app, board, scmd(app, "U", "C", extra=hashlib.sha256(data).digest()))
    assert out[0][3:7] == ["A", "U", "C", "B"] and app.slot == 1


def _tampered(table, factor=1000):
    from firmware.table import parse_table
    t = parse_table(table)
    b = bytearray(table)
    off = 64 + 36 * t.n_sensors + 4 * 8  # payload: 8 words, then b[0] shb[0] fb[0] ...
    for i in range(t.n_sensors):
        v = struct.unpack_from("<i", b, off + 12 * i)[0]
        struct.pack_into("<i", b, off + 12 * i, max(-(1 << 31), min((1 << 31) - 1, v * factor)))
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    return bytes(b)


def test_table_certificate_is_checked_and_bounds_the_output(tmp_path):
    import random
    from firmware.app import App
    from firmware.table import parse_table, TableError
    from models_export.export import export_model
    from hil_tests.fixtures.samples import poly_slope_doc
    doc = poly_slope_doc(random.Random(3), n_sensors=2)
    good = export_model(doc).table
    t = parse_table(good)
    assert 0 < t.cert_out < 1 << 30 and 0 < t.cert_ref and 0 < t.cert_slope
    # certificate missing (a table of the format without it): refused
    short = bytearray(good[:-16])  # the three certificate words and the CRC dropped
    struct.pack_into("<I", short, 8, len(short) + 4)
    struct.pack_into("<I", short, 52, struct.unpack_from("<I", short, 52)[0] - 3)
    with pytest.raises(TableError) as e:
        parse_table(bytes(short) + struct.pack("<I", zlib.crc32(bytes(short))))
    assert e.value.reason == "certificate" and "missing" in str(e.value)
    bad = _tampered(good)
    parse_table(bad)  # the CRC is valid ...
    sensors = list(t.sensors)
    (tmp_path / "table_a.bin").write_bytes(bad)
    from firmware.slots import TableStore
    # the App's own check (App._accept), on a board wired for this table's sensors
    store = TableStore(str(tmp_path), lambda tb: App._accept(_WithNames(sensors), tb))
    tb, slot = store.load()
    assert tb is None and "certificate" in store.refusals[0][1]  # ... but the certificate does not hold
    (tmp_path / "table_a.bin").write_bytes(good)
    tb, slot = TableStore(str(tmp_path), lambda tb: App._accept(_WithNames(sensors), tb)).load()
    assert tb is not None
    # the limiter never goes beyond the certified bound, whatever the config allows
    from firmware.safety import Limiter
    lim = Limiter(10000, 100000, 1000)
    lim.configure(10000, 100000, t.pos_hi - t.pos_lo, t)
    assert lim.max == t.cert_out and lim.max_ref == t.cert_ref and lim.max_s <= t.cert_slope
    for _ in range(100):
        lim.update(10 * t.cert_ref, 10 * t.cert_slope, 10 * t.cert_out, 10 * t.cert_out, True, 1000)
    assert lim.total == t.cert_out and lim.ref == t.cert_ref and abs(lim.slope) <= t.cert_slope


class _WithNames:
    def __init__(self, names):
        class Ch:
            pass
        self.channels = Ch()
        self.channels.names = names


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 31 - 1))
def test_exported_outputs_stay_inside_the_certificate(seed):
    import random
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    from models_export.export import export_model
    from hil_tests.fixtures.samples import linear_direct_doc, poly_slope_doc
    rng = random.Random(seed)
    t = parse_table(export_model((poly_slope_doc if seed & 1 else linear_direct_doc)(rng)).table)
    ev = Evaluator(t)
    for _ in range(20):
        for i in range(t.n_sensors):
            ev.temps[i] = rng.choice([t.env_lo[i], t.env_hi[i], rng.randint(t.env_lo[i], t.env_hi[i])])
        ev.update()
        p = rng.choice([t.pos_lo, t.pos_hi, rng.randint(t.pos_lo, t.pos_hi)])
        ev.set_reference(rng.randint(t.pos_lo, t.pos_hi))
        assert abs(ev.offset_at(p)) <= t.cert_out
        assert abs(ev.ref_offset()) <= t.cert_ref and abs(ev.slope()) <= t.cert_slope


def test_the_key_never_goes_out_on_the_link(tmp_path):
    app, board = rig_app(tmp_path)
    out = board.serial.take()
    assert TEST_KEY.hex().upper().encode() not in out and TEST_KEY not in out
    assert os.path.exists(tmp_path / "key.bin")
