"""A dynamic table's lag states survive a warm restart (lags.bin, firmware/warmstate.py; docs/firmware.md
"Warm restarts of the lag states", issue 21).

The states are written every 10 min (cycle time), at a latch (the rest state) and before an X reset. At a restart
the newest record of this table and these references is used at the first all-good cycle only if the machine is
where it was: every sensor within 1 K of its reading at the write, and the observer's estimate from the present
temperatures within 10 um of output of its estimate from those at the write; otherwise the observer (or rest) starts
the states. A power cut during a write leaves the old or the new record, never a mix.
"""
import pathlib
import random
import struct

import pytest

from fwhelpers import (POWER_CUT_FILE, HELLO_REFS_AT, cmd, compile_mpy, frames, make_table, provision, run_cycles, run_micropython,
                       scmd)

SETTLE_S = 3000.0
WARM = (24.0, 25.0, 26.0)  # T1..T3, the sensors the test table's filters read, on a warm machine
RPM = 6000


def _temps(shift=(0.0, 0.0, 0.0)):
    return [WARM[k] + shift[k] for k in range(3)] + [20.0 + i for i in range(3, 11)]


def _boot(tmp_path, table=None, temps=None):
    """A board on the fakes with table_dir ``tmp_path`` (``table`` written to slot A first); the spindle reported."""
    from fwfakes import make_rig
    from firmware.app import App
    if table is not None:
        (tmp_path / "table_a.bin").write_bytes(table)
        provision(tmp_path)
    board = make_rig(9, 2, temps=temps or _temps(), table_dir=str(tmp_path), extra={"frame_ms": 0}, serial_size=1 << 20)
    app = App(board)
    hello = frames(board.serial.take())[0]
    board.serial.feed(cmd(b"TC,P,0,%d" % RPM))
    app.link.poll(board.clock.t)
    return app, board, hello


def _lags(t, Y):
    """The lag states of ``Y`` (a term without a lag holds its input, not a state)."""
    return [Y[j] for j in range(t.nf) if t.A[j]]


def _to_first_good_cycle(app, board):
    """Cycles of 0.1 s (less than a filter step) until the board has judged its stored record and set its states."""
    n = 0
    while app.lag_rec is not None or app.unobserved:
        run_cycles(app, board, 1)
        n += 1
        assert n < 20
    run_cycles(app, board, 1)


def _records(path, nf, n):
    """Decode lags.bin independently of the firmware: [(seq, table crc, tag, Y, temps, spin, feed, settled)]."""
    from firmware.crc16 import crc16_ccitt
    b = path.read_bytes()
    size = 18 + 4 * (nf + n + 3)
    assert len(b) == 2 * size
    out = []
    for off in (0, size):
        r = b[off:off + size]
        if r[:4] == b"TL\x01" + bytes([nf]) and r[14:16] == bytes([n, 0]) and \
                struct.unpack_from("<H", r, size - 2)[0] == crc16_ccitt(r[:-2]):
            seq, crc, tag = struct.unpack_from("<IIH", r, 4)
            w = list(struct.unpack_from("<%di" % (nf + n + 3), r, 16))
            out.append((seq, crc, tag, w[:nf], w[nf:nf + n], w[nf + n], w[nf + n + 1], w[nf + n + 2]))
    return sorted(out)


def _observer_start(app):
    """The states an observer-only start gives at the present inputs (a fresh evaluator of the same table)."""
    from firmware.evaluate import Evaluator
    ev = Evaluator(app.table)
    ev.temps[:] = app.ev.temps
    ev.set_spindle(app.ev.spin)
    ev.set_feed_rate(app.ev.fin)
    ev.update()
    ev.observe()
    return ev


