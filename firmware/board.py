"""The board interface: everything hardware-specific that ``firmware.app`` needs.

``firmware.app.main(board)`` runs the compensator on any object that has the
attributes below. Nothing in firmware/ creates a bus, a pin, a UART, a timer or
a watchdog itself, so the same code runs on an RP2040 under MicroPython, on a
Linux single-board computer under CPython, and in the hardware-in-the-loop rig
(hil_tests/) against simulated chips, buses, a pty and simulated time.

A board is any object with these attributes (``Board`` below is a plain
container for them):

``config`` (dict)
    Plain data, validated by ``load_config`` (ValueError naming the key on any
    mistake). All quantities are integers in the unit named by the key suffix::

        {
          "channels": [                        # model inputs, in table order
            {"name": "nut",                    # matches the table's sensor name
             "driver": "max31865",             # or "ads122c04"
             "bus": "spi0",                    # key into board.buses
             "cs": 17,                         # MAX31865: chip-select id, passed to board.pin()
                                               #   (None: the bus selects the chip itself, e.g. Linux spidev)
             "rref_mohm": 430000,              # reference resistor, milliohm (430 ohm default)
             "wires": 3,                       # 2, 3 or 4
             "lead_mohm": 0,                   # 2-wire only: total lead resistance subtracted
             "cal_mC": 0,                      # calibration offset added after conversion
             "filter_hz": 50},                 # mains rejection 50 or 60
            {"name": "base", "driver": "ads122c04", "bus": "i2c0",
             "address": 0x40,                  # ADS122C04: 7-bit I2C address 0x40..0x4F
             "rref_mohm": 1620000, "wires": 3, "lead_mohm": 0, "cal_mC": 0,
             "idac_ua": 250},                  # excitation current 10..1500 uA (datasheet steps)
          ],
          "serial": {"mode": "stream",         # "stream" ($TC frames, docs/protocol.md) or "modbus" (RTU slave)
                     "baud": 115200,           # used by the board when it opens the port
                     "address": 1},            # Modbus slave address 1..247
          "plausible_mC": [-20000, 80000],     # readings outside are faults; also the MAX31865 thresholds
          "max_rate_mC_per_s": 2000,           # a faster change is a fault ("jump faster than physics")
          "stuck_ms": 0,                       # identical raw code for this long is a fault (0: off)
          "slew_um_per_s": 5,                  # output rate limit
          "max_offset_um": 300,                # output magnitude limit
          "hold_ms": 60000,                    # hold the last good output this long, then ramp to zero
          "cycle_ms": 100,                     # period of read-convert-evaluate
          "frame_ms": 1000,                    # period of $TC offset frames (stream mode)
          "watchdog_ms": 2000,                 # hardware watchdog timeout (the board creates the WDT)
          "link_timeout_ms": 0,                # no valid controller traffic this long: status LINK (0: off)
          "reference_um": None,                # reference position of the (offset, slope) pair
                                               #   (None: the table's; the controller may set it)
          "table_dir": "/tables",              # holds slot files table_a.bin, table_b.bin and 'active'
        }

``buses`` (dict name -> bus)
    SPI buses with the ``machine.SPI`` methods ``write(buf)`` and
    ``write_readinto(wbuf, rbuf)`` (mode 1 or 3, at most 5 MHz for the
    MAX31865); I2C buses with the ``machine.I2C`` methods ``writeto(addr, buf)``,
    ``readfrom_mem_into(addr, memaddr, buf)`` and ``writeto_mem(addr, memaddr, buf)``.
    On CPython, ``firmware.board_linux`` adapts ``smbus2.SMBus`` and Linux
    spidev to these signatures. Any bus failure must raise ``OSError``.

``pin(id)`` -> pin
    Returns an output pin object with ``value(v)`` (``machine.Pin`` does), idle
    high; called once per channel at start-up with the channel's ``cs``.

``serial``
    Non-blocking byte stream: ``readinto(buf)`` fills the start of a
    preallocated bytearray and returns the count (0 or None when nothing is
    waiting, never blocks); ``write(buf, n)`` sends the first ``n`` bytes of
    ``buf`` (MicroPython streams, e.g. ``machine.UART``, accept exactly this;
    ``board_linux.SerialPort`` adapts pyserial).

``clock``
    ``ticks_ms()``, ``ticks_diff(a, b)`` (a - b, wrap-safe as in MicroPython's
    ``time``) and ``sleep_ms(ms)``. The HIL rig supplies simulated time here.
    ``SystemClock`` below is the real one on both interpreters.

``watchdog``
    An object with ``feed()`` (``machine.WDT``), or None. The app feeds it only
    after a complete cycle.

``reset``
    A callable that resets the device (``machine.reset``), or None: then the
    ``reset`` command restarts the app in-process (reload table, hello frame).

Bad configuration raises ``ValueError``; the app lets it propagate at start-up
so a wrong config never runs.
"""

