"""ADS122C04 24-bit delta-sigma ADC at command and register level (TI SBAS751), measuring a Pt100.

Modelled: the I2C command set (RESET 0000 011x, START/SYNC 0000 100x,
POWERDOWN 0000 001x, RDATA 0001 xxxx, RREG 0010 rrxx, WREG 0100 rrxx); the
four configuration registers with their fields (MUX, GAIN, PGA_BYPASS; DR,
MODE, CM, VREF, TS; DRDY, DCNT, CRC, BCS, IDAC; I1MUX, I2MUX), DRDY set by
each finished conversion and cleared by reading the data; single-shot and
continuous conversion at the configured data rate (normal mode 20..1000 SPS,
turbo twice that), the first conversion after START/SYNC taking one period
plus the digital filter settling (here: one extra period); the data counter
byte (DCNT) in front of the result.

The analogue side is computed from the routing the registers select: the
IDACs' currents through the RTD and the reference resistor. With IDAC1 and
IDAC2 on the two RTD leads (3-wire) the lead drops cancel and V_REF carries
both currents; with one IDAC, V_REF = I * R_REF; with the internal 2.048 V
reference the result depends on the current's absolute value. The code is
floor(gain * 2**23 * V_IN / V_REF), clipped to the 24-bit two's-complement
range; optional noise in micro-ohm comes from the ``Rtd``.
Not modelled: the CRC16/inverted-data output modes (recorded as a violation),
the temperature-sensor mode, burn-out current sources' effect on the reading.
"""

from hil_tests.sim.intmath import muldiv
from hil_tests.sim.stimulus import OPEN
from hil_tests.sim.violations import ViolationLog

_PV_2048MV = 2048000000000000  # the internal 2.048 V reference in pV (uA x uohm)
_SPS = (20, 45, 90, 175, 330, 600, 1000)
_IDAC_UA = (0, 10, 50, 100, 250, 500, 1000, 1500)
_MAX = 0x7FFFFF


class ADS122C04(ViolationLog):
    def __init__(self, clock, rtd, rref_ohm=1620.0, address=0x40, wires=3, name="ads122c04"):
        self.clock = clock
        self.rtd = rtd
        self.rref_uohm = int(rref_ohm * 1e6 + 0.5)
        self._vref2 = 2 * self.rref_uohm  # both IDACs through R_REF
        self.address = address
        self.wires = wires
        self.name = name
        self.regs = bytearray(4)
        self.present = True
        self.conversions = 0
        self.commands = 0
        self._init_violations()
        self._reset()
        clock.on_epoch(self)

    def _reset(self):
        for i in range(4):
            self.regs[i] = 0
        self.data = 0
        self.counter = 0
        self.running = False
        self.next_us = -1
        self.single = False

    def power(self, on):
        if on and not self.present:
            self._reset()
        self.present = on

    # --- conversion ---------------------------------------------------------------
    def _period_us(self):
        r1 = self.regs[1]
        dr = r1 >> 5
        sps = _SPS[dr if dr < 7 else 6]
        if r1 & 0x10:
            sps *= 2
        return 1000000 // sps

    def _code(self, t_us):
        r0 = self.regs[0]
        r3 = self.regs[3]
        mux = r0 >> 4
        gain = 1 << ((r0 >> 1) & 7)
        i_ua = _IDAC_UA[self.regs[2] & 7]
        i1 = (r3 >> 5) & 7
        i2 = (r3 >> 2) & 7
        if mux == 0xE or i_ua == 0 or (i1 == 0 and i2 == 0):
            return 0  # inputs shorted, or no excitation: offset only
        if mux != 0:
            self._violation("input MUX %X is not AIN0-AIN1 (the RTD)" % mux)
            return 0
        if self.rtd.condition == OPEN:
            return _MAX  # IDAC compliance: input driven to the rail
        ohm = self.rtd.measured(self.clock.ms_at(t_us))
        both = i1 != 0 and i2 != 0
        vref_sel = (self.regs[1] >> 1) & 3
        if vref_sel == 1:
            # ratiometric: V_REF = n * I * R_REF, V_IN = I * R_RTD
            code = muldiv(ohm, gain, self._vref2 if both else self.rref_uohm, 0, 23)
        else:
            # internal 2.048 V (or supply) reference: V_IN = I * R, I in uA, R in uohm -> pV
            code = muldiv(ohm, i_ua * gain, _PV_2048MV, 0, 23)
        return _MAX if code > _MAX else code

    def update(self):
        now = self.clock.us
        if self.next_us < 0 or now < self.next_us:
            return
        p = self._period_us()
        k = (now - self.next_us) // p
        t = self.next_us + k * p
        self.data = self._code(t)
        self.conversions += 1
        self.counter = (self.counter + 1) & 0xFF
        self.regs[2] |= 0x80
        if self.single:
            self.next_us = -1
            self.running = False
        else:
            self.next_us = t + p

    def shift_epoch(self, shift):
        """The clock's new epoch begins ``shift`` us after the old one (hil_tests/sim/clock.py): the
        next conversion time moves by ``shift``; one older than the new epoch's start first moves on
        by whole periods (the next access converts at the same period boundary)."""
        if self.next_us >= 0:
            if self.next_us < shift:
                p = self._period_us()
                self.next_us += (shift - self.next_us + p - 1) // p * p
            self.next_us -= shift

    # --- I2C transactions (called by the bus) ---------------------------------------
    def command(self, c):
        """A write of one command byte."""
        self.commands += 1
        self.update()
        if c & 0xFE == 0x06:
            self._reset()
        elif c & 0xFE == 0x08:
            self.single = not self.regs[1] & 0x08
            self.running = True
            self.next_us = self.clock.us + 2 * self._period_us()
        elif c & 0xFE == 0x02:
            self.running = False
            self.next_us = -1
        else:
            return False
        return True

    def read(self, cmd, buf):
        """Write of ``cmd`` then a repeated-start read into ``buf``; False if the chip NAKs the command."""
        self.commands += 1
        self.update()
        r = self.regs
        if cmd & 0xF0 == 0x10:
            if r[2] & 0x30:
                self._violation("CRC/inverted-data output mode is not modelled")
            d = self.data & 0xFFFFFF
            k = 0
            if r[2] & 0x40 and len(buf) > 3:
                buf[0] = self.counter
                k = 1
            n = len(buf)
            for i in range(k, n):
                j = i - k  # byte j of the 24-bit result, MSB first; beyond it the bus reads FFh
                buf[i] = ((d >> (16 - 8 * j)) & 0xFF) if j < 3 else 0xFF
            r[2] &= 0x7F
            return True
        if cmd & 0xF0 == 0x20:
            v = r[(cmd >> 2) & 3]
            for i in range(len(buf)):
                buf[i] = v
            return True
        return False

    def write(self, cmd, buf):
        """Write of ``cmd`` followed by data bytes (WREG)."""
        self.commands += 1
        self.update()
        if cmd & 0xF0 != 0x40 or len(buf) < 1:
            return False
        reg = (cmd >> 2) & 3
        v = buf[0]
        if reg == 2:
            v = (v & 0x7F) | (self.regs[2] & 0x80)  # DRDY is read-only
        elif reg == 3:
            v &= 0xFC  # reserved bits read 0
        self.regs[reg] = v
        return True
