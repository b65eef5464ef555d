"""Modbus RTU slave: CRC, register map, writes, exceptions, ignored frames."""
import struct

from firmware.wire import IR_ERROR_REF, N_INPUT

import pytest
from hypothesis import given, settings, strategies as st

from fwhelpers import modbus_auth_block, rig_app, run_cycles
from firmware.crc16 import crc16_modbus
from firmware import wire as stw


def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


@settings(deadline=None)  # the first example imports pymodbus
@given(st.binary(max_size=64))
def test_crc_matches_pymodbus(data):
    from pymodbus.framer import FramerRTU
    c = crc16_modbus(data)
    assert FramerRTU.compute_CRC(data) == ((c & 0xFF) << 8) | (c >> 8)  # pymodbus gives wire order


@pytest.fixture
def dev(tmp_path):
    app, board = rig_app(tmp_path, serial_mode="modbus", extra={"frame_ms": 0})
    run_cycles(app, board, 200)
    board.serial.take()
    return app, board


def ask(app, board, req, wait=True):
    board.serial.feed(req)
    app.link.poll(board.clock.t)
    if wait:
        board.clock.t += 5
        app.link.poll(board.clock.t)
    out = board.serial.take()
    if out:
        assert crc16_modbus(out[:-2]) == out[-2] | (out[-1] << 8)
    return out


def signed(app, board, req):
    """``req`` (no CRC) preceded by the auth block that authorises it; the reply to ``req``."""
    block = modbus_auth_block(app, req)
    assert ask(app, board, rtu(block)) == rtu(block[:6])
    return ask(app, board, rtu(req))


def regs(out):
    n = out[2] // 2
    return list(struct.unpack(">%dH" % n, out[3:3 + 2 * n]))


def s16(v):
    return v - 65536 if v > 32767 else v


def test_read_input_registers(dev):
    app, board = dev
    out = ask(app, board, rtu(bytes([1, 4, 0, 0, 0, 15])))
    assert out[:3] == bytes([1, 4, 30])
    r = regs(out) + [None] + regs(ask(app, board, rtu(bytes([1, 4, 0, 16, 0, 35]))))
    assert r[0] == app.status & 0xFFFF and r[1] == app.status >> 16
    assert r[2] == app.cycles & 0xFFFF
    assert s16(r[3]) == round(app.total / 10) and s16(r[4]) == round(app.ref_out / 10)
    assert s16(r[5]) == app.slope_out
    assert (r[10] << 16 | r[11]) == app.table.crc and r[12] == 1 and r[13] == 11
    for i in range(11):
        assert abs(s16(r[16 + i]) - (2000 + 100 * i)) <= 4  # 0.01 degC
    assert r[27:32] == [0x8000] * 5  # unused channels read as "no value"
    assert r[48:51] == [0, 0, 0]  # authorisation: last counter 0, no refusal yet
    assert regs(ask(app, board, rtu(bytes([1, 4, 0, IR_ERROR_REF, 0, 1])))) == [0]  # error reference: start (the rig's table)


def test_error_reference_register_names_the_tables_sensor(dev):
    """Input register IR_ERROR_REF (53, after the session nonce): 1 + i for a table whose model was fitted on errors
    corrected to sensor i (byte 58)."""
    app, board = dev
    app.table.error_ref = 3
    assert regs(ask(app, board, rtu(bytes([1, 4, 0, IR_ERROR_REF, 0, 1])))) == [3]
    # after it, the supplied lag states' registers (IR_SUPPLY_STATE, table format 7): none for this table
    assert regs(ask(app, board, rtu(bytes([1, 4, 0, IR_ERROR_REF, 0, 3])))) == [3, 0, 0]
    assert ask(app, board, rtu(bytes([1, 4, 0, N_INPUT - 1, 0, 2])))[1] == 0x84  # beyond the map nothing is mapped


def test_write_position_and_enable(dev):
    app, board = dev
    pos = -123456
    hi, lo = (pos >> 16) & 0xFFFF, pos & 0xFFFF
    out = ask(app, board, rtu(bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">HH", hi, lo)))
    assert out[:6] == bytes([1, 16, 0, 3, 0, 2])
    assert app.pos == pos and app.have_pos
    r = regs(ask(app, board, rtu(bytes([1, 3, 0, 0, 0, 7]))))
    assert r[:5] == [1, 5, 0, hi, lo]
    out = signed(app, board, bytes([1, 6, 0, 0, 0, 0]))
    assert out == rtu(bytes([1, 6, 0, 0, 0, 0]))
    assert not app.enabled
    run_cycles(app, board, 1)
    assert app.status & stw.DISABLED
    assert signed(app, board, bytes([1, 6, 0, 1, 0, 50])) == rtu(bytes([1, 6, 0, 1, 0, 50]))
    assert app.limiter.rate == 5000
    assert regs(ask(app, board, rtu(bytes([1, 4, 0, 48, 0, 3])))) == [0, 2, 0]  # two counters used


