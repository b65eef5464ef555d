"""The board with a dynamic table: spindle speed and feed reach the filters from the stream (P, M)
and from Modbus (holding registers 18-19), the filters step on the table's dt_ms from the cold
start, and the inputs need no authorisation, as the position does not."""
import pytest

from fwhelpers import cmd, frames, rig_app, run_cycles
from firmware.crc16 import crc16_modbus


def _dyn_app(tmp_path, mode="stream"):
    app, board = rig_app(tmp_path, kind="dynamic", serial_mode=mode, extra={"frame_ms": 0})
    run_cycles(app, board, 30)  # channels good, references latched
    board.serial.take()
    assert app.table.kind == "dynamic" and app.ref_state != 0 and not app.unlatched
    return app, board


def _send(app, board, line):
    board.serial.feed(line)
    app.link.poll(board.clock.t)
    return frames(board.serial.take())


def test_stream_p_carries_the_spindle_speed(tmp_path):
    app, board = _dyn_app(tmp_path)
    assert _send(app, board, cmd(b"TC,P,125000,8000")) == []  # like P: no answer
    assert app.pos == 125000 and app.spindle == 8000 and app.ev.spin == 8000
    assert _send(app, board, cmd(b"TC,P,126000")) == []  # the old line: the speed stays
    assert app.pos == 126000 and app.spindle == 8000
    _send(app, board, cmd(b"TC,P,126000,-3000"))  # M4: the magnitude is the heat source
    assert app.ev.spin == 3000
    for bad, code in ((b"TC,P,1,1000001", "4"), (b"TC,P,1,x", "4"), (b"TC,Q,1,5", "2"), (b"TC,P,1,2,3", "2")):
        out = _send(app, board, cmd(bad))
        assert out and out[0][3] == "E" and out[0][4] == code, (bad, out)
    assert app.spindle == -3000


def test_spindle_speed_moves_the_output_through_the_filters(tmp_path):
    """Two boards, the same temperatures: one reports the spindle running. The filters (1 s step) take it in."""
    outs = []
    for rpm, sub in ((0, "a"), (12000, "b")):
        (tmp_path / sub).mkdir()
        app, board = _dyn_app(tmp_path / sub)
        _send(app, board, cmd(b"TC,P,0,%d" % rpm))
        _send(app, board, cmd(b"TC,M,4000,0,0"))
        y0 = list(app.ev.Y)
        run_cycles(app, board, 600)  # 60 s: 60 filter steps
        steps = [y != y0j for y, y0j in zip(app.ev.Y, y0)]
        outs.append((app.ev.offset_at(0), steps, app.ev.fin))
    assert outs[0][2] == outs[1][2] == 4000
    assert outs[0][0] != outs[1][0]
    assert outs[1][1][3] and outs[1][1][4]  # the spindle terms' states moved


def test_m_sets_the_feed_of_a_dynamic_table(tmp_path):
    app, board = _dyn_app(tmp_path)
    out = _send(app, board, cmd(b"TC,M,2500,0,100000"))
    assert out[0][3] == "A" and out[0][4] == "M" and app.ev.fin == 2500
    _send(app, board, cmd(b"TC,M,0,0,0"))
    assert app.ev.fin == 0


def test_latch_restarts_filters_and_step_phase(tmp_path):
    from fwhelpers import scmd
    app, board = _dyn_app(tmp_path)
    _send(app, board, cmd(b"TC,P,0,12000"))
    run_cycles(app, board, 105)
    assert any(app.ev.Y[j] for j in range(app.table.nf) if app.table.A[j])
    out = _send(app, board, scmd(app, "L"))
    assert out[0][3] == "A", out
    assert all(app.ev.Y[j] == 0 for j in range(app.table.nf) if app.table.A[j]) and app.step_ms == 0


def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


def _ask(app, board, req):
    board.serial.feed(rtu(req))
    app.link.poll(board.clock.t)
    board.clock.t += 5
    app.link.poll(board.clock.t)
    return board.serial.take()


