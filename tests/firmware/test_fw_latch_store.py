"""Latched reference temperatures survive a warm restart (refs.bin in the table directory);
the controller re-latches at a cold start with `L` (stream) or holding register 7 (Modbus).

A run-start table (ref_mode 1) latched at 23.5 degC must keep 23.5 after a
watchdog reset with the machine at 25 degC: latching again would under-compensate
the ambient term for the rest of the shift.
"""
import os
import struct
import zlib

import pytest

import hashlib

from fwhelpers import HELLO_REFS_AT
from fwhelpers import (tagged_chunk, cmd, compile_mpy, frames, modbus_auth_block, provision, run_cycles, run_micropython, scmd,
                       table_fields)
from firmware.wire import REF_PENDING

NAMES = ("T1", "T2")


def _table(ref_mode=1, S0=0):
    from models_export.tableformat import pack
    f = table_fields(kind="linear_direct", sensors=NAMES, b=[40, 10], S0=S0)
    f["ref_mode"] = ref_mode
    return pack(f)


def _board(tmp_path, temps, mode="stream"):
    from fwfakes import make_rig
    return make_rig(2, 0, temps=list(temps), table_dir=str(tmp_path), serial_mode=mode,
                    extra={"frame_ms": 0}, serial_size=1 << 16)


def _boot(tmp_path, temps, table=None, mode="stream"):
    """A fresh App (a restart) on a board whose chips read ``temps``; returns (app, board, hello)."""
    from firmware.app import App
    if table is not None:
        (tmp_path / "table_a.bin").write_bytes(table)
    provision(tmp_path)
    board = _board(tmp_path, temps, mode)
    app = App(board)
    out = board.serial.take()
    hello = frames(out)[0] if mode == "stream" else None
    return app, board, hello


def _send(app, board, line):
    board.serial.feed(line)
    app.link.poll(board.clock.t)
    return frames(board.serial.take())


def _stored(tmp_path):
    """(table CRC-32, refs) decoded from refs.bin, checking its layout and CRC-16 independently."""
    from firmware.crc16 import crc16_ccitt
    b = (tmp_path / "refs.bin").read_bytes()
    assert b[:3] == b"TR\x01"
    crc, n = struct.unpack_from("<IB", b, 3)
    assert len(b) == 10 + 4 * n
    assert struct.unpack_from("<H", b, len(b) - 2)[0] == crc16_ccitt(b[:-2])
    return crc, list(struct.unpack_from("<%di" % n, b, 8))


def _near(v, deg_c):
    return abs(v - round(deg_c * 1000)) < 50  # within the RTD conversion of the fakes


def test_warm_restart_keeps_the_stored_references(tmp_path):
    app, board, hello = _boot(tmp_path, (23.5, 21.0), _table())
    assert hello[HELLO_REFS_AT] == "N"  # nothing stored yet: latch pending
    assert int(hello[2], 16) & REF_PENDING  # in the boot status
    saves = []
    save = app.store.save_refs
    app.store.save_refs = lambda t, r: saves.append(list(r)) or save(t, r)
    run_cycles(app, board, 50)
    latched = list(app.ev.ref)
    assert _near(latched[0], 23.5) and _near(latched[1], 21.0)
    assert len(saves) == 1, "written once when latching, never in the steady state"
    assert not app.status & REF_PENDING and app.ref_state == 2
    assert _stored(tmp_path) == (app.table.crc, latched)
    hello = _send(app, board, cmd(b"TC,V"))[0]
    assert hello[HELLO_REFS_AT] == "L"
    # watchdog reset mid-shift: the machine has warmed by 1.5 K
    app, board, hello = _boot(tmp_path, (25.0, 22.5))
    assert hello[HELLO_REFS_AT] == "S" and not int(hello[2], 16) & REF_PENDING
    assert app.ev.ref == latched
    app.store.save_refs = lambda t, r: pytest.fail("stored references are not written again")
    run_cycles(app, board, 20)
    assert app.ev.ref == latched and _near(app.ev.temps[0], 25.0)
    assert not app.status & REF_PENDING
    # the output is the model's for the 1.5 K rise since the cold start, not the
    # warm-latched model's (which would start from zero again)
    from firmware.evaluate import Evaluator
    want = Evaluator(app.table)
    want.ref[:] = latched
    want.temps[:] = app.ev.temps
    want.update()
    warm = Evaluator(app.table)
    warm.temps[:] = app.ev.temps
    warm.latch_references()
    assert app.ev.ref_offset() == want.ref_offset() != warm.ref_offset()


