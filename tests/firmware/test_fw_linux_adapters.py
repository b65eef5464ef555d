"""CPython adapters: smbus2-style bus as machine.I2C, pyserial as the board serial, the Linux board."""
import pytest

from fwfakes import FakeADS122C04
from firmware.linux_adapters import SMBusI2C, SerialPort, MonotonicClock, NullPin
from firmware import ads122c04 as ads, rtd


class FakeSMBus:
    """The smbus2.SMBus methods SMBusI2C uses, in front of a fake ADS122C04."""

    def __init__(self, dev, addr=0x40):
        self.dev, self.addr, self.calls = dev, addr, []

    def _check(self, addr):
        if addr != self.addr or not self.dev.present:
            raise OSError(121, "Remote I/O error")  # what smbus2 raises on a NAK

    def write_byte(self, addr, value):
        self._check(addr)
        self.calls.append("write_byte")
        self.dev.command(value)

    def write_byte_data(self, addr, reg, value):
        self._check(addr)
        self.calls.append("write_byte_data")
        self.dev.write(reg, bytes([value]))

    def write_i2c_block_data(self, addr, reg, data):
        self._check(addr)
        self.dev.write(reg, bytes(data))

    def read_i2c_block_data(self, addr, reg, n):
        self._check(addr)
        self.calls.append("read_i2c_block_data")
        buf = bytearray(n)
        self.dev.read(reg, buf)
        return list(buf)


def test_ads122c04_through_smbus_adapter():
    dev = FakeADS122C04()
    dev.set_temperature(42.0)
    bus = FakeSMBus(dev)
    d = ads.ADS122C04(SMBusI2C(bus), 0x40, rref_mohm=1620000, wires=3, idac_ua=500)
    assert dev.started and {"write_byte", "write_byte_data", "read_i2c_block_data"} <= set(bus.calls)
    assert d.data_ready
    assert abs(rtd.temperature_mC(d.ratio(d.read_data())) - 42000) <= 3
    dev.present = False
    with pytest.raises(OSError):
        d.read_data()


class FakePySerial:
    def __init__(self):
        self.rx = bytearray(b"$TC,S*56EA\r\n")
        self.tx = b""

    def readinto(self, b):  # pyserial with timeout=0 returns what is waiting
        n = min(len(b), len(self.rx))
        b[:n] = self.rx[:n]
        del self.rx[:n]
        return n

    def write(self, data):
        self.tx += bytes(data)
        return len(data)


def test_serial_adapter_writes_first_n_bytes():
    s = FakePySerial()
    port = SerialPort(s)
    buf = bytearray(b"hello world")
    assert port.write(buf, 5) == 5 and s.tx == b"hello"
    rx = bytearray(8)
    assert port.readinto(rx) == 8 and bytes(rx) == b"$TC,S*56"
    assert port.readinto(rx) == 4
    assert port.readinto(rx) == 0


def test_clock_and_null_pin():
    c = MonotonicClock()
    a = c.ticks_ms()
    c.sleep_ms(2)
    assert c.ticks_diff(c.ticks_ms(), a) >= 2
    assert NullPin().value(0) == 1


def test_app_runs_on_cpython_adapters(tmp_path):
    """A whole App on the Linux adapters: the ADS122C04 behind SMBusI2C, pyserial behind SerialPort."""
    from fwhelpers import make_table
    from firmware.board import Board
    from firmware.app import App
    from fwfakes import FakeClock
    dev = FakeADS122C04()
    dev.set_temperature(25.0)
    (tmp_path / "table_a.bin").write_bytes(make_table(kind="linear_direct", sensors=["T1"]))
    cfg = {"channels": [{"name": "T1", "driver": "ads122c04", "bus": "/dev/i2c-1", "address": 0x40,
                         "rref_mohm": 1620000, "idac_ua": 500}], "table_dir": str(tmp_path), "frame_ms": 100}
    ser = FakePySerial()
    board = Board(cfg, {"/dev/i2c-1": SMBusI2C(FakeSMBus(dev))}, lambda cs: NullPin(), SerialPort(ser),
                  FakeClock(0))
    app = App(board)
    app.run(max_cycles=10)
    assert app.channels.good[0] and abs(app.channels.temp[0] - 25000) <= 3
    lines = ser.tx.split(b"\r\n")
    assert lines[0].startswith(b"$TC,0,") and b",H,2," in lines[0]
    assert b",T," in lines[1] and b",!40" in lines[1]  # asked before the first good reading
    ser.rx += b"$TC,S*56EA\r\n"
    app.run(max_cycles=12)
    assert any(b",T," in ln and b",25.00" in ln for ln in ser.tx.split(b"\r\n")[2:])


def test_spidev_adapter_ioctl_layout(monkeypatch):
    """SpidevSPI against a fake kernel: ioctl numbers of linux/spi/spidev.h and the
    32-byte spi_ioc_transfer, with the reply copied into the caller's buffer."""
    import ctypes
    import fcntl
    import os
    import struct
    from firmware import linux_adapters as bl
    calls = []

    def ioctl(fd, req, arg):
        calls.append((req, arg))
        if req == 0x40206B00:  # SPI_IOC_MESSAGE(1)
            tx, rx, n, speed, delay, bits, cs_change = struct.unpack("QQIIHBB", arg[:28])
            assert len(arg) == 32 and bits == 8
            sent = ctypes.string_at(tx, n)
            reply = bytes([0xFF]) + bytes(b ^ 0x5A for b in sent[1:])
            ctypes.memmove(rx, reply, n)
        return 0

    monkeypatch.setattr(os, "open", lambda path, flags: 99)
    monkeypatch.setattr(fcntl, "ioctl", ioctl)
    spi = bl.SpidevSPI("/dev/spidev0.0", baudrate=2000000, mode=1)
    assert calls[0] == (0x40016B01, struct.pack("B", 1))  # SPI_IOC_WR_MODE
    assert calls[1] == (0x40046B04, struct.pack("I", 2000000))  # SPI_IOC_WR_MAX_SPEED_HZ
    rx = bytearray(3)
    spi.write_readinto(bytearray([0x01, 0x00, 0x33]), rx)
    assert rx == bytearray([0xFF, 0x5A, 0x69])
    spi.write(bytearray([0x80, 0xC1]))
    assert struct.unpack("QQI", calls[-1][1][:20])[2] == 2
