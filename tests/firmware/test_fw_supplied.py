"""The lag states the controller supplies (issue 21, table formats 7 and 8; docs/protocol.md "Supplied lag states").

A table whose spindle, squared-speed and feed lags are marked (tauc) does not start its lag states until the controller
has sent them: its dictionary (`Y`, Modbus input registers 54-71) names each one's source, time constant and scale;
`Y,<v1>,...` (Modbus holding registers 20-27) sets them; the other lag states are then estimated by the observer at the
first all-good cycle, as before. SETTLING is raised while they are awaited (after a start without them, until the
table's settle_nr, format 8; a format 7 table: until they come). Once set, a second supply is acknowledged
and not applied. A wrong count, a value outside the state's box or a table without such states is refused, naming
why, and nothing changes.
"""
import struct

from fwhelpers import cmd, frames, rig_app, run_cycles
from firmware.crc16 import crc16_modbus
from firmware.wire import (IR_SUPPLY_STATE, HR_SUPPLY, SETTLING, SUPPLY_AWAITED, SUPPLY_NONE, SUPPLY_SET)

SOURCE_TOP = {-1: 12000, -2: 12000 ** 2}  # the fixture's spindle envelope (rpm, rpm**2); the feed's is the table's fmax


def _app(tmp_path, mode="stream", kind="dynamic_supplied"):
    app, board = rig_app(tmp_path, kind=kind, serial_mode=mode, extra={"frame_ms": 0})
    return app, board


def _send(app, board, line):
    board.serial.feed(line)
    app.link.poll(board.clock.t)
    return [f for f in frames(board.serial.take()) if f[3] != "H"]  # the boot's hello may still be in the buffer


def _dictionary(app, board):
    out = _send(app, board, cmd(b"TC,Y"))
    assert len(out) == 1 and out[0][3] == "A" and out[0][4] == "Y", out
    f = out[0][5:]
    k = int(f[1])
    return f[0], [tuple(int(v) for v in f[2 + 3 * i:5 + 3 * i]) for i in range(k)]


def _values(app, entries, frac):
    """The controller's values at ``frac`` of each source's range, in the board's state units."""
    top = {**SOURCE_TOP, -3: app.table.fmax}
    return [int(round(frac * top[src] * 2 ** scale)) for src, _, scale in entries]


def test_dictionary_names_each_supplied_state(tmp_path):
    app, board = _app(tmp_path)
    t = app.table
    letter, entries = _dictionary(app, board)
    assert letter == "A"
    # the fixture (tests/firmware/fwhelpers.py dynamic_table): spindle 600 s, its square 1800 s, feed 300 s
    assert [(src, tau) for src, tau, _ in entries] == [(-1, 600000), (-2, 1800000), (-3, 300000)]
    # the scale is what makes the state's box the source's physical range
    top = {**SOURCE_TOP, -3: t.fmax}
    boxes = [t.Yhi[j] for j in range(t.nf) if t.tauc[j]]
    assert boxes == [top[src] * 2 ** scale for src, _, scale in entries]


def test_start_waits_for_the_supplied_states_then_takes_them(tmp_path):
    app, board = _app(tmp_path)
    _send(app, board, cmd(b"TC,P,0,6000"))
    _send(app, board, cmd(b"TC,M,1000,0,0"))
    run_cycles(app, board, 40)  # every sensor good, the speed reported: an observer table without supplied states starts here
    assert app.supply == SUPPLY_AWAITED and app.unobserved and app.status & SETTLING
    _, entries = _dictionary(app, board)
    vals = _values(app, entries, 0.5)
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in vals)))
    assert out[0][3:] == ["A", "Y", "S", "1"], out
    t = app.table
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]] == vals
    run_cycles(app, board, 1)  # the observer starts the other lag states; the supplied ones keep their values
    assert not app.unobserved and app.supply == SUPPLY_SET
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]] == vals
    assert any(app.ev.Y[j] for j in range(t.nf) if t.A[j] and not t.tauc[j])  # estimated, not at rest
    run_cycles(app, board, 20)  # 2 s: two filter steps from the supplied values toward the inputs
    now = [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]]
    assert now != vals and all(abs(a - b) < 0.01 * max(1, abs(b)) for a, b in zip(now, vals))
    # a second supply (the controller restarted, the board did not): acknowledged, not applied
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in _values(app, entries, 0.1))))
    assert out[0][3:] == ["A", "Y", "S", "0"]
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]] == now
    assert _dictionary(app, board)[0] == "S"


