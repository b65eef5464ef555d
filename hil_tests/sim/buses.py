"""Simulated SPI and I2C buses with the method signatures the firmware calls, and fault injection.

``SPIBus`` and ``Pin`` have the ``machine.SPI`` / ``machine.Pin`` methods;
``I2CBus`` the ``machine.I2C`` ones; ``SMBus`` the ``smbus2.SMBus`` ones the
CPython board adapter (firmware.linux_adapters.SMBusI2C) uses. Chips are found
by chip-select (SPI: every chip whose CS pin is low takes part; two at once
is bus contention, MISO reads the AND of both) or by 7-bit address (I2C).

Faults (``inject(kind, count, target)``), applied to the next ``count``
transfers (-1: until cleared) to ``target`` (a CS pin id or I2C address;
None: every transfer on the bus):

- ``eio``: the transfer fails with OSError(EIO) (I2C NAK, SPI DMA error);
- ``etimedout``: OSError(ETIMEDOUT) after the bus timeout has elapsed;
- ``corrupt``: one bit of the received data flipped (noise on MISO/SDA);
- ``miso00`` / ``misoff``: MISO / SDA stuck low / high (every read byte 00h / FFh).

A chip that is absent (``chip.present = False``) NAKs on I2C
(OSError(ENODEV)) and leaves MISO floating on SPI (the pull-up reads FFh),
exactly as the hardware does: SPI has no acknowledge.
Each transfer advances the simulated clock by its time on the wire.

The chips' work runs with the heap unlocked (``HEAP_LOCKED``): the DUT locks the heap around the
firmware's cycle (hil_tests/rig/dut.py, ``lock``) to prove that the firmware allocates nothing; the
simulated chips stand for hardware, and on a 32-bit port their arithmetic (micro-ohms times 2**15,
ADC codes times 2**23) passes the small ints (2**30) and allocates.
"""

from hil_tests.sim.rng import XorShift32

try:
    import micropython as _micropython
except ImportError:  # CPython: nothing is ever locked
    _micropython = None

HEAP_LOCKED = [False]  # set by the DUT while the firmware runs under micropython.heap_lock()


def hardware_begin():
    """Unlock the heap (when the DUT locked it) for the simulated hardware's work."""
    if HEAP_LOCKED[0]:
        _micropython.heap_unlock()


def hardware_end():
    if HEAP_LOCKED[0]:
        _micropython.heap_lock()

EIO = 5
ENODEV = 19
ETIMEDOUT = 110
F_NONE = 0
F_EIO = 1
F_ETIMEDOUT = 2
F_CORRUPT = 3
F_MISO00 = 4
F_MISOFF = 5
_NAMES = {EIO: "EIO", ENODEV: "ENODEV", ETIMEDOUT: "ETIMEDOUT"}


def _err(n):
    """OSError with errno set on both interpreters (CPython needs the two-argument form)."""
    return OSError(n, _NAMES[n])


FAULTS = {"none": F_NONE, "eio": F_EIO, "etimedout": F_ETIMEDOUT, "corrupt": F_CORRUPT,
          "miso00": F_MISO00, "misoff": F_MISOFF}


class _Faults:
    def __init__(self, seed):
        self.kind = F_NONE
        self.count = 0
        self.target = None
        self.rng = XorShift32(seed)
        self.injected = 0  # transfers that a fault hit
        self.transfers = 0

    def inject(self, kind, count=1, target=None):
        self.kind = FAULTS[kind] if isinstance(kind, str) else kind
        self.count = count
        self.target = target

    def clear(self):
        self.kind = F_NONE
        self.count = 0

    def take(self, target):
        """The fault kind hitting this transfer (and count it down)."""
        self.transfers += 1
        k = self.kind
        if k == F_NONE or self.count == 0:
            return F_NONE
        if self.target is not None and self.target != target:
            return F_NONE
        if self.count > 0:
            self.count -= 1
            if self.count == 0:
                self.kind = F_NONE
        self.injected += 1
        return k

    def mangle(self, k, buf, start, n):
        if k == F_MISO00 or k == F_MISOFF:
            v = 0 if k == F_MISO00 else 0xFF
            for i in range(start, n):
                buf[i] = v
        elif k == F_CORRUPT and n > start:
            i = start + self.rng.below(n - start)
            buf[i] ^= 1 << self.rng.below(8)


