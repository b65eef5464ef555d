"""The screw state survives a warm restart (heat.bin, firmware/warmstate.py; docs/firmware.md "Warm restarts").

A screw table with latched references: the state is written every 10 min (simulated), at every
latch (zeroed: a cold start) and before an X reset; it is restored when the stored references are
restored (hello letter S). A power cut during a write leaves the old or the new record, never a mix.
"""
import os
import random
import struct

import pytest

from fwhelpers import POWER_CUT_FILE, HELLO_REFS_AT, compile_mpy, frames, provision, run_cycles, run_micropython, scmd

SAVE_MS = 600000
TEMPS = (22.0, 23.0)  # T1 base sensor, T2 the air


@pytest.fixture(scope="module")
def screw_table():
    from hil_tests.rig.boards import _finish, export, screw_doc
    doc = screw_doc(["T1", "T2"])
    doc["thermal"]["reduced"]["base_ref"] = "run_start"  # tcomp fit --model screw's default: latched references
    return export(_finish(doc)).table


def _boot(tmp_path, table=None, temps=TEMPS):
    from fwfakes import make_rig
    from firmware.app import App
    if table is not None:
        (tmp_path / "table_a.bin").write_bytes(table)
        provision(tmp_path)
    board = make_rig(2, 0, temps=list(temps), table_dir=str(tmp_path), extra={"frame_ms": 0}, serial_size=1 << 16)
    app = App(board)
    return app, board, frames(board.serial.take())[0]


def _records(path):
    """Decode heat.bin independently of the firmware: [(seq, table crc, tag, T)] of the CRC-valid slots."""
    from firmware.crc16 import crc16_ccitt
    b = path.read_bytes()
    n = len(b) // 2
    m = (n - 18) // 4
    assert len(b) == 2 * n == 2 * (18 + 4 * m)
    out = []
    for off in (0, n):
        r = b[off:off + n]
        if r[:4] == b"TH\x01" + bytes([m]) and struct.unpack_from("<H", r, n - 2)[0] == crc16_ccitt(r[:-2]):
            seq, crc, tag = struct.unpack_from("<IIH", r, 4)
            out.append((seq, crc, tag, list(struct.unpack_from("<%di" % m, r, 16))))
    return sorted(out)


def _heat(app, board, minutes):
    app.set_feed(10000, 100000, 700000)  # 10 m/min over 600 mm: the nut heats the screw
    run_cycles(app, board, int(minutes * 60), dt=1000)


def test_warm_restart_restores_the_state_and_a_cold_one_would_not(tmp_path, screw_table):
    from firmware.app import App, Restart
    from firmware.warmstate import ref_tag
    app, board, hello = _boot(tmp_path, screw_table)
    assert app.table.ref_mode == 1 and hello[HELLO_REFS_AT] == "N"
    run_cycles(app, board, 3, dt=1000)
    settled = list(app.ev.T)
    recs = _records(tmp_path / "heat.bin")
    assert [r[3] for r in recs] == [settled] and recs[0][2] == ref_tag(app.ev.ref)  # written at the latch
    saves = []
    real = app.heat.save
    app.heat.save = lambda T: saves.append(list(T)) or real(T)
    _heat(app, board, 25)
    assert len(saves) == 2, "every 10 min, not more"
    newest = _records(tmp_path / "heat.bin")[-1]
    assert newest[3] == saves[-1] and newest[1] == app.table.crc
    assert max(saves[-1]) > max(settled) + (1 << app.table.ft)  # more than 1 K of stored heat
    # power cut 5 min after the last write: the restart resumes from that write, not from cold
    app, board, hello = _boot(tmp_path)
    assert hello[HELLO_REFS_AT] == "S" and app.warm and app.ev.T == saves[-1]
    run_cycles(app, board, 2, dt=1000)
    assert max(app.ev.T) > max(settled) + (1 << app.table.ft)  # not settled at the first good cycle
    # an X reset writes the state of that moment first
    _heat(app, board, 3)
    board.serial.feed(scmd(app, "X"))
    with pytest.raises(Restart):
        app.link.poll(board.clock.t)
    at_reset = list(app.ev.T)
    app = App(board)
    assert app.ev.T == at_reset and frames(board.serial.take())[1][HELLO_REFS_AT] == "S"
    # without heat.bin (before issue 13, or a new board) the same restart starts cold
    os.remove(str(tmp_path / "heat.bin"))
    app, board, hello = _boot(tmp_path)
    run_cycles(app, board, 2, dt=1000)
    assert hello[HELLO_REFS_AT] == "S" and not app.warm and max(app.ev.T) < max(at_reset) - (1 << app.table.ft)


def test_latch_is_a_cold_start_that_zeroes_the_stored_state(tmp_path, screw_table):
    from firmware.evaluate import Evaluator
    from firmware.warmstate import ref_tag
    app, board, _ = _boot(tmp_path, screw_table)
    run_cycles(app, board, 3, dt=1000)
    _heat(app, board, 11)
    assert max(_records(tmp_path / "heat.bin")[-1][3]) > max(app.ev.T) // 2 > 0
    board.chips[1].set_temperature(23.3)  # the air has moved since the first latch
    run_cycles(app, board, 3, dt=1000)
    board.serial.feed(scmd(app, "L"))
    app.link.poll(board.clock.t)
    ack = frames(board.serial.take())[-1]
    assert ack[3:5] == ["A", "L"]
    cold = Evaluator(app.table)
    cold.temps[:] = app.ev.temps
    cold.latch_references()
    assert app.ev.T == cold.T
    newest = _records(tmp_path / "heat.bin")[-1]
    assert newest[3] == cold.T and newest[2] == ref_tag(app.ev.ref)
    app, board, hello = _boot(tmp_path, temps=(22.0, 23.3))  # a restart now resumes from the zeroed state
    assert hello[HELLO_REFS_AT] == "S" and app.ev.T == cold.T


