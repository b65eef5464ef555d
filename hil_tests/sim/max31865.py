"""MAX31865 RTD-to-digital converter at register level (Maxim 19-6478 rev. 3).

What is modelled, bit by bit:

- Registers 00h..07h (read) / 80h..86h (write); the address auto-increments
  after every data byte while CS stays low; addresses above 07h read FFh,
  writes to them and to the read-only registers (RTD data, fault status) are
  ignored. The first byte of every transfer is the address; MISO idles high
  during it.
- Configuration D7 V_BIAS, D6 auto conversion, D5 one-shot (self-clearing at
  the end of the conversion), D4 3-wire, D3:D2 fault-detection cycle, D1
  fault-status clear (self-clearing), D0 50/60 Hz filter. Interactions: the
  fault status clears only when D1 is written 1 with D5, D3 and D2 written
  0; a one-shot written together with a fault-detection request is ignored;
  the automatic fault-detection cycle starts only on 100X010Xb (V_BIAS on,
  auto off; a one-shot bit written with it is ignored) and runs 550 us (D3:D2 read 01 meanwhile, then
  00); the manual cycle (10 then 11) is modelled too. Changing the filter in
  auto mode, converting without V_BIAS, or a one-shot sooner than 10.5 time
  constants after V_BIAS on are recorded as ``violations`` (the datasheet
  forbids them; the chip's result is then unreliable, here: V_BIAS off
  converts to zero).
- Conversions: one-shot takes 52 ms (60 Hz) or 62.5 ms (50 Hz) from the
  write; auto mode converts continuously every 16.7 ms / 20 ms after a first
  conversion of the one-shot length. The 15-bit code is
  round(R_RTD * 2**15 / R_REF), clipped to 0..7FFFh, of the resistance at the
  end of the conversion. After every conversion the code is compared with the
  thresholds (high: code >= high threshold sets D7; low: code <= low
  threshold sets D6). Fault status bits latch until cleared; bit D0 of the RTD
  LSB register is set while any fault status bit is.
- Fault-detection cycle results: open element -> D5 (REFIN- > 0.85 V_BIAS);
  a FORCE- open wire (``force_open``) -> D4 and D3; over/under-voltage
  (``ovuv``) sets D2 whenever the chip is powered.
- Power: ``present = False`` takes the chip off the bus (MISO floats to the
  pull-up); power coming back is a power-on reset (every register to its POR
  value: configuration 00h, high threshold FFFFh, low threshold 0000h).

Timing comes from a ``SimClock``; nothing here allocates after construction
on the transfer path, so the firmware's cycle can run under heap_lock.
"""

from hil_tests.sim.intmath import muldiv
from hil_tests.sim.stimulus import OPEN
from hil_tests.sim.violations import ViolationLog

_T_ONESHOT_US = (52000, 62500)  # index: filter bit D0 (0 = 60 Hz, 1 = 50 Hz)
_T_AUTO_US = (16667, 20000)
_T_FAULT_CYCLE_US = 550
_T_BIAS_SETTLE_US = 1050  # 10.5 time constants of a 100 us input filter
_FULL = 0x7FFF