def _heat_until_written(app, board):
    """Warm the machine (the filters' inputs rise), then run to the cycle of the first periodic write; returns it."""
    seq = app.lags.seq
    for k in range(3):
        board.chips[k].set_temperature(WARM[k] + 1.0)
    n = 0
    while app.lags.seq == seq:
        run_cycles(app, board, 1, dt=1000)
        n += 1
        assert n < 700
    return _records(pathlib.Path(app.lags.path), app.table.nf, app.table.n_sensors)[-1]


@pytest.fixture(scope="module")
def observer_table():
    return make_table(kind="dynamic_observer", sensors=["T%d" % i for i in range(1, 12)], settle_s=SETTLE_S)


def test_short_cut_restores_the_states_and_settling_goes_on_where_it_was(tmp_path, observer_table):
    from firmware.app import LAGS_RESTORED
    from firmware.warmstate import ref_tag
    from firmware.wire import SETTLING
    app, board, _ = _boot(tmp_path, observer_table)
    run_cycles(app, board, 3, dt=1000)
    t = app.table
    assert t.obs and not app.unobserved and app.status & SETTLING
    rec = _heat_until_written(app, board)
    seq, crc, tag, Y, temps, spin, feed, settled = rec
    assert crc == t.crc and tag == ref_tag(t.ref) and Y == app.ev.Y and temps == app.ev.temps
    assert spin == RPM and feed == 0 and settled == app.settle_s and 590 <= settled <= 610
    # the power fails right after the write; back within the same second on a machine at the same temperatures
    app2, board2, _ = _boot(tmp_path, temps=_temps((1.0, 1.0, 1.0)))
    assert app2.lag_rec is not None and app2.unobserved
    _to_first_good_cycle(app2, board2)
    assert app2.lag_verdict == LAGS_RESTORED and not app2.unobserved and app2.ev.Y == Y
    assert app2.settle_s == settled and app2.status & SETTLING  # the restored state was itself settling: it goes on
    # from the first cycle the restored board is the uninterrupted one (within a step's phase), where the observer's
    # start is not
    obs = _observer_start(app2)
    assert abs(obs.offset_at(0) - app.ev.offset_at(0)) > 50  # 0.5 um: the two starts are told apart
    for k in range(60):
        run_cycles(app, board, 1, dt=1000)
        run_cycles(app2, board2, 1, dt=1000)
        assert abs(app2.ev.offset_at(0) - app.ev.offset_at(0)) <= 2, k
    # SETTLING clears settle_s after the estimate, counting the time before the cut: 3000 - settled s after the restart
    run_cycles(app2, board2, int(SETTLE_S - settled) - 60 - 5, dt=1000)
    assert app2.status & SETTLING
    run_cycles(app2, board2, 10, dt=1000)
    assert not app2.status & SETTLING
    # a settled state restores settled: no SETTLING once restored
    rec2 = _heat_until_written(app2, board2)
    assert rec2[0] > rec[0] and rec2[7] == int(SETTLE_S)
    app3, board3, _ = _boot(tmp_path, temps=_temps((1.0, 1.0, 1.0)))
    _to_first_good_cycle(app3, board3)
    assert app3.lag_verdict == LAGS_RESTORED and not app3.status & SETTLING and app3.ev.Y == rec2[3]