try:
    from time import ticks_ms as _ticks_ms, ticks_diff as _ticks_diff, sleep_ms as _sleep_ms
except ImportError:  # CPython: no ticks; monotonic time never wraps there
    import time as _time

    def _ticks_ms():
        return _time.monotonic_ns() // 1000000

    def _ticks_diff(a, b):
        return a - b

    def _sleep_ms(ms):
        if ms > 0:
            _time.sleep(ms / 1000)


class SystemClock:
    """The interpreter's own monotonic millisecond clock."""

    def ticks_ms(self):
        return _ticks_ms()

    def ticks_diff(self, a, b):
        return _ticks_diff(a, b)

    def sleep_ms(self, ms):
        _sleep_ms(ms)


class Board:
    """Plain container for the board attributes documented in this module."""

    def __init__(self, config, buses, pin, serial, clock=None, watchdog=None, reset=None):
        self.config = config
        self.buses = buses
        self.pin = pin
        self.serial = serial
        self.clock = clock if clock is not None else SystemClock()
        self.watchdog = watchdog
        self.reset = reset


DRIVERS = ("max31865", "ads122c04")
SERIAL_MODES = ("stream", "modbus")

# Defaults for every optional key; a key not listed here or in the channel
# defaults is rejected so that a typo never silently falls back to a default.
DEFAULTS = {
    "serial": None,
    "plausible_mC": (-20000, 80000),
    "max_rate_mC_per_s": 2000,
    "stuck_ms": 0,
    "slew_um_per_s": 5,
    "max_offset_um": 300,
    "hold_ms": 60000,
    "cycle_ms": 100,
    "frame_ms": 1000,
    "watchdog_ms": 2000,
    "link_timeout_ms": 0,
    "reference_um": None,
    "table_dir": "tables",
}
CHANNEL_DEFAULTS = {
    "cs": None,
    "address": 0x40,
    "rref_mohm": 430000,
    "wires": 3,
    "lead_mohm": 0,
    "cal_mC": 0,
    "filter_hz": 50,
    "idac_ua": 250,
}
SERIAL_DEFAULTS = {"mode": "stream", "baud": 115200, "address": 1}


class Config:
    """Validated configuration: the dict's keys as integer attributes."""


class ChannelConfig:
    """Validated configuration of one sensor channel."""


def _int(where, value, lo, hi):
    # bool is an int in Python; a True where a number belongs is a typo
    if not isinstance(value, int) or isinstance(value, bool):
        raise ValueError("config %s: expected an integer, got %r" % (where, value))
    if value < lo or value > hi:
        raise ValueError("config %s: %d outside %d..%d" % (where, value, lo, hi))
    return value


def _check_keys(where, d, allowed):
    if not isinstance(d, dict):
        raise ValueError("config %s: expected a dict" % where)
    for k in d:
        if k not in allowed:
            raise ValueError("config %s: unknown key %r" % (where, k))


