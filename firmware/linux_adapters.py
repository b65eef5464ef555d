"""CPython adapters that give Linux devices the MicroPython bus signatures.

Drivers in firmware/ call only the ``machine.SPI`` / ``machine.I2C`` methods
listed in ``firmware.board``; these small classes map them onto Linux:

- ``SMBusI2C(smbus)``: an ``smbus2.SMBus`` (or anything with its methods, such
  as the HIL rig's simulated bus) as a ``machine.I2C``;
- ``SpidevSPI(path)``: a /dev/spidevB.C node via the spidev ioctl, as a
  ``machine.SPI`` (no extra package needed);
- ``SysfsPin(n)``: a GPIO output through /sys/class/gpio, for boards that wire
  MAX31865 chip-selects to GPIOs; ``NullPin`` when the kernel drives CS;
- ``SerialPort(serial.Serial)``: pyserial as the non-blocking ``serial`` (a device path or any
  pySerial URL: ``socket://``, ``spy://``, ``loop://``).

CPython only (not part of the MicroPython image).
"""

import os

import time

from firmware.board import Board


class MonotonicClock:
    """CPython's monotonic clock in the MicroPython ticks interface (never wraps)."""

    def ticks_ms(self):
        return time.monotonic_ns() // 1000000

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, ms):
        if ms > 0:
            time.sleep(ms / 1000)


class SMBusI2C:
    """``machine.I2C`` methods on top of an ``smbus2.SMBus``-like object."""

    def __init__(self, smbus):
        self._bus = smbus

    def writeto(self, addr, buf):
        if len(buf) == 1:
            self._bus.write_byte(addr, buf[0])
        else:
            self._bus.write_i2c_block_data(addr, buf[0], list(buf[1:]))
        return 1

    def readfrom_mem_into(self, addr, memaddr, buf):
        data = self._bus.read_i2c_block_data(addr, memaddr, len(buf))
        if len(data) != len(buf):
            raise OSError(5, "short I2C read from 0x%02x" % addr)
        for i in range(len(buf)):
            buf[i] = data[i]

    def writeto_mem(self, addr, memaddr, buf):
        if len(buf) == 1:
            self._bus.write_byte_data(addr, memaddr, buf[0])
        else:
            self._bus.write_i2c_block_data(addr, memaddr, list(buf))


# linux/spi/spidev.h: _IOW('k', nr, size)
def _iow(nr, size):
    return (1 << 30) | (size << 16) | (ord("k") << 8) | nr


_SPI_IOC_MESSAGE_1 = _iow(0, 32)
_SPI_IOC_WR_MODE = _iow(1, 1)
_SPI_IOC_WR_MAX_SPEED_HZ = _iow(4, 4)


class SpidevSPI:
    """``machine.SPI`` ``write``/``write_readinto`` on a Linux spidev node.

    One call is one transfer with chip-select held for its whole length, which
    is what the MAX31865 driver relies on.
    """

    def __init__(self, path, baudrate=1000000, mode=1):
        import fcntl
        import struct
        self._fcntl = fcntl
        self._struct = struct
        self._fd = os.open(path, os.O_RDWR)
        self._speed = baudrate
        fcntl.ioctl(self._fd, _SPI_IOC_WR_MODE, struct.pack("B", mode))
        fcntl.ioctl(self._fd, _SPI_IOC_WR_MAX_SPEED_HZ, struct.pack("I", baudrate))

    def _transfer(self, tx, rx):
        import ctypes
        n = len(tx)
        txb = (ctypes.c_uint8 * n).from_buffer_copy(bytes(tx))
        rxb = (ctypes.c_uint8 * n)()
        xfer = self._struct.pack("QQIIHBBBBBB", ctypes.addressof(txb), ctypes.addressof(rxb),
                                 n, self._speed, 0, 8, 0, 0, 0, 0, 0)
        self._fcntl.ioctl(self._fd, _SPI_IOC_MESSAGE_1, xfer)
        if rx is not None:
            rx[:n] = bytes(rxb)

    def write(self, buf):
        self._transfer(buf, None)

    def write_readinto(self, wbuf, rbuf):
        self._transfer(wbuf, rbuf)

    def close(self):
        os.close(self._fd)


class NullPin:
    """Chip-select handled by the bus (spidev drives CS itself)."""

    def value(self, v=None):
        return 1


class SysfsPin:
    """GPIO output via /sys/class/gpio (exported on first use), idle high."""

    def __init__(self, n):
        base = "/sys/class/gpio/gpio%d" % n
        if not os.path.exists(base):
            with open("/sys/class/gpio/export", "w") as f:
                f.write(str(n))
        with open(base + "/direction", "w") as f:
            f.write("high")
        self._fd = os.open(base + "/value", os.O_WRONLY)

    def value(self, v=None):
        if v is not None:
            os.write(self._fd, b"1" if v else b"0")


class SerialPort:
    """pyserial port (``serial_for_url(..., timeout=0)``) as the board's serial."""

    def __init__(self, ser):
        self._s = ser

    def readinto(self, buf):
        return self._s.readinto(buf)

    def write(self, buf, n):
        return self._s.write(memoryview(buf)[:n])


def make_linux_board(config, port):
    """Board for CPython on Linux: bus names are device paths in ``config``."""
    import serial
    import smbus2

    buses = {}
    for ch in config["channels"]:
        path = ch["bus"]
        if path in buses:
            continue
        if ch["driver"] == "max31865":
            buses[path] = SpidevSPI(path)
        else:
            num = int(path.rsplit("-", 1)[1])
            buses[path] = SMBusI2C(smbus2.SMBus(num))

    def pin(cs):
        return NullPin() if cs is None else SysfsPin(cs)

    baud = (config.get("serial") or {}).get("baud", 115200)
    ser = SerialPort(serial.serial_for_url(port, baud, timeout=0))  # a device path or a pySerial URL
    return Board(config, buses, pin, ser, clock=MonotonicClock(), watchdog=None, reset=None)