def test_a_machine_that_moved_during_the_cut_gets_the_observer(tmp_path, observer_table, monkeypatch):
    from firmware.app import LAGS_DISAGREE, LAGS_MOVED, LAGS_RESTORED
    from firmware.wire import SETTLING
    app, board, _ = _boot(tmp_path, observer_table)
    run_cycles(app, board, 3, dt=1000)
    Y = _heat_until_written(app, board)[3]
    base = (1.0, 1.0, 1.0)
    # one sensor 1.1 K away from its reading at the write: the machine cooled or heated while the board was off
    for k in range(3):
        shift = list(base)
        shift[k] += 1.1
        app2, board2, _ = _boot(tmp_path, temps=_temps(shift))
        _to_first_good_cycle(app2, board2)
        assert app2.lag_verdict == LAGS_MOVED and app2.ev.Y == _observer_start(app2).Y != Y, k
        assert app2.settle_s == 0 and app2.status & SETTLING
    # the observer's own check: with the drift limit out of the way (this table's observer moves its output by
    # 1.2 um per K on every sensor), a machine 10 K warmer is seen by the observer: its estimate is used
    import firmware.app
    monkeypatch.setattr(firmware.app, "_LAG_DRIFT_MK", 50000)
    app2, board2, _ = _boot(tmp_path, temps=_temps((11.0, 11.0, 11.0)))
    _to_first_good_cycle(app2, board2)
    assert app2.lag_verdict == LAGS_DISAGREE and app2.ev.Y == _observer_start(app2).Y
    app2, board2, _ = _boot(tmp_path, temps=_temps((3.0, 3.0, 3.0)))
    _to_first_good_cycle(app2, board2)
    assert app2.lag_verdict == LAGS_RESTORED  # 2 K: the observer's view moved less than 10 um
    monkeypatch.undo()
    # within both: restored
    app2, board2, _ = _boot(tmp_path, temps=_temps((1.9, 0.1, 1.0)))
    _to_first_good_cycle(app2, board2)
    assert app2.lag_verdict == LAGS_RESTORED and _lags(app2.table, app2.ev.Y) == _lags(app2.table, Y)


def test_another_tables_or_damaged_records_are_not_used(tmp_path, observer_table):
    from firmware.app import LAGS_NONE
    from firmware.table import parse_table
    from firmware.warmstate import LagStore
    app, board, _ = _boot(tmp_path, observer_table)
    run_cycles(app, board, 3, dt=1000)
    _heat_until_written(app, board)
    path = tmp_path / "lags.bin"
    old = path.read_bytes()
    Y_old = list(app.ev.Y)
    t = parse_table(observer_table)
    for k in range(3):
        board.chips[k].set_temperature(WARM[k] + 1.5)
    run_cycles(app, board, 600, dt=1000)
    new = path.read_bytes()
    h = app.lags
    Y_new = _records(path, t.nf, t.n_sensors)[-1][3]
    assert Y_new != _records(path, t.nf, t.n_sensors)[0][3]
    n = h.size
    off = n if h.seq & 1 else 0
    assert old[:off] == new[:off] and old[off + n:] == new[off + n:]
    for k in range(n + 1):
        for rest in ("old", 0xFF, 0x00):
            tail = old[off + k:off + n] if rest == "old" else bytes([rest]) * (n - k)
            path.write_bytes(old[:off] + new[off:off + k] + tail + old[off + n:])
            got = LagStore(str(tmp_path), t, h.tag).load()
            assert got is not None
            assert got[:t.nf] == (Y_new if k == n else _records_y(old, t, off)), (k, rest)
    rng = random.Random(5)
    for _ in range(200):
        b = bytearray(new)
        for o in (0, n):
            b[o + rng.randrange(n)] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(b))
        assert LagStore(str(tmp_path), t, h.tag).load() is None
    path.write_bytes(new)
    assert LagStore(str(tmp_path), t, h.tag ^ 1).load() is None  # other references' records
    # another table (same sensors and filters, other coefficients): its record is not this table's
    other = make_table(kind="dynamic_observer", sensors=["T%d" % i for i in range(1, 12)], settle_s=SETTLE_S - 1)
    assert parse_table(other).nf == t.nf and parse_table(other).crc != t.crc
    app2, board2, _ = _boot(tmp_path, other, temps=_temps((1.5, 1.5, 1.5)))
    assert app2.lag_rec is None
    _to_first_good_cycle(app2, board2)
    assert app2.lag_verdict == LAGS_NONE and app2.ev.Y == _observer_start(app2).Y
    assert Y_old != app2.ev.Y


def _records_y(blob, t, written_off):
    """Y of the record in the slot that was not being written (the one the loader must fall back to)."""
    n = len(blob) // 2
    keep = n - written_off
    r = blob[keep:keep + n]
    return list(struct.unpack_from("<%di" % t.nf, r, 16))