class MAX31865(ViolationLog):
    def __init__(self, clock, rtd, rref_ohm=430.0, name="max31865"):
        self.clock = clock
        self.rtd = rtd
        self.rref_uohm = int(rref_ohm * 1e6 + 0.5)
        self._half_rref = self.rref_uohm // 2
        self.name = name
        self.regs = bytearray(8)
        self.present = True
        self.force_open = False
        self.ovuv = False
        self.conversions = 0
        self.fault_cycles = 0
        self.clears = 0
        self.ignored_clears = 0
        self.ignored_one_shots = 0
        self.transfers = 0
        self._init_violations()
        self._por()
        self._sel = False
        self._addr = 0
        self._first = False
        clock.on_epoch(self)

    def _por(self):
        r = self.regs
        for i in range(8):
            r[i] = 0
        r[3] = 0xFF
        r[4] = 0xFF
        self.code = 0
        self.oneshot_end = -1
        self.auto_next = -1
        self.cycle_end = -1
        self.manual = 0
        self.bias_on_us = -1

    # --- power ---------------------------------------------------------------
    def power(self, on):
        if on and not self.present:
            self._por()
        self.present = on

    # --- time ------------------------------------------------------------------
    def _convert(self, t_us):
        r = self.regs
        if not r[0] & 0x80:
            self._violation("conversion with V_BIAS off")
            code = 0
        else:
            ohm = self.rtd.measured(self.clock.ms_at(t_us))
            if self.rtd.condition == OPEN or self.force_open:
                code = _FULL
            else:
                code = muldiv(ohm, 32768, self.rref_uohm, self._half_rref)
                if code > _FULL:
                    code = _FULL
        self.code = code
        self.conversions += 1
        r[1] = code >> 7
        r[2] = (code << 1) & 0xFE
        hi = ((r[3] << 8) | r[4]) >> 1
        lo = ((r[5] << 8) | r[6]) >> 1
        if code >= hi:
            r[7] |= 0x80
        if code <= lo:
            r[7] |= 0x40

    def _fault_checks(self):
        f = 0
        if self.rtd.condition == OPEN:
            f |= 0x20
        if self.force_open:
            f |= 0x18
        self.regs[7] |= f
        self.fault_cycles += 1

    def update(self):
        """Bring conversions and the fault-detection cycle up to the present time."""
        now = self.clock.us
        r = self.regs
        if self.cycle_end >= 0 and now >= self.cycle_end:
            self.cycle_end = -1
            self._fault_checks()
            r[0] &= ~0x0C
        if self.oneshot_end >= 0 and now >= self.oneshot_end:
            t = self.oneshot_end
            self.oneshot_end = -1
            self._convert(t)
            r[0] &= ~0x20
        if self.auto_next >= 0 and now >= self.auto_next:
            period = _T_AUTO_US[r[0] & 1]
            k = (now - self.auto_next) // period
            t = self.auto_next + k * period
            self.auto_next = t + period
            self._convert(t)
        if self.ovuv:
            r[7] |= 0x04

    def shift_epoch(self, shift):
        """The clock's new epoch (hil_tests/sim/clock.py) begins ``shift`` us after the old one.

        Stored times move by ``shift``. A time older than the new epoch's start (more than 4.5
        simulated minutes ago) keeps its meaning: a finished fault cycle or one-shot nobody has read
        yet completes now, at its own time, as the next access would have completed it; the next
        auto conversion moves by whole periods (the next access converts at the same period
        boundary); V_BIAS switched on that long ago is settled either way (0: the epoch's start)."""
        if 0 <= self.cycle_end < shift or 0 <= self.oneshot_end < shift:
            r = self.regs
            if 0 <= self.cycle_end < shift:
                self.cycle_end = -1
                self._fault_checks()
                r[0] &= ~0x0C
            if 0 <= self.oneshot_end < shift:
                t = self.oneshot_end
                self.oneshot_end = -1
                self._convert(t)
                r[0] &= ~0x20
        if self.cycle_end >= 0:
            self.cycle_end -= shift
        if self.oneshot_end >= 0:
            self.oneshot_end -= shift
        if self.auto_next >= 0:
            if self.auto_next < shift:
                period = _T_AUTO_US[self.regs[0] & 1]
                self.auto_next += (shift - self.auto_next + period - 1) // period * period
            self.auto_next -= shift
        if self.bias_on_us >= 0:
            self.bias_on_us = self.bias_on_us - shift if self.bias_on_us >= shift else 0

    # --- configuration write (the interactions live here) -------------------------
    def _write_config(self, v):
        r = self.regs
        old = r[0]
        now = self.clock.us
        if (v ^ old) & 0x80:
            self.bias_on_us = now if v & 0x80 else -1
        if (v ^ old) & 0x01 and old & 0x40 and v & 0x40:
            self._violation("filter changed during auto conversion")
        if v & 0x02:
            if v & 0x2C:
                self.ignored_clears += 1  # datasheet: clear only with D5, D3, D2 written 0
            else:
                r[7] = 0
                self.clears += 1
        cyc = v & 0x0C
        new = v & 0xD1  # D1 self-clears; D5 and D3:D2 are set below when they take effect
        if cyc:
            if v & 0x20:
                self.ignored_one_shots += 1
            if cyc == 0x04:
                if v & 0xC0 == 0x80 and self.cycle_end < 0:  # D5 is ignored with a cycle request
                    self.cycle_end = now + _T_FAULT_CYCLE_US
                    self.auto_next = -1
                    new = (new & ~0x40) | 0x04
                else:
                    self._violation("fault-detection cycle requested with config %02Xh (needs 100X010Xb)" % v)
            elif cyc == 0x08:
                if v & 0x80:
                    self.manual = 1
                    new |= 0x08
                else:
                    self._violation("manual fault cycle with V_BIAS off")
            elif cyc == 0x0C and self.manual == 1:
                self.manual = 0
                self.cycle_end = now + 100
                new |= 0x0C
        elif v & 0x20:
            if v & 0x40:
                self.ignored_one_shots += 1  # already converting continuously
            elif self.oneshot_end < 0:
                if self.bias_on_us < 0 or now - self.bias_on_us < _T_BIAS_SETTLE_US:
                    self._violation("one-shot before V_BIAS settled")
                self.oneshot_end = now + _T_ONESHOT_US[v & 1]
                new |= 0x20
        if self.cycle_end >= 0 and not cyc:
            new |= old & 0x0C  # a running cycle keeps reporting itself
        if self.manual and not cyc:
            new |= 0x08
        if new & 0x40 and not old & 0x40:
            self.auto_next = now + _T_ONESHOT_US[new & 1]
        elif not new & 0x40:
            self.auto_next = -1
        if old & 0x20 and self.oneshot_end >= 0:
            new |= 0x20
        r[0] = new

    # --- SPI (called by the bus, one byte at a time while CS is low) ------------------
    def select(self):
        self.transfers += 1
        self.update()
        self._first = True

    def deselect(self):
        self._first = False

    def exchange(self, b):
        if self._first:
            self._first = False
            self._addr = b
            return 0xFF
        a = self._addr
        self._addr = a + 1
        if a & 0x80:
            a &= 0x7F
            if a == 0:
                self._write_config(b)
            elif 3 <= a <= 6:
                self.regs[a] = b
            return 0xFF
        if a > 7:
            return 0xFF
        r = self.regs
        if a == 2:
            return (r[2] & 0xFE) | (1 if r[7] else 0)
        return r[a]