def test_refusals_change_nothing(tmp_path):
    app, board = _app(tmp_path)
    run_cycles(app, board, 30)
    _, entries = _dictionary(app, board)
    good = _values(app, entries, 0.5)
    before = list(app.ev.Y)
    bad_box = list(good)
    bad_box[1] = app.table.Yhi[[j for j in range(app.table.nf) if app.table.tauc[j]][1]] + 1
    for vals, want in ((good[:2], ["E", "2", "syntax", "supplied states: wrong count"]),
                       (good + [0], ["E", "2", "syntax", "supplied states: wrong count"]),
                       (bad_box, ["E", "4", "range", "supplied state 2 outside its box"]),
                       ([-1] + good[1:], ["E", "4", "range", "supplied state 1 outside its box"])):
        out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in vals)))
        assert out[0][3:] == want, (vals, out)
    out = _send(app, board, cmd(b"TC,Y,1,x,3"))
    assert out[0][3:5] == ["E", "4"]
    assert app.supply == SUPPLY_AWAITED and list(app.ev.Y) == before


def test_a_table_without_supplied_states_refuses_them(tmp_path):
    app, board = _app(tmp_path, kind="dynamic_observer")
    _send(app, board, cmd(b"TC,P,0,6000"))
    run_cycles(app, board, 30)
    assert _dictionary(app, board) == ("-", [])
    out = _send(app, board, cmd(b"TC,Y,5"))
    assert out[0][3:] == ["E", "5", "state", "no supplied states"]
    assert app.supply == SUPPLY_NONE and not app.unobserved  # it started without waiting for supplied states


def _rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


def _ask(app, board, body):
    board.serial.feed(_rtu(body))
    board.clock.t += 10
    app.link.poll(board.clock.t)
    return board.serial.take()


def test_modbus_dictionary_and_write(tmp_path):
    app, board = _app(tmp_path, mode="modbus")
    run_cycles(app, board, 30)
    out = _ask(app, board, bytes([1, 4, 0, IR_SUPPLY_STATE, 0, 2 + 4 * 3]))
    regs = [struct.unpack(">H", out[3 + 2 * i:5 + 2 * i])[0] for i in range(out[2] // 2)]
    assert regs[:2] == [SUPPLY_AWAITED, 3]

    def s16(v):
        return v - 65536 if v > 32767 else v
    entries = [(s16(regs[2 + 4 * i]), (regs[3 + 4 * i] << 16) | regs[4 + 4 * i], s16(regs[5 + 4 * i])) for i in range(3)]
    assert entries == _dictionary_stream_equivalent(app)
    vals = _values(app, entries, 0.25)
    body = b"".join(struct.pack(">i", v) for v in vals)
    # half a state, a wrong count, a value outside its box: exceptions 03, nothing set
    assert _ask(app, board, bytes([1, 16, 0, HR_SUPPLY, 0, 5, 10]) + body[:10])[1:3] == bytes([0x90, 3])
    assert _ask(app, board, bytes([1, 16, 0, HR_SUPPLY, 0, 4, 8]) + body[:8])[1:3] == bytes([0x90, 3])
    assert _ask(app, board, bytes([1, 16, 0, HR_SUPPLY, 0, 6, 12]) + struct.pack(">i", -5) + body[4:])[1:3] == bytes([0x90, 3])
    assert app.supply == SUPPLY_AWAITED
    out = _ask(app, board, bytes([1, 16, 0, HR_SUPPLY, 0, 6, 12]) + body)
    assert out[1] == 16 and app.supply == SUPPLY_SET
    t = app.table
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]] == vals
    out = _ask(app, board, bytes([1, 4, 0, IR_SUPPLY_STATE, 0, 1]))
    assert out[3:5] == bytes([0, SUPPLY_SET])
    assert _ask(app, board, bytes([1, 3, 0, HR_SUPPLY, 0, 6]))[3:15] == bytes(12)  # the registers read 0


