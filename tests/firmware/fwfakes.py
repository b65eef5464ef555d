"""Register-level fakes for the firmware's unit tests, on CPython and MicroPython.

Not a test module: conftest.py puts this folder on sys.path for pytest, and the
MicroPython scripts of test_fw_heaplock.py import it through MICROPYPATH. The
fakes allocate nothing on their steady-state paths so that the firmware's
cycle can run under ``micropython.heap_lock()`` with them.

These are unit-test fakes (datasheet register maps, simple timing); the
faithful chip simulations with fault injection live in hil_tests/.
"""

A = 3.9083e-3
B = -5.775e-7
C = -4.183e-12


def pt100_ohm(t_c):
    """IEC 60751 Callendar-Van Dusen (float; test side only)."""
    r = 1.0 + A * t_c + B * t_c * t_c
    if t_c < 0:
        r += C * (t_c - 100.0) * t_c * t_c * t_c
    return 100.0 * r


class FakePin:
    def __init__(self, ident=None):
        self.ident = ident
        self.v = 1

    def value(self, v=None):
        if v is None:
            return self.v
        self.v = 1 if v else 0
        return None


class FakeSPI:
    """machine.SPI subset: chips attached with their chip-select pins."""

    def __init__(self):
        self.pins = []
        self.chips = []
        self.fail = 0  # raise OSError on the next ``fail`` transfers
        self.transfers = 0

    def attach(self, pin, chip):
        self.pins.append(pin)
        self.chips.append(chip)

    def _chip(self):
        sel = None
        for i in range(len(self.pins)):
            if self.pins[i].v == 0:
                if sel is not None:
                    return None  # two chips selected: bus contention reads as nothing
                sel = self.chips[i]
        return sel

    def write(self, buf):
        self.write_readinto(buf, None)

    def write_readinto(self, wbuf, rbuf):
        self.transfers += 1
        if self.fail:
            self.fail -= 1
            raise OSError(5)
        chip = self._chip()
        if chip is None or not chip.present:
            if rbuf is not None:
                for i in range(len(rbuf)):
                    rbuf[i] = 0xFF
            return
        chip.transfer(wbuf, rbuf)


class FakeMAX31865:
    """MAX31865 register file: config, RTD, thresholds, fault status, auto-increment.

    ``ohm`` is the RTD resistance (set ``open_circuit`` for a broken sensor).
    In auto mode the RTD register holds the conversion of the current
    resistance; one-shot converts once. Threshold faults set D7/D6 and the
    RTD fault bit; faults latch until cleared with D1 (D5, D3, D2 written 0).
    """

    def __init__(self, rref_ohm=430.0, ohm=100.0):
        self.regs = bytearray(8)
        self.regs[3] = 0xFF
        self.regs[4] = 0xFF
        self.rref = rref_ohm
        self.open_circuit = False
        self.present = True
        self.fault_cycles = 0
        self.set_ohm(ohm)

    def set_temperature(self, t_c):
        self.set_ohm(pt100_ohm(t_c))

    def set_ohm(self, ohm):
        # the conversion result is computed here so that reads allocate nothing
        self.ohm = ohm
        c = int(ohm / self.rref * 32768.0 + 0.5)
        self.rtd_code = 0x7FFF if c > 0x7FFF else c

    def code(self):
        return 0x7FFF if self.open_circuit else self.rtd_code

    def _convert(self):
        r = self.regs
        code = self.code()
        hi = ((r[3] << 8) | r[4]) >> 1
        lo = ((r[5] << 8) | r[6]) >> 1
        fault = 0
        if code >= hi:
            fault |= 0x80
        if code < lo:
            fault |= 0x40
        if self.open_circuit:
            fault |= 0x04 | 0x80
        r[7] |= fault
        r[1] = (code >> 7) & 0xFF
        r[2] = ((code << 1) & 0xFE) | (1 if r[7] else 0)

    def transfer(self, wbuf, rbuf):
        r = self.regs
        addr = wbuf[0]
        n = len(wbuf)
        if addr & 0x80:
            a = addr & 0x7F
            for i in range(1, n):
                if a < 7:
                    self._write(a, wbuf[i])
                a += 1
            return
        if r[0] & 0x40:
            self._convert()
        a = addr
        if rbuf is not None:
            rbuf[0] = 0xFF
            for i in range(1, n):
                rbuf[i] = r[a] if a < 8 else 0xFF
                a += 1

    def _write(self, a, v):
        r = self.regs
        if a == 0:
            if v & 0x02 and not v & 0x2C:  # fault status clear
                r[7] = 0
                r[2] &= 0xFE
                v &= ~0x02
            if v & 0x0C == 0x04:  # automatic fault detection: finishes at once here
                self.fault_cycles += 1
                if self.open_circuit:
                    r[7] |= 0x04
                v &= ~0x0C
            if v & 0x20:  # one-shot
                self._convert()
                v &= ~0x20
            r[0] = v
        else:
            r[a] = v


