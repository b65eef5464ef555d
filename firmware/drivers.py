"""The table of sensor drivers (Klipper's sensor table), shared by bootcfg.py and channels.py.

``DRIVERS`` holds the config's ``driver`` names. Every driver class has the same small interface:

- ``Cls(bus, select, *, rref_mohm, wires, filter_hz, ...)``: ``select`` picks the chip on its bus
  (the chip-select pin of an SPI chip, the address of an I2C chip; ``SPI`` says which); the
  settings named in ``OPTIONS`` follow, keyword-only. Calling ``__init__`` again re-initialises
  the chip in place.
- ``sample()``: the newest ratio code, ``NO_DATA`` when no new conversion is ready, or ``FAULT``
  when the chip flags one (its fault byte is then in ``last_fault``, already cleared on the chip).
  Allocation-free: the cycle calls it.
- ``ratio(code)``: R/R0 * 1e7 of a code; ``set_limits(low_ratio, high_ratio)``: the chip's own fault
  thresholds, where it has them.
"""
from micropython import const

DRIVERS = ("max31865", "ads122c04")
# sample() results that are not codes: below every ADS122C04 code (signed 24 bit) and MAX31865 code (>= 0)
NO_DATA = const(-0x1000000)
FAULT = const(-0x1000001)


def driver_class(name):
    """The class of driver ``name`` (one of DRIVERS), imported on first use: a board loads only the
    driver modules its channels name."""
    if name == "max31865":
        from firmware.max31865 import MAX31865
        return MAX31865
    from firmware.ads122c04 import ADS122C04
    return ADS122C04
