"""MAX31865 RTD-to-digital converter (SPI), one chip per sensor with its own chip-select.

Register and bit names follow the Maxim datasheet (19-6478). The bus is a
``machine.SPI`` in mode 1 or 3 (the driver uses ``write`` and
``write_readinto`` only) and ``cs`` an output pin with ``value()``; both are
created by the board. Every transfer is one call with chip-select held low, so
a Linux spidev node that drives chip-select itself works as well.

The hot path (``read_rtd``, ``fault_status``, ``clear_fault``, ``ratio``)
allocates nothing and keeps every integer below 2**30.
"""

from micropython import const

# register read addresses; write address = read address | 0x80
_REG_CONFIG = const(0x00)
_REG_RTD_MSB = const(0x01)
_REG_RTD_LSB = const(0x02)
_REG_HIGH_FAULT_MSB = const(0x03)
_REG_HIGH_FAULT_LSB = const(0x04)
_REG_LOW_FAULT_MSB = const(0x05)
_REG_LOW_FAULT_LSB = const(0x06)
_REG_FAULT_STATUS = const(0x07)
_WRITE = const(0x80)

# configuration register bits
_CONFIG_VBIAS = const(0x80)  # D7: V_BIAS on
_CONFIG_AUTO = const(0x40)  # D6: conversion mode auto (1) / normally off (0)
_CONFIG_1SHOT = const(0x20)  # D5: one-shot (self-clearing)
_CONFIG_3WIRE = const(0x10)  # D4: 3-wire (1) / 2- or 4-wire (0)
_CONFIG_FAULT_CYCLE = const(0x0C)  # D3:D2: fault-detection cycle control
_CONFIG_FAULT_CLEAR = const(0x02)  # D1: fault status clear (self-clearing)
_CONFIG_FILTER_50HZ = const(0x01)  # D0: 50 Hz (1) / 60 Hz (0) notch
_FAULT_CYCLE_NONE = const(0x00)
_FAULT_CYCLE_AUTO = const(0x04)  # automatic fault detection with delay
_FAULT_CYCLE_MANUAL_1 = const(0x08)
_FAULT_CYCLE_MANUAL_2 = const(0x0C)
_SELF_CLEARING = const(0x2E)  # D5 one-shot, D3:D2 fault cycle, D1 fault clear

# fault status register bits
_FAULT_HIGH_THRESHOLD = const(0x80)  # D7: RTD high threshold
_FAULT_LOW_THRESHOLD = const(0x40)  # D6: RTD low threshold
_FAULT_REFIN_HIGH = const(0x20)  # D5: REFIN- > 0.85 x V_BIAS
_FAULT_REFIN_LOW_OPEN = const(0x10)  # D4: REFIN- < 0.85 x V_BIAS (FORCE- open)
_FAULT_RTDIN_LOW_OPEN = const(0x08)  # D3: RTDIN- < 0.85 x V_BIAS (FORCE- open)
_FAULT_OVUV = const(0x04)  # D2: overvoltage / undervoltage
_FAULT_CYCLE_POLLS = const(100)
_FAULT = const(-0x1000001)  # firmware.drivers.FAULT (tests/firmware/test_fw_consts.py checks)


def _bad(arg, v):
    return ValueError("MAX31865 %s %r" % (arg, v))