def test_modbus_spindle_register_pair(tmp_path):
    app, board = _dyn_app(tmp_path, "modbus")
    rpm = 70000  # beyond 16 bits: the pair, high word first
    out = _ask(app, board, bytes([1, 16, 0, 18, 0, 2, 4, rpm >> 24, (rpm >> 16) & 255, (rpm >> 8) & 255, rpm & 255]))
    assert out[:6] == bytes([1, 16, 0, 18, 0, 2]), out  # written without an auth block: an input, like the position
    assert app.spindle == 70000 and app.ev.spin == 70000
    out = _ask(app, board, bytes([1, 3, 0, 18, 0, 2]))
    assert out[:7] == bytes([1, 3, 4, 0, 1, (rpm >> 8) & 255, rpm & 255])
    neg = (-1500) & 0xFFFFFFFF
    _ask(app, board, bytes([1, 16, 0, 18, 0, 2, 4, neg >> 24, (neg >> 16) & 255, (neg >> 8) & 255, neg & 255]))
    assert app.spindle == -1500 and app.ev.spin == 1500
    # half the pair, out of range, or spanning the auth block: refused, nothing changes
    for req in (bytes([1, 6, 0, 18, 0, 1]), bytes([1, 16, 0, 19, 0, 1, 2, 0, 1]),
                bytes([1, 16, 0, 18, 0, 2, 4, 0, 0x0F, 0x42, 0x41]), bytes([1, 16, 0, 17, 0, 3, 6, 0, 0, 0, 0, 0, 1])):
        out = _ask(app, board, req)
        assert out[1] & 0x80 and out[2] == 3, (req, out)
    assert app.spindle == -1500
    out = _ask(app, board, bytes([1, 3, 0, 28, 0, 1]))
    assert out[1] == 0x83 and out[2] == 2  # past the map (20-27: the supplied lag states, which read 0)
    assert _ask(app, board, bytes([1, 3, 0, 20, 0, 2]))[3:7] == bytes(4)


def test_accept_refuses_a_dynamic_table_beyond_its_certificate(tmp_path):
    """The board's cheap certificate check puts the filter states at the ends of their boxes."""
    import struct
    import zlib
    from fwhelpers import dynamic_table
    from firmware.table import parse_table, TableError, HEADER_SIZE, NAME_SIZE, SENSOR_SIZE
    names = ["T%d" % i for i in range(1, 12)]
    good = dynamic_table(names)
    t = parse_table(good)
    b = bytearray(good)
    # the bY list: after COMMON, the 16-word head and 8 lists of nf words (src A shA gA rA fy Ylo Yhi)
    off = HEADER_SIZE + (NAME_SIZE + SENSOR_SIZE) * t.n_sensors + 4 * (8 + 3 * t.n_sensors + 1 + 16 + 8 * t.nf)
    assert struct.unpack_from("<i", b, off)[0] == t.bY[0]
    struct.pack_into("<i", b, off, t.bY[0] * 1000)
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    (tmp_path / "table_a.bin").write_bytes(bytes(b))
    app, board = rig_app(tmp_path, table=False, serial_mode="stream", extra={"frame_ms": 0})
    assert app.table is None
    with pytest.raises(TableError) as e:
        app._accept(parse_table(bytes(b)))
    assert e.value.reason == "certificate"
    app._accept(parse_table(good))


def test_observer_estimates_at_the_first_all_good_cycle_and_settling_lasts_settle_s(tmp_path):
    """A table with an observer (issue 21; fixed references, settle_s 20 s) that reads the spindle speed: its lag
    states stay unset until the first cycle in which every sensor it needs reads good and the controller has sent
    the spindle speed (P,<pos>,<rpm>; a P without it does not do), are then estimated from the inputs (a warm machine: not the
    rest state 0), and SETTLING is raised from boot until 20 s after the estimate."""
    from firmware.evaluate import Evaluator
    from firmware.wire import SETTLING
    app, board = rig_app(tmp_path, kind="dynamic_observer", serial_mode="stream", extra={"frame_ms": 0},
                         table_kw={"settle_s": 20.0})
    t = app.table
    assert t.obs == 1 and t.settle_s == 20 and t.ref_mode == 0 and app.unobserved and app.obs_link == 2
    lag = [j for j in range(t.nf) if t.A[j]]
    run_cycles(app, board, 40)  # the sensors read good, no position report yet: nothing estimated (the filters run
    assert all(app.channels.good[i] for i in app.map) and app.unobserved  # from rest meanwhile, as without an observer)
    assert app.status & SETTLING
    _send(app, board, cmd(b"TC,P,0"))  # the position alone: the speed is still unknown
    run_cycles(app, board, 3)
    assert app.unobserved
    _send(app, board, cmd(b"TC,P,0,6000"))
    run_cycles(app, board, 1)
    assert not app.unobserved and app.ev.spin == 6000
    est = list(app.ev.Y)
    # the estimate is the table's: a fresh evaluator on the same inputs gives the same states
    ev = Evaluator(t)
    ev.temps[:] = app.ev.temps
    ev.set_spindle(6000)
    ev.set_feed_rate(app.feed)
    ev.update()
    ev.observe()
    assert ev.Y == est and any(est[j] for j in lag)
    assert app.step_ms == 100  # the step phase restarts at the estimate's cycle, as at a latch (firmware App._latch)
    run_cycles(app, board, 198)  # 19.9 s after the estimate
    assert app.status & SETTLING
    run_cycles(app, board, 2)
    assert not app.status & SETTLING


def test_table_without_observer_never_settles(tmp_path):
    from firmware.wire import SETTLING
    app, board = _dyn_app(tmp_path)
    assert not app.table.obs and not app.status & SETTLING
