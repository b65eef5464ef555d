"""ADS122C04 24-bit delta-sigma ADC (I2C) as a ratiometric Pt100 front end.

Names follow the TI datasheet (SBAS751). The chip's two matched excitation
current sources (IDAC1, IDAC2) drive the RTD and the return current flows
through the reference resistor between REFP0 and REFN0, so the conversion
result is the ratio R_RTD / R_REF independent of the current's accuracy and
drift. Wiring (docs/firmware.md):

- 3-wire: IDAC1 on AIN0 (RTD lead 1), IDAC2 on AIN1 (lead 2), input AIN0-AIN1,
  lead 3 to REFP0. The two lead drops cancel; V_REF carries both currents, so
  R_RTD = 2 * R_REF * code / (gain * 2**23).
- 2-wire and 4-wire: IDAC1 only. 2-wire: IDAC1 on AIN0, input AIN0-AIN1;
  4-wire: IDAC1 on AIN3 (force), input AIN0-AIN1 (sense);
  R_RTD = R_REF * code / (gain * 2**23).

Continuous conversion at 20 SPS in normal mode, which the datasheet gives
simultaneous 50 Hz and 60 Hz rejection, so ``filter_hz`` needs no register.

The bus is a ``machine.I2C`` (``writeto``, ``readfrom_mem_into``,
``writeto_mem``), created by the board. The hot path allocates nothing.
"""

from micropython import const

# commands
_CMD_RESET = const(0x06)
_CMD_START_SYNC = const(0x08)
_CMD_POWERDOWN = const(0x02)
_CMD_RDATA = const(0x10)
_CMD_RREG = const(0x20)  # | reg << 2
_CMD_WREG = const(0x40)  # | reg << 2

# configuration register 0
_REG0_MUX_SHIFT = const(4)  # MUX[3:0]
_MUX_AIN0_AIN1 = const(0x0)
_MUX_SHORTED = const(0xE)  # (AINp, AINn) shorted to (AVDD + AVSS) / 2: offset check
_REG0_GAIN_SHIFT = const(1)  # GAIN[2:0]: gain = 2**GAIN
_REG0_PGA_BYPASS = const(0x01)
# configuration register 1
_REG1_DR_SHIFT = const(5)  # DR[2:0]: 000 = 20 SPS normal mode
_REG1_MODE_TURBO = const(0x10)
_REG1_CM_CONTINUOUS = const(0x08)
_REG1_VREF_SHIFT = const(1)  # VREF[1:0]
_VREF_INTERNAL = const(0)
_VREF_EXTERNAL = const(1)  # REFP0 / REFN0
_REG1_TS = const(0x01)
# configuration register 2
_REG2_DRDY = const(0x80)
_REG2_DCNT = const(0x40)
_REG2_CRC_SHIFT = const(4)
_REG2_BCS = const(0x08)  # burn-out current sources
_REG2_IDAC_MASK = const(0x07)
# configuration register 3
_REG3_I1MUX_SHIFT = const(5)
_REG3_I2MUX_SHIFT = const(2)
_IMUX_OFF = const(0)
_IMUX_AIN0 = const(1)
_IMUX_AIN1 = const(2)
_IMUX_AIN2 = const(3)
_IMUX_AIN3 = const(4)

IDAC_UA = (0, 10, 50, 100, 250, 500, 1000, 1500)  # IDAC[2:0] code -> uA
_MAX_RATIO_R = const(400000)  # mohm: Pt100 at +850 degC is 390.48 ohm
_NO_DATA = const(-0x1000000)  # firmware.drivers.NO_DATA (tests/firmware/test_fw_consts.py checks)


def _bad(arg, v):
    return ValueError("ADS122C04 %s %r" % (arg, v))


