"""Modbus RTU slave: CRC, register map, writes, exceptions, ignored frames."""
import struct

import pytest
from hypothesis import given, strategies as st

from fwhelpers import rig_app, run_cycles
from firmware.crc16 import crc16_modbus
from firmware import wire as stw


def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])


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


def regs(out):
    n = out[2] // 2
    return list(struct.unpack(">%dH" % n, out[3:3 + 2 * n]))


def s16(v):
    return v - 65536 if v > 32767 else v


def test_read_input_registers(dev):
    app, board = dev
    out = ask(app, board, rtu(bytes([1, 4, 0, 0, 0, 48])))
    assert out[:3] == bytes([1, 4, 96])
    r = regs(out)
    assert r[0] == app.status & 0xFFFF and r[1] == app.status >> 16
    assert r[2] == app.cycles & 0xFFFF
    assert s16(r[3]) == round(app.total / 10) and s16(r[4]) == round(app.ref_out / 10)
    assert s16(r[5]) == app.slope_out
    assert (r[10] << 16 | r[11]) == app.table.crc and r[12] == 1 and r[13] == 11
    for i in range(11):
        assert abs(s16(r[16 + i]) - (2000 + 100 * i)) <= 4  # 0.01 degC
    assert r[27:32] == [0x8000] * 5  # unused channels read as "no value"


def test_write_position_and_enable(dev):
    app, board = dev
    pos = -123456
    hi, lo = (pos >> 16) & 0xFFFF, pos & 0xFFFF
    out = ask(app, board, rtu(bytes([1, 16, 0, 3, 0, 2, 4]) + struct.pack(">HH", hi, lo)))
    assert out[:6] == bytes([1, 16, 0, 3, 0, 2])
    assert app.pos == pos and app.have_pos
    r = regs(ask(app, board, rtu(bytes([1, 3, 0, 0, 0, 7]))))
    assert r[:5] == [1, 5, 0, hi, lo]
    out = ask(app, board, rtu(bytes([1, 6, 0, 0, 0, 0])))
    assert out == rtu(bytes([1, 6, 0, 0, 0, 0]))
    assert not app.enabled
    run_cycles(app, board, 1)
    assert app.status & stw.DISABLED
    ask(app, board, rtu(bytes([1, 6, 0, 1, 0, 50])))
    assert app.limiter.rate == 5000


@pytest.mark.parametrize("req, code", [
    (bytes([1, 5, 0, 0, 0xFF, 0]), 1),  # write coil: illegal function
    (bytes([1, 43, 14, 1, 0]), 1),  # device identification: not implemented
    (bytes([1, 4, 0, 40, 0, 9]), 2),  # beyond the input map
    (bytes([1, 3, 0, 8, 0, 1]), 2),  # beyond the holding map
    (bytes([1, 6, 0, 7, 0, 2]), 3),  # latch takes 1 (or 0: nothing)
    (bytes([1, 6, 0, 7, 0, 1]), 4),  # latch: the table has fixed references
    (bytes([1, 6, 0, 9, 0, 1]), 2),
    (bytes([1, 4, 0, 0, 0, 0]), 3),  # zero quantity
    (bytes([1, 4, 0, 0, 0, 126]), 3),  # too many
    (bytes([1, 6, 0, 0, 0, 2]), 3),  # enable must be 0/1
    (bytes([1, 6, 0, 1, 0, 0]), 3),  # slew 0
    (bytes([1, 16, 0, 0, 0, 2, 3, 0, 1, 0]), 3),  # byte count mismatch
    (bytes([1, 16, 0, 3, 0, 2, 4, 0x7F, 0, 0, 0]), 3),  # position beyond 100 m
])
def test_exceptions(dev, req, code):
    app, board = dev
    before = (list(app.link.hold), app.pos, app.enabled, app.slew)
    out = ask(app, board, rtu(req))
    assert out == rtu(bytes([1, req[1] | 0x80, code]))
    assert (list(app.link.hold), app.pos, app.enabled, app.slew) == before


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
    assert ask(app, board, rtu(bytes([0, 6, 0, 0, 0, 0]))) == b""  # broadcast: acts silently
    assert not app.enabled
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
