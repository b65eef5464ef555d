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
          "max_speed_mm_min": 120000,          # position reports farther apart than this speed allows are
                                               #   refused (docs/protocol.md, "Position and feed"; 0: off)
          "reference_um": None,                # reference position of the (offset, slope) pair
                                               #   (None: the table's; the controller may set it)
          "table_dir": "/tables",              # holds slot files table_a.bin, table_b.bin and 'active'
        }

``buses`` (dict name -> bus)
    SPI buses with the ``machine.SPI`` methods ``write(buf)`` and
    ``write_readinto(wbuf, rbuf)`` (mode 1 or 3, at most 5 MHz for the
    MAX31865); I2C buses with the ``machine.I2C`` methods ``writeto(addr, buf)``,
    ``readfrom_mem_into(addr, memaddr, buf)`` and ``writeto_mem(addr, memaddr, buf)``.
    On CPython, ``firmware.linux_adapters`` adapts ``smbus2.SMBus`` and Linux
    spidev to these signatures. Any bus failure must raise ``OSError``.

``pin(id)`` -> pin
    Returns an output pin object with ``value(v)`` (``machine.Pin`` does), idle
    high; called once per channel at start-up with the channel's ``cs``.

``serial``
    Non-blocking byte stream: ``readinto(buf)`` fills the start of a
    preallocated bytearray and returns the count (0 or None when nothing is
    waiting, never blocks); ``write(buf, n)`` sends the first ``n`` bytes of
    ``buf`` (MicroPython streams, e.g. ``machine.UART``, accept exactly this;
    ``linux_adapters.SerialPort`` adapts pyserial).

``clock``
    ``ticks_ms()``, ``ticks_diff(a, b)`` (a - b, wrap-safe as in MicroPython's
    ``time``) and ``sleep_ms(ms)``. The HIL rig supplies simulated time here.
    ``SystemClock`` below is MicroPython's; ``linux_adapters.MonotonicClock`` CPython's.

``watchdog``
    An object with ``feed()`` (``machine.WDT``), or None. The app feeds it only
    after a complete cycle.

``reset``
    A callable that resets the device (``machine.reset``), or None: then the
    ``reset`` command restarts the app in-process (reload table, hello frame).

``entropy`` (optional)
    A callable returning 4 bytes that differ from boot to boot (a hardware
    random source): the session nonce of the authorisation (firmware/auth.py,
    docs/protocol.md "Sessions"). Without it the port's ``os.urandom`` is used,
    else ``/dev/urandom``, else a hash of the microsecond tick at boot.

Bad configuration raises ``ValueError`` naming the key: on the board
``firmware.bootcfg.load_config`` (terse, ``config <key>: <value>``), on the
host ``host.board.config.load_config`` (the same rules with messages that state
them; ``tcomp flash --config`` and ``tcomp hil --config`` run it); the app lets
it propagate at start-up so a wrong config never runs.
"""

import time


class SystemClock:
    """MicroPython's millisecond tick clock (``linux_adapters.MonotonicClock`` on CPython)."""

    def ticks_ms(self):
        return time.ticks_ms()

    def ticks_diff(self, a, b):
        return time.ticks_diff(a, b)

    def sleep_ms(self, ms):
        time.sleep_ms(ms)


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
        self.entropy = None