class Pin:
    """``machine.Pin`` output: ``value([v])``, ``on()``, ``off()``, ``init()``; CS edges reach the chip."""

    OUT = 1
    IN = 0
    OPEN_DRAIN = 2
    PULL_UP = 1
    PULL_DOWN = 2

    def __init__(self, ident, mode=-1, pull=-1, value=None):
        self.ident = ident
        self.v = 1 if value is None else (1 if value else 0)
        self.chip = None  # the chip whose chip-select this pin is

    def init(self, mode=-1, pull=-1, value=None):
        if value is not None:
            self.value(value)

    def value(self, v=None):
        if v is None:
            return self.v
        v = 1 if v else 0
        if v != self.v:
            self.v = v
            c = self.chip
            if c is not None and c.present:
                hardware_begin()
                try:
                    if v == 0:
                        c.select()
                    else:
                        c.deselect()
                finally:
                    hardware_end()
        return None

    def on(self):
        self.value(1)

    def off(self):
        self.value(0)

    def __call__(self, v=None):
        return self.value(v)


class SPIBus:
    """``machine.SPI``: ``init``, ``read``, ``readinto``, ``write``, ``write_readinto``, ``deinit``."""

    def __init__(self, clock, ident=0, baudrate=1000000, polarity=0, phase=0, bits=8, seed=7, **kw):
        self.clock = clock
        self.ident = ident
        self.pins = []
        self.faults = _Faults(seed)
        self.bytes = 0
        self.contention = 0
        self.mode_errors = 0
        self.init(baudrate, polarity, phase, bits)

    def init(self, baudrate=1000000, polarity=0, phase=0, bits=8, firstbit=0, sck=None, mosi=None, miso=None):
        self.baudrate = baudrate
        self.polarity = polarity
        self.phase = phase
        self.bits = bits

    def deinit(self):
        pass

    def attach(self, pin, chip):
        pin.chip = chip
        self.pins.append(pin)

    def _xfer(self, wbuf, rbuf, fill):
        hardware_begin()
        try:
            self._transfer(wbuf, rbuf, fill)
        finally:
            hardware_end()

    def _transfer(self, wbuf, rbuf, fill):
        n = len(rbuf) if wbuf is None else len(wbuf)
        self.clock.spend_us(2 + (n * 8 * 1000000) // self.baudrate)
        self.bytes += n
        sel = None
        nsel = 0
        for p in self.pins:
            if p.v == 0:
                nsel += 1
                sel = p
        k = self.faults.take(sel.ident if sel is not None else None)
        if k == F_EIO:
            raise _err(EIO)
        if k == F_ETIMEDOUT:
            self.clock.spend_us(50000)
            raise _err(ETIMEDOUT)
        if nsel > 1:
            self.contention += 1
        # MAX31865: SPI modes 1 and 3 (CPHA = 1); in mode 0/2 it samples on the wrong edge
        wrong_mode = self.phase != 1 or self.bits != 8
        if wrong_mode:
            self.mode_errors += 1
        for i in range(n):
            b = fill if wbuf is None else wbuf[i]
            r = 0xFF
            for p in self.pins:
                c = p.chip
                if p.v == 0 and c is not None and c.present:
                    r &= c.exchange((b >> 1) | 0x80 if wrong_mode else b)
            if rbuf is not None:
                rbuf[i] = ((r << 1) | 1) & 0xFF if wrong_mode else r
        if rbuf is not None:
            self.faults.mangle(k, rbuf, 0, n)

    def write(self, buf):
        self._xfer(buf, None, 0)
        return None

    def write_readinto(self, wbuf, rbuf):
        if len(wbuf) != len(rbuf):
            raise ValueError("buffers must be the same length")
        self._xfer(wbuf, rbuf, 0)

    def readinto(self, buf, write=0):
        self._xfer(None, buf, write)

    def read(self, nbytes, write=0):
        buf = bytearray(nbytes)
        self._xfer(None, buf, write)
        return bytes(buf)


class I2CBus:
    """``machine.I2C``: ``scan``, ``writeto``, ``readfrom_into``, ``readfrom_mem_into``, ``writeto_mem``, ..."""

    def __init__(self, clock, ident=0, freq=400000, timeout=50000, seed=11, **kw):
        self.clock = clock
        self.ident = ident
        self.freq = freq
        self.timeout = timeout
        self.devices = {}
        self.faults = _Faults(seed)
        self.transactions = 0
        self._k = F_NONE

    def init(self, freq=400000, **kw):
        self.freq = freq

    def attach(self, chip):
        self.devices[chip.address] = chip

    def _dev(self, addr, nbytes):
        self.transactions += 1
        self.clock.spend_us(((nbytes + 2) * 9 * 1000000) // self.freq)
        k = self.faults.take(addr)
        if k == F_EIO:
            raise _err(EIO)
        if k == F_ETIMEDOUT:
            self.clock.spend_us(self.timeout)
            raise _err(ETIMEDOUT)
        d = self.devices.get(addr)
        if d is None or not d.present:
            raise _err(ENODEV)
        self._k = k  # not returned as a tuple: that would allocate under heap_lock
        return d

    def scan(self):
        return [a for a in sorted(self.devices) if self.devices[a].present]

    def writeto(self, addr, buf, stop=True):
        hardware_begin()
        try:
            return self._writeto(addr, buf)
        finally:
            hardware_end()

    def _writeto(self, addr, buf):
        d = self._dev(addr, len(buf))
        if len(buf) == 0:
            return 0
        if len(buf) == 1:
            if not d.command(buf[0]):
                raise _err(EIO)
        elif not d.write(buf[0], memoryview(buf)[1:]):
            raise _err(EIO)
        return len(buf)

    def readfrom_mem_into(self, addr, memaddr, buf, addrsize=8):
        hardware_begin()
        try:
            d = self._dev(addr, len(buf) + 1)
            if not d.read(memaddr, buf):
                raise _err(EIO)
            self.faults.mangle(self._k, buf, 0, len(buf))
        finally:
            hardware_end()

    def readfrom_mem(self, addr, memaddr, nbytes, addrsize=8):
        buf = bytearray(nbytes)
        self.readfrom_mem_into(addr, memaddr, buf)
        return bytes(buf)

    def writeto_mem(self, addr, memaddr, buf, addrsize=8):
        hardware_begin()
        try:
            d = self._dev(addr, len(buf) + 1)
            if not d.write(memaddr, buf):
                raise _err(EIO)
        finally:
            hardware_end()

    def readfrom_into(self, addr, buf, stop=True):
        # the ADS122C04 answers a bare read with the last RDATA/RREG result; not used by the firmware
        raise _err(EIO)

    def readfrom(self, addr, nbytes, stop=True):
        raise _err(EIO)


class SMBus:
    """The ``smbus2.SMBus`` methods the CPython board adapter uses, on an ``I2CBus``."""

    def __init__(self, bus=None, force=False):
        self.i2c = bus
        self.fd = 0

    def open(self, bus):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def write_byte(self, i2c_addr, value, force=None):
        self.i2c.writeto(i2c_addr, bytes((value,)))

    def write_byte_data(self, i2c_addr, register, value, force=None):
        self.i2c.writeto_mem(i2c_addr, register, bytes((value,)))

    def write_i2c_block_data(self, i2c_addr, register, data, force=None):
        if len(data) > 32:
            raise ValueError("Data length cannot exceed 32 bytes")
        self.i2c.writeto_mem(i2c_addr, register, bytes(data))

    def read_byte_data(self, i2c_addr, register, force=None):
        return self.read_i2c_block_data(i2c_addr, register, 1)[0]

    def read_i2c_block_data(self, i2c_addr, register, length, force=None):
        if length > 32:
            raise ValueError("Desired block length over 32 bytes")
        buf = bytearray(length)
        self.i2c.readfrom_mem_into(i2c_addr, register, buf)
        return list(buf)