@pytest.mark.parametrize("req, code", [
    (bytes([1, 5, 0, 0, 0xFF, 0]), 1),  # write coil: illegal function
    (bytes([1, 43, 14, 1, 0]), 1),  # device identification: not implemented
    (bytes([1, 4, 0, N_INPUT - 8, 0, 9]), 2),  # beyond the input map
    (bytes([1, 4, 0, 15, 0, 1]), 2),  # the unmapped input register
    (bytes([1, 4, 0, 10, 0, 6]), 2),  # a range over it
    (bytes([1, 3, 0, 28, 0, 1]), 2),  # beyond the holding map (18-19: the spindle speed, 20-27: supplied lag states)
    (bytes([1, 16, 0, 20, 0, 2, 4, 0, 0, 0, 1]), 4),  # supplied lag states: this table has none
    (bytes([1, 16, 0, 20, 0, 1, 2, 0, 1]), 3),  # half of a supplied state
    (bytes([1, 6, 0, 7, 0, 2]), 3),  # latch takes 1 (or 0: nothing)
    (bytes([1, 6, 0, 7, 0, 1]), 4),  # latch: the table has fixed references
    (bytes([1, 6, 0, 28, 0, 1]), 2),
    (bytes([1, 6, 0, 20, 0, 1]), 3),  # half of a supplied state
    (bytes([1, 6, 0, 18, 0, 1]), 3),  # half of the spindle speed
    (bytes([1, 6, 0, 9, 0, 1]), 3),  # the auth block is written whole
    (bytes([1, 16, 0, 8, 0, 2, 4, 0, 0, 0, 1]), 3),
    (bytes([1, 6, 0, 3, 0, 5]), 3),  # half of the position: never combined with a stale half
    (bytes([1, 6, 0, 4, 0, 5]), 3),
    (bytes([1, 6, 0, 5, 0, 5]), 3),  # half of the reference
    (bytes([1, 16, 0, 4, 0, 1, 2, 0, 5]), 3),
    (bytes([1, 16, 0, 4, 0, 2, 4, 0, 5, 0, 0]), 3),  # position low half + reference high half
    (bytes([1, 6, 0, 0, 0, 0]), 4),  # disable: not authorised
    (bytes([1, 6, 0, 1, 0, 50]), 4),  # slew: not authorised
    (bytes([1, 6, 0, 2, 0, 50]), 4),  # link timeout: not authorised
    (bytes([1, 16, 0, 0, 0, 2, 4, 0, 1, 0, 50]), 4),
    (bytes([1, 4, 0, 0, 0, 0]), 3),  # zero quantity
    (bytes([1, 4, 0, 0, 0, 126]), 3),  # too many
    (bytes([1, 6, 0, 0, 0, 2]), 3),  # enable must be 0/1
    (bytes([1, 6, 0, 1, 0, 0]), 3),  # slew 0
    (bytes([1, 16, 0, 0, 0, 2, 3, 0, 1, 0]), 3),  # byte count mismatch
    (bytes([1, 16, 0, 3, 0, 2, 4, 0x7F, 0, 0, 0]), 3),  # position beyond 100 m
    (bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">i", 100000001), 3),  # the stream's limit, + 1 um
    (bytes([1, 16, 0, 5, 0, 2, 4]) + struct.pack(">i", -100000001), 3),
])
def test_exceptions(dev, req, code):
    app, board = dev
    before = (list(app.link.hold), app.pos, app.enabled, app.slew)
    out = ask(app, board, rtu(req))
    assert out == rtu(bytes([1, req[1] | 0x80, code]))
    assert (list(app.link.hold), app.pos, app.enabled, app.slew) == before


@pytest.mark.parametrize("pos", [100000000, -100000000, 0, -1, 65535, -65536])
def test_position_range_is_the_streams(dev, pos):
    app, board = dev
    req = bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">i", pos)
    assert ask(app, board, rtu(req)) == rtu(req[:6])
    assert app.pos == pos

def test_multi_write_is_atomic(dev):
    app, board = dev
    # enable=0 valid, slew=0 invalid: nothing may change
    out = ask(app, board, rtu(bytes([1, 16, 0, 0, 0, 2, 4, 0, 0, 0, 0])))
    assert out[1] == 0x90 and app.enabled and app.link.hold[0] == 1


def test_bad_crc_other_address_and_broadcast(dev):
    app, board = dev
    req = bytearray(rtu(bytes([1, 4, 0, 0, 0, 2])))
    req[-1] ^= 0xFF
    assert ask(app, board, bytes(req)) == b""  # bad CRC: no reply (Modbus spec)
    assert ask(app, board, rtu(bytes([7, 4, 0, 0, 0, 2]))) == b""  # not us
    before = (list(app.link.hold), app.pos, app.enabled, app.slew)
    assert ask(app, board, rtu(bytes([0, 6, 0, 0, 0, 0]))) == b""  # broadcast write: refused, silently
    assert ask(app, board, rtu(bytes([0, 16, 0, 3, 0, 2, 4, 0, 0, 0, 9]))) == b""
    block = modbus_auth_block(app, bytes([1, 6, 0, 0, 0, 0]))
    assert ask(app, board, rtu(bytes([0]) + block[1:])) == b""  # even with a valid auth block
    assert ask(app, board, rtu(bytes([0, 6, 0, 0, 0, 0]))) == b""
    assert (list(app.link.hold), app.pos, app.enabled, app.slew) == before
    # after garbage the next good request is still answered
    assert ask(app, board, rtu(bytes([1, 4, 0, 2, 0, 1])))[:3] == bytes([1, 4, 2])


def test_request_split_across_polls(dev):
    app, board = dev
    req = rtu(bytes([1, 4, 0, 0, 0, 3]))
    board.serial.feed(req[:3])
    app.link.poll(board.clock.t)
    board.serial.feed(req[3:])
    app.link.poll(board.clock.t)
    out = board.serial.take()
    assert out[:3] == bytes([1, 4, 6])