def _channel(i, ch):
    where = "channels[%d]" % i
    allowed = ("name", "driver", "bus") + tuple(CHANNEL_DEFAULTS)
    _check_keys(where, ch, allowed)
    c = ChannelConfig()
    for k in ("name", "driver", "bus"):
        if k not in ch:
            raise ValueError("config %s.%s: missing" % (where, k))
    name = ch["name"]
    if not isinstance(name, str) or not name or "," in name or "*" in name:
        raise ValueError("config %s.name: expected a non-empty string without ',' or '*'" % where)
    c.name = name
    if ch["driver"] not in DRIVERS:
        raise ValueError("config %s.driver: %r is not one of %s" % (where, ch["driver"], ", ".join(DRIVERS)))
    c.driver = ch["driver"]
    c.bus = ch["bus"]
    get = lambda k: ch[k] if k in ch else CHANNEL_DEFAULTS[k]
    c.cs = get("cs")
    c.address = _int(where + ".address", get("address"), 0x40, 0x4F) if c.driver == "ads122c04" else get("address")
    c.rref_mohm = _int(where + ".rref_mohm", get("rref_mohm"), 100000, 10000000)
    c.wires = _int(where + ".wires", get("wires"), 2, 4)
    c.lead_mohm = _int(where + ".lead_mohm", get("lead_mohm"), 0, 50000)
    if c.lead_mohm and c.wires != 2:
        raise ValueError("config %s.lead_mohm: lead correction applies to 2-wire sensors only (wires=%d)" % (where, c.wires))
    c.cal_mC = _int(where + ".cal_mC", get("cal_mC"), -10000, 10000)
    c.filter_hz = _int(where + ".filter_hz", get("filter_hz"), 50, 60)
    if c.filter_hz not in (50, 60):
        raise ValueError("config %s.filter_hz: must be 50 or 60" % where)
    c.idac_ua = _int(where + ".idac_ua", get("idac_ua"), 10, 1500)
    return c


def load_config(d):
    """Validate a board config dict; returns a ``Config`` or raises ValueError."""
    allowed = ("channels",) + tuple(DEFAULTS)
    _check_keys("", d, allowed)
    cfg = Config()
    chans = d.get("channels")
    if not isinstance(chans, (list, tuple)) or not chans:
        raise ValueError("config channels: expected a non-empty list")
    if len(chans) > 16:
        raise ValueError("config channels: at most 16 channels, got %d" % len(chans))
    cfg.channels = [_channel(i, ch) for i, ch in enumerate(chans)]
    names = [c.name for c in cfg.channels]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ValueError("config channels[%d].name: %r used twice" % (i, n))
    get = lambda k: d[k] if k in d else DEFAULTS[k]
    ser = get("serial") or {}
    _check_keys("serial", ser, tuple(SERIAL_DEFAULTS))
    mode = ser.get("mode", "stream")
    if mode not in SERIAL_MODES:
        raise ValueError("config serial.mode: %r is not one of %s" % (mode, ", ".join(SERIAL_MODES)))
    cfg.serial_mode = mode
    cfg.baud = _int("serial.baud", ser.get("baud", 115200), 1200, 4000000)
    cfg.modbus_address = _int("serial.address", ser.get("address", 1), 1, 247)
    pl = get("plausible_mC")
    if not isinstance(pl, (list, tuple)) or len(pl) != 2:
        raise ValueError("config plausible_mC: expected [low, high]")
    cfg.plausible_lo_mC = _int("plausible_mC[0]", pl[0], -200000, 850000)
    cfg.plausible_hi_mC = _int("plausible_mC[1]", pl[1], -200000, 850000)
    if cfg.plausible_lo_mC >= cfg.plausible_hi_mC:
        raise ValueError("config plausible_mC: low must be below high")
    cfg.max_rate_mC_per_s = _int("max_rate_mC_per_s", get("max_rate_mC_per_s"), 1, 1000000)
    cfg.stuck_ms = _int("stuck_ms", get("stuck_ms"), 0, 86400000)
    cfg.slew_um_per_s = _int("slew_um_per_s", get("slew_um_per_s"), 1, 10000)
    cfg.max_offset_um = _int("max_offset_um", get("max_offset_um"), 1, 100000)
    cfg.hold_ms = _int("hold_ms", get("hold_ms"), 0, 86400000)
    cfg.cycle_ms = _int("cycle_ms", get("cycle_ms"), 1, 60000)
    cfg.frame_ms = _int("frame_ms", get("frame_ms"), 0, 3600000)
    cfg.watchdog_ms = _int("watchdog_ms", get("watchdog_ms"), 0, 8388)
    cfg.link_timeout_ms = _int("link_timeout_ms", get("link_timeout_ms"), 0, 3600000)
    ref = get("reference_um")
    cfg.reference_um = None if ref is None else _int("reference_um", ref, -10000000, 10000000)
    td = get("table_dir")
    if not isinstance(td, str) or not td:
        raise ValueError("config table_dir: expected a directory path")
    cfg.table_dir = td
    if cfg.watchdog_ms and cfg.watchdog_ms < 2 * cfg.cycle_ms:
        raise ValueError("config watchdog_ms: %d is shorter than two cycles (cycle_ms=%d)" % (cfg.watchdog_ms, cfg.cycle_ms))
    return cfg