class ADS122C04:
    """One ADS122C04 measuring one Pt100 ratiometrically (see module docstring).

    ``address`` is the 7-bit I2C address (0x40..0x4F by A0/A1 strapping),
    ``rref_mohm`` the reference resistor in milliohm (100000..10000000, and
    small enough for the ratio arithmetic at the chosen gain), ``idac_ua`` one
    of 10, 50, 100, 250, 500, 1000, 1500, ``wires`` 2, 3 or 4, ``filter_hz``
    50 or 60. The PGA gain is the largest that keeps a
    Pt100 at +850 degC below 90 % of full scale. The constructor resets the
    chip, writes and verifies the four configuration registers and starts
    continuous conversion.
    """

    # transfer buffers shared by all instances (transfers never interleave)
    _b1 = bytearray(1)
    _b3 = bytearray(3)

    SPI = False  # ``select`` is the I2C address (firmware/drivers.py)
    OPTIONS = ("rref_mohm", "wires", "idac_ua", "filter_hz")

    def __init__(self, i2c, address=0x40, *, rref_mohm=1620000, wires=3, idac_ua=250, filter_hz=50):
        # ValueError("ADS122C04 <argument> <value>"); the allowed values are in the docstring
        if not 0x40 <= address <= 0x4F:
            raise _bad("address", address)
        if wires not in (2, 3, 4):
            raise _bad("wires", wires)
        if idac_ua not in IDAC_UA[1:]:
            raise _bad("idac_ua", idac_ua)
        if filter_hz not in (50, 60):
            raise _bad("filter_hz", filter_hz)
        if not 100000 <= rref_mohm <= 10000000:
            raise _bad("rref_mohm", rref_mohm)
        self._i2c = i2c
        self.address = address
        m = 2 if wires == 3 else 1
        gain = 1
        while gain < 128 and gain * 2 * _MAX_RATIO_R * 10 < 9 * m * rref_mohm:
            gain *= 2
        self.gain = gain
        # R/R0*1e7 = code * k / 2**23 with k = m * rref_mohm * 100 / gain (R0 = 100 ohm)
        k = m * rref_mohm * 100 // gain
        if k >= 1 << 29:
            raise _bad("rref_mohm", rref_mohm)  # too large for the ratio arithmetic
        self._k1 = k >> 12
        self._k0 = k & 0xFFF
        g = 0
        while (1 << g) < gain:
            g += 1
        if wires == 3:
            i1, i2 = _IMUX_AIN0, _IMUX_AIN1
        elif wires == 2:
            i1, i2 = _IMUX_AIN0, _IMUX_OFF
        else:
            i1, i2 = _IMUX_AIN3, _IMUX_OFF
        self._config = (
            (_MUX_AIN0_AIN1 << _REG0_MUX_SHIFT) | (g << _REG0_GAIN_SHIFT),
            _REG1_CM_CONTINUOUS | (_VREF_EXTERNAL << _REG1_VREF_SHIFT),
            IDAC_UA.index(idac_ua),
            (i1 << _REG3_I1MUX_SHIFT) | (i2 << _REG3_I2MUX_SHIFT),
        )
        self.reset()
        for reg in range(4):
            self.write_register(reg, self._config[reg])
        for reg in range(4):
            got = self.read_register(reg)
            if reg == 2:
                got &= ~_REG2_DRDY
            if got != self._config[reg]:
                raise OSError(5, "ADS122C04 at 0x%02x: register %d reads 0x%02x after writing 0x%02x"
                              % (address, reg, got, self._config[reg]))
        self.start()

    # --- commands and registers ------------------------------------------
    def _command(self, cmd):
        b = self._b1
        b[0] = cmd
        self._i2c.writeto(self.address, b)

    def reset(self):
        self._command(_CMD_RESET)

    def start(self):
        """START/SYNC: begin (continuous) conversion."""
        self._command(_CMD_START_SYNC)

    def powerdown(self):
        self._command(_CMD_POWERDOWN)

    def read_register(self, reg):
        self._i2c.readfrom_mem_into(self.address, _CMD_RREG | (reg << 2), self._b1)
        return self._b1[0]

    def write_register(self, reg, value):
        b = self._b1
        b[0] = value
        self._i2c.writeto_mem(self.address, _CMD_WREG | (reg << 2), b)

    # --- hot path ------------------------------------------------------------
    @property
    def data_ready(self):
        """DRDY: a new conversion result is waiting (cleared by reading it)."""
        return bool(self.read_register(2) & _REG2_DRDY)

    def read_data(self):
        """Latest conversion result, signed 24-bit (RDATA)."""
        b = self._b3
        self._i2c.readfrom_mem_into(self.address, _CMD_RDATA, b)
        v = (b[0] << 16) | (b[1] << 8) | b[2]
        if v & 0x800000:
            v -= 0x1000000
        return v

    def sample(self):
        """The newest conversion result, or NO_DATA when none arrived since the last one."""
        if not self.data_ready:
            return _NO_DATA
        return self.read_data()

    def set_limits(self, low_ratio, high_ratio):
        """No fault comparator on this chip: the plausible-range check in firmware/channels.py does it."""

    def ratio(self, code):
        """R/R0 * 1e7 of a conversion result for a Pt100 (R0 = 100 ohm); 0 if not positive."""
        if code <= 0:
            return 0
        # code * k >> 23 with code and k split in 12-bit pieces (no product >= 2**30)
        c1 = code >> 12
        c0 = code & 0xFFF
        k1 = self._k1
        k0 = self._k0
        return ((c1 * k1) << 1) + ((c1 * k0 + c0 * k1 + ((c0 * k0) >> 12)) >> 11)

    def code_of(self, ratio):
        """Conversion result of an R/R0*1e7 ratio (tests and start-up use)."""
        k = (self._k1 << 12) | self._k0
        return (ratio << 23) // k