class MAX31865:
    """One MAX31865 on a shared SPI bus.

    ``rref_mohm`` is the reference resistor in milliohm (430 ohm on the usual
    Pt100 breakouts, 400 ohm in the datasheet), ``wires`` 2, 3 or 4,
    ``filter_hz`` 50 or 60. The constructor leaves the chip converting
    continuously (V_BIAS on, auto mode) after one automatic fault-detection
    cycle.
    """

    # transfer buffers shared by all instances: transfers never interleave
    # (one thread, no interrupt handler touches a driver), and RAM is scarce
    _tx = bytearray(3)
    _rx = bytearray(3)
    _t2 = bytearray(2)
    _r2 = bytearray(2)

    SPI = True  # ``select`` is the chip-select pin (firmware/drivers.py)
    OPTIONS = ("rref_mohm", "wires", "filter_hz")

    def __init__(self, spi, cs, *, rref_mohm=430000, wires=3, filter_hz=50):
        # ValueError("MAX31865 <argument> <value>"): wires 2, 3 or 4, filter_hz 50 or 60,
        # rref_mohm 100000..10000000
        if wires not in (2, 3, 4):
            raise _bad("wires", wires)
        if filter_hz not in (50, 60):
            raise _bad("filter_hz", filter_hz)
        if not 100000 <= rref_mohm <= 10000000:
            raise _bad("rref_mohm", rref_mohm)
        self._spi = spi
        self._cs = cs
        self.rref_mohm = rref_mohm
        self.last_fault = 0  # fault status byte of the last FAULT sample()
        # R/R0*1e7 = code * rref_mohm * 100 / 2**15 (R0 = 100 ohm), split so
        # that no product reaches 2**30
        k = rref_mohm * 100
        self._kh = k >> 15
        self._kl = k & 0x7FFF
        base = _CONFIG_VBIAS | (_CONFIG_3WIRE if wires == 3 else 0) | (
            _CONFIG_FILTER_50HZ if filter_hz == 50 else 0)
        cs.value(1)
        # the filter may only change while not converting automatically
        self.configuration = base
        self.last_fault_cycle_status = self.run_fault_detection()
        self.clear_fault()
        self.configuration = base | _CONFIG_AUTO

    # --- register access -------------------------------------------------
    def _transfer(self, tx, rx):
        """One chip-select frame: write ``tx``, reading into ``rx`` unless it is None."""
        cs = self._cs
        cs.value(0)
        try:
            if rx is None:
                self._spi.write(tx)
            else:
                self._spi.write_readinto(tx, rx)
        finally:
            cs.value(1)

    def read_register(self, reg):
        """One register's value (reg is the read address 0x00..0x07)."""
        self._t2[0] = reg
        self._t2[1] = 0
        self._transfer(self._t2, self._r2)
        return self._r2[1]

    def write_register(self, reg, value):
        tx = self._t2
        tx[0] = reg | _WRITE
        tx[1] = value
        self._transfer(tx, None)

    # --- configuration (datasheet names) ---------------------------------
    # Every configuration write is built from ``_conf``, the configuration the
    # driver set (V_BIAS, auto, wiring, filter), never from a read-back: a bus
    # error that corrupts a read must not switch V_BIAS off or change the
    # filter or wiring through a read-modify-write.
    @property
    def configuration(self):
        return self.read_register(_REG_CONFIG)

    @configuration.setter
    def configuration(self, value):
        # self-clearing bits are commands, not part of the configuration to keep
        self._conf = value & ~_SELF_CLEARING
        self.write_register(_REG_CONFIG, value)

    @property
    def fault_detection(self):
        """Fault-detection cycle control bits D3:D2 (FAULT_CYCLE_*); 0 when idle."""
        return self.configuration & _CONFIG_FAULT_CYCLE

    def clear_fault(self):
        """Clear the fault status (D1), writing D5, D3 and D2 as 0 as the datasheet requires."""
        self.write_register(_REG_CONFIG, self._conf | _CONFIG_FAULT_CLEAR)

    def run_fault_detection(self):
        """Automatic fault-detection cycle (D3:D2 = 01); returns the fault status byte.

        The chip must not convert automatically meanwhile; the driver's
        configuration is restored afterwards. OSError if the cycle never ends.
        """
        saved = self._conf
        self.write_register(_REG_CONFIG, (saved & ~_CONFIG_AUTO) | _CONFIG_VBIAS | _FAULT_CYCLE_AUTO)
        for _ in range(_FAULT_CYCLE_POLLS):
            if self.configuration & _CONFIG_FAULT_CYCLE == 0:
                break
        else:
            raise OSError(110, "MAX31865 fault-detection cycle did not finish")
        status = self.fault_status
        self.configuration = saved
        return status

    # --- thresholds --------------------------------------------------------
    def _read15(self, reg):
        return ((self.read_register(reg) << 8) | self.read_register(reg + 1)) >> 1

    def _write15(self, reg, code):
        if not 0 <= code <= 0x7FFF:
            raise _bad("threshold code", code)  # 0..32767
        self.write_register(reg, (code >> 7) & 0xFF)
        self.write_register(reg + 1, (code << 1) & 0xFF)

    @property
    def high_threshold(self):
        """High fault threshold as a 15-bit RTD code."""
        return self._read15(_REG_HIGH_FAULT_MSB)

    @high_threshold.setter
    def high_threshold(self, code):
        self._write15(_REG_HIGH_FAULT_MSB, code)

    @property
    def low_threshold(self):
        """Low fault threshold as a 15-bit RTD code."""
        return self._read15(_REG_LOW_FAULT_MSB)

    @low_threshold.setter
    def low_threshold(self, code):
        self._write15(_REG_LOW_FAULT_MSB, code)

    def code_of(self, ratio):
        """15-bit RTD code of an R/R0*1e7 ratio (start-up use: thresholds)."""
        code = (ratio * 32768 + self.rref_mohm * 50) // (self.rref_mohm * 100)
        return 0 if code < 0 else (0x7FFF if code > 0x7FFF else code)

    def set_limits(self, low_ratio, high_ratio):
        """Fault thresholds from R/R0*1e7 ratios (e.g. ``rtd.ratio_of`` of the plausible range)."""
        self.low_threshold = self.code_of(low_ratio)
        self.high_threshold = self.code_of(high_ratio)

    # --- hot path ------------------------------------------------------------
    def read_rtd(self):
        """RTD MSB:LSB as one 16-bit value: 15-bit ratio code << 1 | fault bit (D0)."""
        tx = self._tx
        tx[0] = _REG_RTD_MSB
        tx[1] = 0
        tx[2] = 0
        self._transfer(tx, self._rx)
        rx = self._rx
        return (rx[1] << 8) | rx[2]

    def sample(self):
        """15-bit ratio code, or FAULT with the fault status byte in ``last_fault`` (cleared on the chip)."""
        raw = self.read_rtd()
        if raw & 1:
            self.last_fault = self.fault_status
            self.clear_fault()
            return _FAULT
        return raw >> 1

    @property
    def rtd(self):
        """15-bit RTD ratio code (ADC code / 2**15 = R_RTD / R_REF)."""
        return self.read_rtd() >> 1

    @property
    def fault_status(self):
        """Fault status register (FAULT_* bits); latched until ``clear_fault``."""
        return self.read_register(_REG_FAULT_STATUS)

    def ratio(self, code):
        """R/R0 * 1e7 of a 15-bit code for a Pt100 (R0 = 100 ohm)."""
        return code * self._kh + ((code * self._kl + 16384) >> 15)
