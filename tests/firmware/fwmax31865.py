"""MAX31865 operations only the tests need, kept off the board: fault names, one configuration bit,
a one-shot conversion. They go through the driver's own ``configuration`` and ``_conf`` (the
configuration it keeps, never the chip's read-back)."""
from firmware import max31865 as mx

FAULT_NAMES = (
    (mx._FAULT_HIGH_THRESHOLD, "rtd_high_threshold"),
    (mx._FAULT_LOW_THRESHOLD, "rtd_low_threshold"),
    (mx._FAULT_REFIN_HIGH, "refin_high"),
    (mx._FAULT_REFIN_LOW_OPEN, "refin_low_force_open"),
    (mx._FAULT_RTDIN_LOW_OPEN, "rtdin_low_force_open"),
    (mx._FAULT_OVUV, "over_under_voltage"),
)


def decode_faults(status):
    """Names of the faults set in a fault status byte."""
    return [name for bit, name in FAULT_NAMES if status & bit]


def config_bit(d, mask):
    """True if the configuration bits in ``mask`` (e.g. V_BIAS 0x80) are set on the chip."""
    return bool(d.configuration & mask)


def set_config_bit(d, mask, on):
    """Set or clear configuration bits from the kept configuration (self-clearing bits never re-written)."""
    d.configuration = (d._conf | mask) if on else (d._conf & ~mask)


def one_shot(d):
    """Start a single conversion (D5) with V_BIAS already on."""
    d.write_register(mx._REG_CONFIG, d._conf | mx._CONFIG_1SHOT)