def test_latched_table_restores_with_its_references_and_a_latch_stores_rest(tmp_path):
    """A dynamic table without an observer (run-start references): the states restore only with the stored references
    (hello S); L is a cold start that stores the rest state; without the stored references the latch is pending and
    nothing is restored."""
    import os
    from firmware.app import LAGS_NONE, LAGS_RESTORED
    from firmware.warmstate import ref_tag
    table = make_table(kind="dynamic", sensors=["T%d" % i for i in range(1, 12)])
    app, board, hello = _boot(tmp_path, table)
    run_cycles(app, board, 3, dt=1000)
    t = app.table
    assert t.ref_mode == 1 and not t.obs and hello[HELLO_REFS_AT] == "N"
    rest = _records(tmp_path / "lags.bin", t.nf, t.n_sensors)[-1]
    assert rest[2] == ref_tag(app.ev.ref) and not any(rest[3][j] for j in range(t.nf) if t.A[j])  # at the latch
    Y = _heat_until_written(app, board)[3]
    assert any(Y[j] for j in range(t.nf) if t.A[j])
    app2, board2, hello = _boot(tmp_path, temps=_temps((1.0, 1.0, 1.0)))
    _to_first_good_cycle(app2, board2)
    assert hello[HELLO_REFS_AT] == "S" and app2.lag_verdict == LAGS_RESTORED and _lags(t, app2.ev.Y) == _lags(t, Y)
    # an X reset writes the state of that very moment
    run_cycles(app2, board2, 30, dt=1000)
    board2.serial.feed(scmd(app2, "X"))
    from firmware.app import Restart
    with pytest.raises(Restart):
        app2.link.poll(board2.clock.t)
    at_reset = list(app2.ev.Y)
    assert at_reset != Y and _records(tmp_path / "lags.bin", t.nf, t.n_sensors)[-1][3] == at_reset
    # L: a cold start; the rest state is stored under the new references
    board2.serial.feed(scmd(app2, "L"))
    app2.link.poll(board2.clock.t)
    assert frames(board2.serial.take())[-1][3:5] == ["A", "L"]
    last = _records(tmp_path / "lags.bin", t.nf, t.n_sensors)[-1]
    assert last[2] == ref_tag(app2.ev.ref) and not any(last[3][j] for j in range(t.nf) if t.A[j])
    # without the stored references (refs.bin lost) the latch is pending: a cold start, the record unused
    os.remove(str(tmp_path / "refs.bin"))
    app3, board3, hello = _boot(tmp_path, temps=_temps((1.0, 1.0, 1.0)))
    assert hello[HELLO_REFS_AT] == "N" and app3.lag_rec is None
    _to_first_good_cycle(app3, board3)
    assert app3.lag_verdict == LAGS_NONE


MP_SCRIPT = r"""
import gc, micropython
from fwfakes import make_rig
from firmware.app import App
from firmware.warmstate import LagStore
from firmware.crc16 import crc16_ccitt
body = b"TC,P,0,6000"
P = b"$" + body + b"*" + (b"%04X" % crc16_ccitt(body)) + b"\r\n"
def boot(shift):
    b = make_rig(9, 2, temps=[24.0 + shift, 25.0 + shift, 26.0 + shift] + [20.0 + i for i in range(3, 11)], table_dir=".",
                 extra={"frame_ms": 100})
    a = App(b)
    b.serial.feed(P)
    return a, b
def cycles(app, board, n):
    for k in range(n):
        app.cycle(); board.clock.t += 1000
        board.serial.nout = 0
app, board = boot(0.0)
cycles(app, board, 3)
for k in range(3):
    board.chips[k].set_temperature(25.0 + k)
h = app.lags
seq0 = h.seq
gc.collect()
free = gc.mem_free()
micropython.heap_lock()
try:
    cycles(app, board, 1300)  # 21.7 min: two writes inside the locked cycle
finally:
    micropython.heap_unlock()
print("locked", free - gc.mem_free(), h.seq - seq0)
for k in CUTS:
    h = app.lags
    real = h.f
    w_old = LagStore(".", app.table, h.tag).load()
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
    y_new = list(app.ev.Y)
    real.close()  # the power is gone
    app = board = h = view = None
    gc.collect()
    app, board = boot(1.0)  # power back within the second, on the same warm machine
    while app.lag_rec is not None or app.unobserved:  # to the first all-good cycle, in steps shorter than a filter's
        app.cycle(); board.clock.t += 100
    got = app.ev.Y
    print("cut", k, dfree, app.lag_verdict, 1 if got == y_new else (0 if got == w_old[:len(got)] else -1))
    cycles(app, board, 5)
"""