class FakeI2C:
    """machine.I2C subset dispatching to fake devices by address."""

    def __init__(self):
        self.devices = {}
        self.fail = 0

    def attach(self, addr, dev):
        self.devices[addr] = dev

    def _dev(self, addr):
        if self.fail:
            self.fail -= 1
            raise OSError(5)
        d = self.devices.get(addr)
        if d is None or not d.present:
            raise OSError(19)  # ENODEV: no ACK
        return d

    def writeto(self, addr, buf):
        self._dev(addr).command(buf[0])
        return 1

    def readfrom_mem_into(self, addr, memaddr, buf):
        self._dev(addr).read(memaddr, buf)

    def writeto_mem(self, addr, memaddr, buf):
        self._dev(addr).write(memaddr, buf)


class FakeADS122C04:
    """ADS122C04 command set: RESET, START/SYNC, RDATA, RREG, WREG; 4 config registers.

    Conversions complete when ``convert()`` is called (the test advances
    them), computing the ratiometric code from ``ohm`` and the configured
    gain, IDAC routing and reference resistor.
    """

    def __init__(self, rref_ohm=1620.0, ohm=100.0):
        self.regs = bytearray(4)
        self.rref = rref_ohm
        self.present = True
        self.data = 0
        self.started = False
        self.auto = True  # every RREG of register 2 finds a fresh conversion
        self._codes = [0] * 8
        self.set_ohm(ohm)

    def set_temperature(self, t_c):
        self.set_ohm(pt100_ohm(t_c))

    def set_ohm(self, ohm):
        # codes for every gain and wiring are computed here so that reads allocate nothing
        self.ohm = ohm
        for g in range(8):
            self._codes[g] = int(ohm * (1 << g) / self.rref * 8388608.0)

    def command(self, c):
        if c & 0xFE == 0x06:
            for i in range(4):
                self.regs[i] = 0
            self.started = False
        elif c & 0xFE == 0x08:
            self.started = True

    def convert(self):
        code = self._codes[(self.regs[0] >> 1) & 7]
        if (self.regs[3] >> 2) & 7:  # both IDACs: 3-wire, V_REF carries both currents
            code >>= 1
        if code > 0x7FFFFF:
            code = 0x7FFFFF
        self.data = code
        self.regs[2] |= 0x80

    def read(self, cmd, buf):
        if cmd & 0xF0 == 0x10:  # RDATA
            d = self.data & 0xFFFFFF
            buf[0] = d >> 16
            buf[1] = (d >> 8) & 0xFF
            buf[2] = d & 0xFF
            self.regs[2] &= 0x7F
        elif cmd & 0xF0 == 0x20:  # RREG
            reg = (cmd >> 2) & 3
            if reg == 2 and self.auto and self.started and self.regs[1] & 0x08:
                self.convert()
            buf[0] = self.regs[reg]
        else:
            raise OSError(5)

    def write(self, cmd, buf):
        if cmd & 0xF0 != 0x40:
            raise OSError(5)
        reg = (cmd >> 2) & 3
        v = buf[0]
        if reg == 2:
            v = (v & 0x7F) | (self.regs[2] & 0x80)
        self.regs[reg] = v