def test_power_cut_during_a_write_leaves_the_old_or_the_new_record(tmp_path, screw_table):
    """Every cut point of the slot being written, with the rest of the slot left as it was, erased
    (0xFF) or zeroed: the loader restores the previous record unless the new one is complete."""
    from firmware.table import parse_table
    from firmware.warmstate import HeatStore
    app, board, _ = _boot(tmp_path, screw_table)
    run_cycles(app, board, 3, dt=1000)
    _heat(app, board, 10.5)
    path = tmp_path / "heat.bin"
    old = path.read_bytes()
    h = app.heat
    t_old = _records(path)[-1][3]
    _heat(app, board, 10)
    new = path.read_bytes()
    t_new = _records(path)[-1][3]
    assert t_new != t_old
    n = h.size
    off = n if h.seq & 1 else 0
    assert old[:off] == new[:off] and old[off + n:] == new[off + n:]
    table = parse_table(screw_table)
    seen = set()
    for k in range(n + 1):
        for rest in ("old", 0xFF, 0x00):
            tail = old[off + k:off + n] if rest == "old" else bytes([rest]) * (n - k)
            path.write_bytes(old[:off] + new[off:off + k] + tail + old[off + n:])
            got = HeatStore(str(tmp_path), table, h.tag).load()
            want = t_new if k == n else t_old
            assert got == want, (k, rest)
            seen.add(k == n)
    assert seen == {True, False}
    # both slots damaged: no state at all (a cold start), never a damaged one
    rng = random.Random(3)
    for _ in range(200):
        b = bytearray(new)
        for off2 in (0, n):
            b[off2 + rng.randrange(n)] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(b))
        assert HeatStore(str(tmp_path), table, h.tag).load() is None
    # another table's or other references' records are not used
    path.write_bytes(new)
    assert HeatStore(str(tmp_path), table, h.tag ^ 1).load() is None


MP_SCRIPT = r"""
import gc, micropython
from fwfakes import make_rig
from firmware.app import App
from firmware.warmstate import HeatStore
def boot():
    b = make_rig(2, 0, temps=[22.0, 23.0], table_dir=".", extra={"frame_ms": 100})
    return App(b), b
def cycles(app, board, n):
    for k in range(n):
        app.cycle(); board.clock.t += 1000
        board.serial.nout = 0
app, board = boot()
cycles(app, board, 3)
app.set_feed(10000, 100000, 700000)
cycles(app, board, 30)
h = app.heat
seq0 = h.seq
gc.collect()
free = gc.mem_free()
micropython.heap_lock()
try:
    cycles(app, board, 1300)  # 21.7 min: two state writes inside the locked cycle
finally:
    micropython.heap_unlock()
print("locked", free - gc.mem_free(), h.seq - seq0)
for k in CUTS:
    h = app.heat
    real = h.f
    t_old = HeatStore(".", app.table, h.tag).load()
    view = memoryview(h.buf)[:k]
    h.f = Cut(real, view)
    h.ms = 600000 - 1000  # the next cycle writes
    gc.collect()
    free = gc.mem_free()
    micropython.heap_lock()
    try:
        cycles(app, board, 1)
    finally:
        micropython.heap_unlock()
    dfree = free - gc.mem_free()
    t_new = list(app.ev.T)
    real.close()  # the power is gone
    app = board = h = view = None
    gc.collect()
    app, board = boot()  # power back: a warm restart, which runs on (and meets the next cut)
    got = app.ev.T
    print("cut", k, dfree, app.ref_state, 1 if got == t_new else (0 if got == t_old else -1))
    app.set_feed(10000, 100000, 700000)
    cycles(app, board, 60)
"""


@pytest.mark.micropython
def test_state_writes_in_the_heap_locked_cycle_and_power_cuts_on_micropython(tmp_path, screw_table):
    mpy = compile_mpy(fakes=True)
    (tmp_path / "table_a.bin").write_bytes(screw_table)
    n = 18 + 4 * 8
    cuts = sorted(random.Random(13).sample(range(1, n), 5)) + [n]
    out = run_micropython("CUTS = %r\n" % cuts + POWER_CUT_FILE + MP_SCRIPT, str(tmp_path), mpy, "256K").split("\n")
    word, dfree, writes = out[0].split()
    assert word == "locked" and int(dfree) == 0 and int(writes) == 2
    for k, line in zip(cuts, out[1:]):
        word, kk, dfree, ref_state, verdict = line.split()[:5]
        assert word == "cut" and int(kk) == k and int(dfree) == 0 and int(ref_state) == 1
        assert int(verdict) == (1 if k == n else 0), line  # the new record only when complete, else the old
    assert len(out) >= len(cuts) + 1
