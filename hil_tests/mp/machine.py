"""``machine`` for the MicroPython unix port inside the HIL rig (on MICROPYPATH before the built-in).

The unix port's own ``machine`` has no SPI, I2C, Pin, UART or WDT. These
return the simulated hardware of the process's ``World``
(hil_tests/sim/world.py), so an unmodified board file such as
firmware/boards/rp2040.py builds its board on simulated chips.
"""

from hil_tests.sim import world as _world


def _w():
    return _world.current()


class Pin:
    """``machine.Pin`` proxy onto the world's pin of that id (a chip-select reaches its chip)."""

    IN = 0
    OUT = 1
    OPEN_DRAIN = 2
    PULL_UP = 1
    PULL_DOWN = 2

    def __init__(self, ident, mode=-1, pull=-1, value=None):
        self._p = _w().pin(ident)
        if value is not None:
            self._p.value(value)

    def init(self, mode=-1, pull=-1, value=None):
        if value is not None:
            self._p.value(value)

    def value(self, v=None):
        return self._p.value(v)

    def on(self):
        self._p.value(1)

    def off(self):
        self._p.value(0)

    def __call__(self, v=None):
        return self._p.value(v)


def SPI(ident=0, baudrate=1000000, polarity=0, phase=0, bits=8, firstbit=0, sck=None, mosi=None, miso=None):
    b = _w().spi(ident)
    b.init(baudrate, polarity, phase, bits)
    return b


def I2C(ident=0, scl=None, sda=None, freq=400000, timeout=50000):
    b = _w().i2c(ident)
    b.init(freq=freq)
    b.timeout = timeout
    return b


def UART(ident=0, baudrate=115200, **kw):
    return _w().make_uart()


def WDT(id=0, timeout=5000):
    return _w().watchdog(timeout)


class _Reset(SystemExit):
    pass


def reset():
    raise _Reset(0x7E)


def soft_reset():
    raise _Reset(0x7E)


def freq(*a):
    return 125000000


def unique_id():
    return b"HILRIG01"


def idle():
    pass