@pytest.mark.micropython
def test_writes_in_the_heap_locked_cycle_and_power_cuts_on_micropython(tmp_path, observer_table):
    from firmware.table import parse_table
    mpy = compile_mpy(fakes=True)
    (tmp_path / "table_a.bin").write_bytes(observer_table)
    t = parse_table(observer_table)
    n = 18 + 4 * (t.nf + t.n_sensors + 3)
    cuts = sorted(random.Random(17).sample(range(1, n), 5)) + [n]
    out = run_micropython("CUTS = %r\n" % cuts + POWER_CUT_FILE + MP_SCRIPT, str(tmp_path), mpy, "256K").split("\n")
    word, dfree, writes = out[0].split()
    assert word == "locked" and int(dfree) == 0 and int(writes) == 2
    for k, line in zip(cuts, out[1:]):
        word, kk, dfree, verdict, which = line.split()[:5]
        assert word == "cut" and int(kk) == k and int(dfree) == 0 and int(verdict) == 1, line
        assert int(which) == (1 if k == n else 0), line  # the new record only when complete, else the old


def test_a_new_latch_outranks_a_stale_record_of_the_same_references(tmp_path):
    """A record written before refs.bin was lost, with references a new latch happens to repeat exactly (the same
    temperatures): the latch's rest state must be the newer record, not the stale warm state (the writes' sequence
    numbers go on above every intact record in the file)."""
    import os
    from firmware.app import LAGS_RESTORED
    table = make_table(kind="dynamic", sensors=["T%d" % i for i in range(1, 12)])
    app, board, _ = _boot(tmp_path, table)
    run_cycles(app, board, 3, dt=1000)
    t = app.table
    for k in range(3):
        board.chips[k].set_temperature(WARM[k] + 1.0)
    run_cycles(app, board, 300, dt=1000)
    for k in range(3):  # back where it started: the lag states still hold the warm-up
        board.chips[k].set_temperature(WARM[k])
    seq = app.lags.seq
    while app.lags.seq == seq:  # the periodic write, 10 min after the latch
        run_cycles(app, board, 1, dt=1000)
    stale = _records(tmp_path / "lags.bin", t.nf, t.n_sensors)[-1]
    # a warm state whose readings are the first boot's (within 0.1 K): the restore rule alone would take it
    assert any(_lags(t, stale[3])) and max(abs(a - 1000 * w) for a, w in zip(stale[4], WARM)) < 100
    os.remove(str(tmp_path / "refs.bin"))
    app2, board2, _ = _boot(tmp_path)  # the same temperatures as the first boot: the latch repeats its references
    _to_first_good_cycle(app2, board2)
    assert app2.ref_state == 2 and app2.ev.ref == app.ev.ref
    app3, board3, hello = _boot(tmp_path)
    _to_first_good_cycle(app3, board3)
    assert app3.lag_verdict == LAGS_RESTORED and not any(_lags(t, app3.ev.Y)), (_lags(t, app3.ev.Y), _lags(t, stale[3]))