class FakeSerial:
    """Non-blocking serial: ``feed`` queues bytes for the firmware, ``tx`` collects its output."""

    def __init__(self, size=1024):
        self.inq = bytearray(size)
        self.head = 0
        self.tail = 0
        self.out = bytearray(size)
        self.nout = 0
        self.dropped = 0  # bytes that did not fit: take() refuses to hide them

    def feed(self, data):
        for c in data:
            self.inq[self.tail] = c
            self.tail += 1

    def readinto(self, buf):
        n = 0
        while n < len(buf) and self.head < self.tail:
            buf[n] = self.inq[self.head]
            self.head += 1
            n += 1
        if self.head == self.tail:
            self.head = 0
            self.tail = 0
        return n

    def write(self, buf, n):
        out = self.out
        k = self.nout
        for i in range(n):
            if k < len(out):
                out[k] = buf[i]
                k += 1
            else:
                self.dropped += 1
        self.nout = k
        return n

    def take(self):
        """Everything written since the last take, as bytes (allocates: test side)."""
        if self.dropped:
            n = self.dropped
            self.dropped = 0
            self.nout = 0
            raise OverflowError("FakeSerial dropped %d bytes: take() more often" % n)
        b = bytes(self.out[:self.nout])
        self.nout = 0
        return b


class BoardPort:
    """A pySerial-like port onto a fake board's FakeSerial (``board.serial``), for host code that opens a port (the
    LinuxCNC bridge's StreamLink): what it writes is the board's input, what it reads the board's output."""

    def __init__(self, board):
        self.board = board
        self.rx = bytearray()

    @property
    def in_waiting(self):
        self.rx += self.board.serial.take()
        return len(self.rx)

    def write(self, b):
        self.board.serial.feed(bytes(b))

    def read(self, n):
        self.rx += self.board.serial.take()
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def close(self):
        pass


class FakeClock:
    def __init__(self, t=0):
        self.t = t

    def ticks_ms(self):
        return self.t

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, ms):
        self.t += ms


class FakeWDT:
    def __init__(self):
        self.fed = 0

    def feed(self):
        self.fed += 1


def make_rig(n_max=9, n_ads=2, temps=None, serial_mode="stream", table_dir="tables", extra=None,
             serial_size=1024):
    """A Board with ``n_max`` MAX31865 on one SPI bus and ``n_ads`` ADS122C04 on one I2C bus."""
    from firmware.board import Board
    spi = FakeSPI()
    i2c = FakeI2C()
    chans = []
    chips = []
    pins = {}
    for i in range(n_max):
        chip = FakeMAX31865()
        pin = FakePin(10 + i)
        pins[10 + i] = pin
        spi.attach(pin, chip)
        chips.append(chip)
        chans.append({"name": "T%d" % (i + 1), "driver": "max31865", "bus": "spi0", "cs": 10 + i,
                      "rref_mohm": 430000, "wires": 3})
    for k in range(n_ads):
        dev = FakeADS122C04()
        i2c.attach(0x40 + k, dev)
        chips.append(dev)
        chans.append({"name": "T%d" % (n_max + k + 1), "driver": "ads122c04", "bus": "i2c0",
                      "address": 0x40 + k, "rref_mohm": 1620000, "wires": 3, "idac_ua": 500})
    for i, chip in enumerate(chips):
        chip.set_temperature(temps[i] if temps is not None else 20.0 + i)
    cfg = {"channels": chans, "serial": {"mode": serial_mode, "baud": 115200, "address": 1},
           "table_dir": table_dir, "cycle_ms": 100, "frame_ms": 100, "watchdog_ms": 1000}
    if extra:
        for k in extra:
            cfg[k] = extra[k]
    ser = FakeSerial(serial_size)
    clock = FakeClock(1000)
    board = Board(cfg, {"spi0": spi, "i2c0": i2c}, lambda cs: pins[cs], ser, clock, FakeWDT(), None)
    board.chips = chips
    board.entropy = _test_nonce
    return board


def _test_nonce():
    # the fakes' boards draw the same session nonce every boot (fwhelpers.TEST_NONCE): runs are reproducible
    return b"\x5e\x55\x10\x4e"
