"""Scenario 8: Modbus RTU mode. pymodbus, as the master, polls the firmware over the pty and reads
the same offsets the stream mode emits; malformed requests get the right exception (or, for a
bad CRC, silence, as the Modbus serial line specification requires) and never a crash.
"""
import time

import pytest
import serial

from hil_tests.rig.boards import export, poly_slope_for_run, rig_config

pytestmark = pytest.mark.rig
SENSORS = ["T1", "T2", "T4"]
TEMPS = {"T1": 24.0, "T2": 25.5, "T4": 23.0}
POS = 600000


def crc_modbus(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes((crc & 0xFF, crc >> 8))


def _s16(v):
    return v - 0x10000 if v & 0x8000 else v


def _raw(port, req, expect, wait=5.0):
    """Send one request and read until ``expect`` bytes came back (or ``wait`` s passed): no fixed sleep
    decides the outcome, so a slow machine only makes it slower."""
    with serial.Serial(port, 115200, timeout=0) as s:
        s.reset_input_buffer()
        s.write(req)
        s.flush()
        end = time.monotonic() + wait
        out = b""
        while len(out) < expect and time.monotonic() < end:
            out += s.read(256)
            time.sleep(0.005)
        return out


def _unanswered(port, bad, good, expect_good, wait=5.0):
    """Send ``bad``, then (after a frame gap) ``good``: what comes back must be exactly the answer to
    ``good``, which proves ``bad`` got none, however slow the machine is."""
    with serial.Serial(port, 115200, timeout=0) as s:
        s.reset_input_buffer()
        s.write(bad)
        s.flush()
        time.sleep(0.05)  # > 3.5 character times at 115200 baud: two frames, not one
        s.write(good)
        s.flush()
        end = time.monotonic() + wait
        out = b""
        while len(out) < expect_good and time.monotonic() < end:
            out += s.read(256)
            time.sleep(0.005)
        time.sleep(0.05)
        return out + s.read(256)


def test_modbus_reads_stream_offsets_and_answers_bad_requests(make_rig, demo_run):
    from pymodbus.client import ModbusSerialClient
    table = export(poly_slope_for_run(demo_run, SENSORS, seed=21)).table
    stream = make_rig(rig_config(SENSORS), table, temps=TEMPS)
    stream.send("P", POS)
    stream.run(150000)
    o = [f for f in stream.frames if f.kind == "O"][-1]
    assert o.status & 0xFFFF == 0 and o.pos_um == POS

    rig = make_rig(rig_config(SENSORS, mode="modbus"), table, temps=TEMPS, open_port=False)
    client = ModbusSerialClient(rig.port, baudrate=115200, timeout=1.0, retries=0)
    assert client.connect()
    try:
        with rig.free_run():
            w = client.write_registers(3, [(POS >> 16) & 0xFFFF, POS & 0xFFFF], device_id=1)
            assert not w.isError(), w
        rig.run(150000)
        with rig.free_run():
            rr = client.read_input_registers(0, count=15, device_id=1)
            assert not rr.isError(), rr
            regs = rr.registers
            assert (regs[6] << 16 | regs[7]) == POS
            assert regs[0] == 0  # no sensor fault (status low word)
            # the same offsets as the stream: total and reference offset in 0.1 um, slope in 0.01 um/m
            assert abs(_s16(regs[3]) - round(o.total_um * 10)) <= 1, (regs[3], o.raw)
            assert abs(_s16(regs[4]) - round(float(o.fields[3]) * 10)) <= 1, (regs[4], o.raw)
            assert abs(_s16(regs[5]) - round(float(o.fields[4]) * 100)) <= 2, (regs[5], o.raw)
            # illegal data address: input registers end at 71 (54-71: the supplied lag states, none for this table:
            # docs/protocol.md), and 15 is a hole
            assert client.read_input_registers(54, count=18, device_id=1).registers == [0] * 18
            bad = client.read_input_registers(65, count=10, device_id=1)
            assert bad.isError() and bad.exception_code == 2
            bad = client.read_input_registers(15, count=1, device_id=1)
            assert bad.isError() and bad.exception_code == 2
            bad = client.read_holding_registers(28, count=1, device_id=1)  # 18-19: the spindle speed, 20-27: supplied states
            assert bad.isError() and bad.exception_code == 2
            assert client.read_holding_registers(20, count=8, device_id=1).registers == [0] * 8  # they read 0
            # illegal data value: slew 0 is out of range; half of the position
            bad = client.write_register(1, 0, device_id=1)
            assert bad.isError() and bad.exception_code == 3
            bad = client.write_register(4, 5, device_id=1)
            assert bad.isError() and bad.exception_code == 3
            # changing the output needs the board's key: refused without, accepted with the auth block
            bad = client.write_register(1, 50, device_id=1)
            assert bad.isError() and bad.exception_code == 4
            why = client.read_input_registers(48, count=3, device_id=1).registers
            assert why == [0, 0, 6]  # no counter used; the last refusal: unsigned
            nonce = client.read_input_registers(51, count=2, device_id=1).registers  # the session nonce
            rig.signer.observe(None, nonce[0] << 16 | nonce[1])
            block = rig.signer.modbus_auth(1, 1, [50])
            assert not client.write_registers(8, block, device_id=1).isError()
            assert not client.write_register(1, 50, device_id=1).isError()
            assert client.read_holding_registers(1, count=1, device_id=1).registers == [50]
            assert client.read_input_registers(48, count=3, device_id=1).registers == [0, 1, 0]
            # the same block again (replayed): refused
            assert not client.write_registers(8, block, device_id=1).isError()
            bad = client.write_register(1, 50, device_id=1)
            assert bad.isError() and bad.exception_code == 4
            assert client.read_input_registers(50, count=1, device_id=1).registers == [3]
        client.close()
        with rig.free_run():
            # illegal function (read coils)
            req = bytes((1, 1, 0, 0, 0, 1))
            assert _raw(rig.port, req + crc_modbus(req), 5) == bytes((1, 0x81, 1)) + crc_modbus(bytes((1, 0x81, 1)))
            # quantity 0
            req = bytes((1, 4, 0, 0, 0, 0))
            assert _raw(rig.port, req + crc_modbus(req), 5)[:3] == bytes((1, 0x84, 3))
            req = bytes((1, 4, 0, 3, 0, 1))
            good = req + crc_modbus(req)
            ans = _raw(rig.port, good, 7)
            assert len(ans) == 7 and ans[:3] == bytes((1, 4, 2)) and ans[-2:] == crc_modbus(ans[:-2])
            # bad CRC: discarded silently; the only bytes back are the answer to the next good request
            assert _unanswered(rig.port, good[:-1] + bytes((good[-1] ^ 0x5A,)), good, 7)[:3] == bytes((1, 4, 2))
            assert len(_unanswered(rig.port, good[:-1] + bytes((good[-1] ^ 0x5A,)), good, 7)) == 7
            # another slave's address: not ours, no answer
            req = bytes((7, 4, 0, 3, 0, 1))
            other = _unanswered(rig.port, req + crc_modbus(req), good, 7)
            assert len(other) == 7 and other[:3] == bytes((1, 4, 2))
        assert rig.alive
    finally:
        client.close()