@pytest.mark.parametrize("content, letter", [
    (None, "N"),
    (b"", "C"),
    (b"TR\x01garbage", "C"),
    (b"\xff" * 5000, "C"),
    ("flip", "C"),  # one bit flipped in a valid file
    ("count", "C"),  # valid CRC, but for a table with another sensor count
    ("range", "C"),  # valid CRC, a reference outside the table's envelope
    ("foreign", "O"),  # valid file of another table
])
def test_missing_corrupt_or_foreign_file_latches_anew(tmp_path, content, letter):
    from firmware.slots import TableStore
    from firmware.table import parse_table
    table = _table()
    t = parse_table(table)
    store = TableStore(str(tmp_path))
    if content == "flip":
        store.save_refs(t, [23000, 21000])
        b = bytearray((tmp_path / "refs.bin").read_bytes())
        b[9] ^= 0x04
        (tmp_path / "refs.bin").write_bytes(bytes(b))
    elif content == "count":
        t3 = parse_table(_table_n(3))
        store.save_refs(t3, [23000, 21000, 22000])
        b = bytearray((tmp_path / "refs.bin").read_bytes())
        b[3:7] = struct.pack("<I", t.crc)  # even tied to this table's CRC
        _recrc(tmp_path, b)
    elif content == "range":
        store.save_refs(t, [23000, 90000])  # env_hi is 80 degC
    elif content == "foreign":
        store.save_refs(parse_table(_table(S0=77)), [23000, 21000])
    elif content is not None:
        (tmp_path / "refs.bin").write_bytes(content)
    app, board, hello = _boot(tmp_path, (24.0, 21.0), table)
    assert hello[HELLO_REFS_AT] == letter and app.unlatched
    assert app.ev.ref == [20000, 20000]  # the table's own until the latch
    run_cycles(app, board, 5)
    assert _near(app.ev.ref[0], 24.0) and app.ref_state == 2
    assert _stored(tmp_path) == (app.table.crc, app.ev.ref)


def _table_n(n):
    from models_export.tableformat import pack
    f = table_fields(kind="linear_direct", sensors=["T%d" % (i + 1) for i in range(n)])
    f["ref_mode"] = 1
    return pack(f)


def _recrc(tmp_path, b):
    from firmware.crc16 import crc16_ccitt
    c = crc16_ccitt(bytes(b[:-2]))
    b[-2:] = struct.pack("<H", c)
    (tmp_path / "refs.bin").write_bytes(bytes(b))


def test_refs_new_left_by_a_cut_between_remove_and_rename_is_used(tmp_path):
    """On FAT the rename fallback removes refs.bin first: refs.bin.new is read meanwhile."""
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    latched = list(app.ev.ref)
    os.rename(tmp_path / "refs.bin", tmp_path / "refs.bin.new")
    app, board, hello = _boot(tmp_path, (26.0, 22.0))
    assert hello[HELLO_REFS_AT] == "S" and app.ev.ref == latched


def test_complete_refs_new_is_newer_and_a_partial_one_is_ignored(tmp_path):
    """A cut after writing refs.bin.new but before the rename: the new file is the latest latch;
    a cut while writing it leaves a partial file, which fails its CRC."""
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    old = (tmp_path / "refs.bin").read_bytes()
    for k in range(1, 31):
        board.chips[0].set_temperature(23.5 + 0.05 * k)
        run_cycles(app, board, 10)
    _send(app, board, scmd(app, "L"))
    newer = list(app.ev.ref)
    (tmp_path / "refs.bin.new").write_bytes((tmp_path / "refs.bin").read_bytes())
    (tmp_path / "refs.bin").write_bytes(old)
    app, board, hello = _boot(tmp_path, (26.0, 22.0))
    assert hello[HELLO_REFS_AT] == "S" and app.ev.ref == newer
    (tmp_path / "refs.bin.new").write_bytes(old[:-3])
    app, board, hello = _boot(tmp_path, (26.0, 22.0))
    assert hello[HELLO_REFS_AT] == "S" and app.ev.ref == _stored(tmp_path)[1] != newer