def _dictionary_stream_equivalent(app):
    t = app.table
    return [(t.src[j], t.tauc[j], app.ev.supply_scale(j)) for j in range(t.nf) if t.tauc[j]]


def test_restart_restores_the_record_but_takes_the_supplied_states_from_the_controller(tmp_path):
    """lags.bin holds every state; after a restart on an unchanged machine the board restores it, but only once the
    controller has sent its states, and the supplied ones are the controller's, not the record's."""
    from firmware.app import App, LAGS_RESTORED
    app, board = _app(tmp_path)
    _send(app, board, cmd(b"TC,P,0,6000"))
    _, entries = _dictionary(app, board)
    _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in _values(app, entries, 0.5))))
    run_cycles(app, board, 6100)  # 10 min 10 s: lags.bin written once
    t = app.table
    stored = [app.ev.Y[j] for j in range(t.nf)]
    app2 = App(board)  # the restart, same flash, same temperatures
    app = app2
    run_cycles(app, board, 40)
    assert app.supply == SUPPLY_AWAITED and app.unobserved  # the record waits for the controller too
    fresh = _values(app, entries, 0.2)
    board.serial.take()
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in fresh)))
    assert out[0][3:] == ["A", "Y", "S", "1"]
    run_cycles(app, board, 1)
    assert app.lag_verdict == LAGS_RESTORED and not app.unobserved
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]] == fresh
    # the board's own states come from the record (within the filter steps of the 10 s since its write)
    for j in range(t.nf):
        if t.A[j] and not t.tauc[j]:
            assert abs(app.ev.Y[j] - stored[j]) <= 0.02 * max(abs(stored[j]), 1 << t.fy[j]), j


def test_without_the_controller_the_board_starts_after_10_s_and_takes_the_states_when_they_come(tmp_path):
    """A controller that does not send them (no --signal-record, a bridge started late): after 10 s the table starts
    with its supplied states at the steady state of the present speed (the host's start without a record), SETTLING
    stays raised until they come, and when they come they replace it."""
    app, board = _app(tmp_path)
    _send(app, board, cmd(b"TC,P,0,6000"))
    _send(app, board, cmd(b"TC,M,1000,0,0"))
    run_cycles(app, board, 95)
    assert app.unobserved  # 9.5 s: still waiting
    run_cycles(app, board, 10)
    t = app.table
    assert not app.unobserved and app.supply == SUPPLY_AWAITED and app.status & SETTLING
    steady = {-1: 6000, -2: 6000 ** 2, -3: 1000}
    sup = [j for j in range(t.nf) if t.tauc[j]]
    # the state is the input (rpm, rpm**2 / 2**shq, mm/min) in state units: the steady state, checked in the source's units
    for j in sup:
        assert abs(app.ev.Y[j] / 2.0 ** app.ev.supply_scale(j) - steady[t.src[j]]) <= 2.0 ** -app.ev.supply_scale(j) * 4, j
    run_cycles(app, board, 400)  # 40 s, past the fixture's settle_s (30 s): still SETTLING, the states never came
    assert app.status & SETTLING
    _, entries = _dictionary(app, board)
    vals = _values(app, entries, 0.5)
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in vals)))
    assert out[0][3:] == ["A", "Y", "S", "1"]
    assert [app.ev.Y[j] for j in sup] == vals
    run_cycles(app, board, 1)
    assert not app.status & SETTLING  # the estimate is older than settle_s and the states came