def test_unwritable_flash_keeps_the_latch_and_says_so(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    (tmp_path / "refs.bin.new").mkdir()  # opening the temp file for writing fails
    run_cycles(app, board, 5)
    assert _near(app.ev.ref[0], 23.5) and not app.unlatched
    assert app.ref_state == 3 and _send(app, board, cmd(b"TC,V"))[0][HELLO_REFS_AT] == "U"


def test_L_relatches_and_persists(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    for k in range(1, 31):  # the machine warms (slowly: a jump would be flagged)
        board.chips[0].set_temperature(23.5 + 0.05 * k)
        run_cycles(app, board, 10)
    assert _near(app.ev.ref[0], 23.5)
    out = _send(app, board, scmd(app, "L"))
    assert out[0][3:6] == ["A", "L", "L"], out
    assert _near(app.ev.ref[0], 25.0) and app.ev.temps == app.ev.ref
    assert _stored(tmp_path) == (app.table.crc, app.ev.ref)
    relatched = list(app.ev.ref)
    app, board, hello = _boot(tmp_path, (25.0, 21.0))  # and it survives a restart
    assert hello[HELLO_REFS_AT] == "S" and app.ev.ref == relatched


def test_L_latches_a_pending_table_at_once(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    out = _send(app, board, scmd(app, "L"))  # before the first cycle nothing has read good
    assert out[0][3:7] == ["E", "5", "state", "sensor faulty"], out
    assert app.unlatched and not (tmp_path / "refs.bin").exists()


def _state(app, tmp_path):
    p = tmp_path / "refs.bin"
    return (list(app.ev.ref) if app.ev else None, app.ref_state, app.unlatched,
            p.read_bytes() if p.exists() else None)


def test_L_with_a_needed_sensor_faulty_is_refused_and_changes_nothing(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    board.chips[1].set_ohm(400.0)  # far outside the plausible range
    run_cycles(app, board, 2)
    assert app.status & 0x2
    before = _state(app, tmp_path)
    out = _send(app, board, scmd(app, "L"))
    assert out[0][3:7] == ["E", "5", "state", "sensor faulty"], out
    assert _state(app, tmp_path) == before


def test_L_with_fixed_references_or_no_table_is_refused(tmp_path):
    app, board, hello = _boot(tmp_path, (23.5, 21.0), _table(ref_mode=0))
    assert hello[HELLO_REFS_AT] == "-"
    run_cycles(app, board, 5)
    before = _state(app, tmp_path)
    out = _send(app, board, scmd(app, "L"))
    assert out[0][3:7] == ["E", "5", "state", "fixed references"], out
    assert _state(app, tmp_path) == before and before[3] is None
    (tmp_path / "table_a.bin").unlink()
    app, board, hello = _boot(tmp_path, (23.5, 21.0))
    assert hello[HELLO_REFS_AT] == "-" and app.table is None
    run_cycles(app, board, 2)
    out = _send(app, board, scmd(app, "L"))
    assert out[0][3:7] == ["E", "5", "state", "no table"], out
    assert _send(app, board, cmd(b"TC,L,1"))[0][3:5] == ["E", "2"]  # L takes no argument


def test_new_table_upload_latches_anew(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    old = _stored(tmp_path)
    for k in range(1, 31):
        board.chips[0].set_temperature(23.5 + 0.05 * k)
        run_cycles(app, board, 10)
    new = _table(S0=55)
    out = _send(app, board, scmd(app, "U", "B", len(new), "%08X" % zlib.crc32(new)))
    for off in range(0, len(new), 48):
        out = _send(app, board, tagged_chunk(app, off, new[off:off + 48]))
    out = _send(app, board, scmd(app, "U", "C", extra=hashlib.sha256(new).digest()))
    assert out[0][3:7] == ["A", "U", "C", "B"] and out[1][3] == "H"
    assert out[1][HELLO_REFS_AT] == "O" and app.unlatched  # the stored references belong to the old table
    assert _stored(tmp_path) == old
    run_cycles(app, board, 2)
    assert _near(app.ev.ref[0], 25.0)
    assert _stored(tmp_path) == (app.table.crc, app.ev.ref) != old


def _rtu(body):
    from firmware.crc16 import crc16_modbus
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


def _ask(app, board, req):
    board.serial.feed(_rtu(req))
    app.link.poll(board.clock.t)
    board.clock.t += 5
    app.link.poll(board.clock.t)
    return board.serial.take()


def _signed(app, board, req):
    """Write the auth block for the write ``req``, then send it."""
    block = modbus_auth_block(app, req)
    assert _ask(app, board, block) == _rtu(block[:6])
    return _ask(app, board, req)


def test_modbus_latch_register(tmp_path):
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table(), mode="modbus")
    read_state = bytes([1, 4, 0, 14, 0, 1])
    assert _ask(app, board, read_state) == _rtu(bytes([1, 4, 2, 0, 4]))  # pending, nothing stored
    run_cycles(app, board, 5)
    assert _ask(app, board, read_state) == _rtu(bytes([1, 4, 2, 0, 2]))  # latched and stored
    assert (app.status >> 16) & 0x800 == 0
    for k in range(1, 31):
        board.chips[0].set_temperature(23.5 + 0.05 * k)
        run_cycles(app, board, 10)
    write = bytes([1, 6, 0, 7, 0, 1])
    assert _ask(app, board, write) == _rtu(bytes([1, 0x86, 4]))  # not authorised
    assert _signed(app, board, write) == _rtu(write)
    assert _near(app.ev.ref[0], 25.0) and _stored(tmp_path) == (app.table.crc, app.ev.ref)
    assert _ask(app, board, bytes([1, 3, 0, 7, 0, 1])) == _rtu(bytes([1, 3, 2, 0, 0]))  # reads 0
    # a needed sensor faulty: exception 04, nothing changes (a multi-write neither)
    board.chips[1].set_ohm(400.0)
    run_cycles(app, board, 2)
    before = (_state(app, tmp_path), list(app.link.hold))
    assert _signed(app, board, write) == _rtu(bytes([1, 0x86, 4]))
    multi = bytes([1, 16, 0, 5, 0, 3, 6, 0, 0, 0, 9, 0, 1])  # reference + latch
    assert _signed(app, board, multi) == _rtu(bytes([1, 0x90, 4]))
    assert (_state(app, tmp_path), list(app.link.hold)) == before
    app, board, _ = _boot(tmp_path, (26.0, 21.0), mode="modbus")  # restart: stored ones kept
    assert _ask(app, board, read_state) == _rtu(bytes([1, 4, 2, 0, 1]))


WARM_RESTART = r"""
import gc, micropython
from fwfakes import make_rig
from firmware.app import App
def boot(temps):
    b = make_rig(2, 0, temps=temps, table_dir=".", extra={"frame_ms": 100})
    return App(b), b
app, board = boot([23.5, 21.0])
for k in range(20):
    app.cycle(); board.clock.t += 100
latched = list(app.ev.ref)
app, board = boot([25.0, 22.5])  # a warm restart
for k in range(20):
    app.cycle(); board.clock.t += 100
    board.serial.take()
print(latched[0], latched[1], app.ev.ref[0], app.ev.ref[1], app.ref_state, app.ev.temps[0])
gc.collect()
free = gc.mem_free()
micropython.heap_lock()
try:
    for k in range(100):
        app.cycle(); board.clock.t += 100
        board.serial.nout = 0
finally:
    micropython.heap_unlock()
print("locked", free - gc.mem_free(), app.cycles)
"""


@pytest.mark.micropython
def test_warm_restart_on_micropython(tmp_path):
    """The real interpreter: refs.bin written and read back by MicroPython's own file API,
    and the cycle after loading stored references allocates nothing."""
    mpy = compile_mpy(fakes=True)
    (tmp_path / "table_a.bin").write_bytes(_table())
    out = run_micropython(WARM_RESTART, str(tmp_path), mpy, "256K").split("\n")
    l0, l1, r0, r1, st, t0 = (int(v) for v in out[0].split())
    assert _near(l0, 23.5) and _near(l1, 21.0) and (r0, r1) == (l0, l1) and st == 1 and _near(t0, 25.0)
    assert _stored(tmp_path)[1] == [l0, l1]
    word, dfree, cycles = out[1].split()
    assert word == "locked" and int(dfree) == 0 and int(cycles) == 120


def test_reset_command_restart_keeps_the_stored_references(tmp_path):
    """`X` (in-process restart, as main() does on a board without a hardware reset)."""
    from firmware.app import App, Restart
    app, board, _ = _boot(tmp_path, (23.5, 21.0), _table())
    run_cycles(app, board, 5)
    latched = list(app.ev.ref)
    board.chips[0].set_temperature(23.6)
    run_cycles(app, board, 5)
    board.serial.feed(scmd(app, "X"))
    with pytest.raises(Restart):
        app.link.poll(board.clock.t)
    app = App(board)
    out = frames(board.serial.take())
    assert out[0][3:5] == ["A", "X"] and out[1][3] == "H" and out[1][HELLO_REFS_AT] == "S", out
    run_cycles(app, board, 5)
    assert app.ev.ref == latched and _near(app.ev.temps[0], 23.6)