def test_without_the_controller_a_fitted_table_starts_them_at_its_estimate(tmp_path):
    """A fit writes gains for the supplied states (the estimate until the controller's values come): after 10 s without
    them the board starts them there, as the other lag states, not at the steady state; the values replace it."""
    from firmware.evaluate import Evaluator
    app, board = _app(tmp_path, kind="dynamic_supplied_gains")
    _send(app, board, cmd(b"TC,P,0,6000"))
    _send(app, board, cmd(b"TC,M,1000,0,0"))
    run_cycles(app, board, 105)
    t = app.table
    sup = [j for j in range(t.nf) if t.tauc[j]]
    assert not app.unobserved and app.supply == SUPPLY_AWAITED and app.status & SETTLING
    # the same table's observer on the same inputs, in a fresh evaluator: the supplied rows are estimated like the others
    ev = Evaluator(t)
    ev.temps[:] = app.ev.temps
    ev.set_spindle(6000)
    ev.set_feed_rate(1000)
    ev.update()
    ev.observe()
    steady = {-1: 6000, -2: 6000 ** 2, -3: 1000}
    for j in sup:
        assert abs(app.ev.Y[j] - ev.Y[j]) <= abs(ev.Y[j]) * 0.02 + 4, j  # one filter step since the start at most
        assert abs(ev.Y[j] / 2.0 ** ev.supply_scale(j) - steady[t.src[j]]) > 0.01 * steady[t.src[j]], j  # not the steady state
    _, entries = _dictionary(app, board)
    vals = _values(app, entries, 0.5)
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in vals)))
    assert out[0][3:] == ["A", "Y", "S", "1"] and [app.ev.Y[j] for j in sup] == vals


def test_a_start_without_the_values_settles_at_the_tables_settle_nr(tmp_path):
    """Table format 8: a board whose controller never sends the values started them at the observer's estimate; its
    SETTLING lasts the table's settle_nr (the start-error bound with those states' own bounds), not for ever and not
    only settle_s. Values that come later still replace the estimate, and SETTLING then follows settle_s."""
    app, board = rig_app(tmp_path, kind="dynamic_supplied_gains", serial_mode="stream", extra={"frame_ms": 0},
                         table_kw={"settle_s": 30.0, "settle_without_record_s": 90.0})
    t = app.table
    assert t.version == 8 and t.settle_s == 30 and t.settle_nr == 90
    _send(app, board, cmd(b"TC,P,0,6000"))
    _send(app, board, cmd(b"TC,M,1000,0,0"))
    run_cycles(app, board, 105)  # the start after 10 s without the values
    assert not app.unobserved and app.supply == SUPPLY_AWAITED and app.status & SETTLING
    run_cycles(app, board, 400)  # 40 s after the start: past settle_s, not yet settle_nr
    assert app.status & SETTLING
    run_cycles(app, board, 510)  # 91 s after it
    assert app.supply == SUPPLY_AWAITED and not app.status & SETTLING
    _, entries = _dictionary(app, board)
    vals = _values(app, entries, 0.5)
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in vals)))
    assert out[0][3:] == ["A", "Y", "S", "1"] and app.supply == SUPPLY_SET
    run_cycles(app, board, 1)
    assert not app.status & SETTLING


def test_with_the_values_settling_ends_at_settle_s_whatever_settle_nr(tmp_path):
    """The values in time: SETTLING follows settle_s; settle_nr only counts for a start without them."""
    app, board = rig_app(tmp_path, kind="dynamic_supplied_gains", serial_mode="stream", extra={"frame_ms": 0},
                         table_kw={"settle_s": 30.0, "settle_without_record_s": 90.0})
    _send(app, board, cmd(b"TC,P,0,6000"))
    _send(app, board, cmd(b"TC,M,1000,0,0"))
    _, entries = _dictionary(app, board)
    out = _send(app, board, cmd(b"TC,Y," + b",".join(b"%d" % v for v in _values(app, entries, 0.25))))
    assert out[0][3:] == ["A", "Y", "S", "1"]
    run_cycles(app, board, 5)
    assert not app.unobserved and app.status & SETTLING
    run_cycles(app, board, 300)  # 30.5 s after the start
    assert not app.status & SETTLING
