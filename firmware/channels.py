"""Sensor channels: read every front end, convert to milli-degC, exclude implausible readings.

A reading is excluded (and the channel flagged faulty) when the chip reports a
fault, the bus raises OSError, the temperature is outside the plausible range,
it changed faster than ``max_rate_mC_per_s`` allows since the last good
reading ("faster than physics"), the raw code has not changed for
``stuck_ms``, or (ADS122C04) no new conversion arrived for a while. A faulty
channel becomes good again after ``_RECOVER_READS`` consecutive readings that
pass every check and agree with each other; a channel whose chip is faulty is
re-initialised every ``_REINIT_MS`` so that a chip that lost power and came back
is configured again.

``read_all`` is the hot path: no allocation, integers below 2**30.
"""

from micropython import const

from firmware import rtd
from firmware.drivers import driver_class

# firmware.drivers' sample() results (tests/firmware/test_fw_consts.py checks the copies)
_NO_DATA = const(-0x1000000)
_FAULT = const(-0x1000001)

# per-channel fault reasons (``Channels.fault``)
_F_CHIP = const(0x01)  # the chip flags a fault (MAX31865: its fault byte in ``chip_status``)
_F_RANGE = const(0x02)  # outside the plausible range
_F_RATE = const(0x04)  # jump faster than max_rate_mC_per_s
_F_STUCK = const(0x08)  # identical raw code for stuck_ms
_F_BUS = const(0x10)  # bus error (OSError) or chip absent
_F_STALE = const(0x20)  # no new conversion for _STALE_MS (ADS122C04)
_F_NEVER = const(0x40)  # no good reading since start-up
FAULT_NAMES = ((_F_CHIP, "chip"), (_F_RANGE, "range"), (_F_RATE, "rate"), (_F_STUCK, "stuck"),
               (_F_BUS, "bus"), (_F_STALE, "stale"), (_F_NEVER, "never"))

_RECOVER_READS = const(3)
_REINIT_MS = const(1000)
_STALE_MS = const(1000)
_NOISE_MC = const(200)  # allowance for conversion noise on top of the physical rate
_RATE_DT_CAP_MS = const(100000)  # beyond this the last good value says nothing
_CAP = const(0x20000000)  # elapsed-time counters saturate here (2**29 ms, 6.2 days)


class Channels:
    """All sensor channels of a validated board config (``firmware.bootcfg.Config``)."""

    def __init__(self, cfg, board, now):
        n = self.n = len(cfg.channels)
        self.cfg = cfg
        self.board = board
        self.names = [c.name for c in cfg.channels]
        self.driver_class = [driver_class(c.driver) for c in cfg.channels]  # the table in firmware/drivers.py
        self.lead = [c.lead_mohm * 100 for c in cfg.channels]  # ratio units (R0 = 100 ohm)
        self.cal = [c.cal_mC for c in cfg.channels]
        self.lo = cfg.plausible_lo_mC
        self.hi = cfg.plausible_hi_mC
        self.rate = cfg.max_rate_mC_per_s
        self.stuck_ms = cfg.stuck_ms
        self.temp = [0] * n  # last good temperature, milli-degC
        self.reading = [0] * n  # last converted reading, good or not
        self.good = [False] * n
        self.have_good = [False] * n
        self.fault = [_F_NEVER] * n
        self.chip_status = [0] * n
        # elapsed milliseconds since an event, saturating at _CAP: timestamps would
        # need wrap-aware arithmetic (MicroPython ticks wrap every 2**30 ms and
        # ticks_diff is only valid for half of that), counters never do
        self.good_ms = [0] * n  # since the last good reading
        self.code = [-1] * n
        self.code_ms = [0] * n  # since the raw code last changed
        self.data_ms = [0] * n  # since the last new conversion
        self.streak = [0] * n
        self.prev = [0] * n
        self.prev_ms = [0] * n  # since the previous reading while recovering
        self.reinit_ms = [0] * n  # since the last (re-)initialisation attempt
        self.last_now = now
        self.drivers: list = [None] * n
        self.pins: list = [None] * n  # chip-select pins of SPI chips, made once
        for i in range(n):
            self._init_driver(i)

    def _init_driver(self, i):
        """(Re-)initialise channel i's driver; False if the chip did not answer (OSError).

        A driver that exists is re-initialised in place (same object, same pin):
        a chip that keeps failing must not churn the heap.
        """
        ch = self.cfg.channels[i]
        buses = self.board.buses
        if ch.bus not in buses:
            raise ValueError("config channel %s: no bus %r" % (ch.name, ch.bus))
        d = self.drivers[i]
        cls = self.driver_class[i]
        if cls.SPI:
            if self.pins[i] is None:
                self.pins[i] = self.board.pin(ch.cs)
            select = self.pins[i]
        else:
            select = ch.address
        options = {}
        for k in cls.OPTIONS:
            options[k] = getattr(ch, k)
        try:
            if d is None:
                self.drivers[i] = cls(buses[ch.bus], select, **options)
            else:
                d.__init__(buses[ch.bus], select, **options)
            return True
        except OSError:
            self.drivers[i] = None
            return False

    def set_thresholds(self):
        """The chips' own fault thresholds (where they have them) from the plausible range."""
        lo = rtd.ratio_of(self.lo)
        hi = rtd.ratio_of(self.hi)
        for i in range(self.n):
            d = self.drivers[i]
            if d is not None:
                try:
                    d.set_limits(lo + self.lead[i], hi + self.lead[i])
                except OSError:
                    pass

    def faulty_mask(self):
        m = 0
        for i in range(self.n):
            if not self.good[i]:
                m |= 1 << i
        return m

    def read_all(self, now, clock):
        """Read and check every channel; returns the mask of faulty channels."""
        dt = clock.ticks_diff(now, self.last_now)
        self.last_now = now
        if dt < 0:
            dt = 0
        elif dt > _CAP:
            dt = _CAP
        m = 0
        good_ms = self.good_ms
        for i in range(self.n):
            # only the counters a channel in this state will look at are advanced
            v = good_ms[i] + dt
            good_ms[i] = v if v < _CAP else _CAP
            if not self.good[i]:
                v = self.prev_ms[i] + dt
                self.prev_ms[i] = v if v < _CAP else _CAP
                v = self.reinit_ms[i] + dt
                self.reinit_ms[i] = v if v < _CAP else _CAP
            f = self._read(i, dt)
            if f < 0:  # no new data this cycle (ADS122C04 between conversions)
                if not self.good[i]:
                    m |= 1 << i
                continue
            self._judge(i, f)
            if not self.good[i]:
                m |= 1 << i
        return m

    def _read(self, i, dt):
        """Raw read of channel i into ``reading``; returns fault bits, or -1 for no new data."""
        d = self.drivers[i]
        if ((d is None or self.fault[i] & (_F_CHIP | _F_BUS | _F_STALE | _F_RANGE))
                and self.reinit_ms[i] >= _REINIT_MS):
            self.reinit_ms[i] = 0
            if not self._init_driver(i):
                return _F_BUS
            d = self.drivers[i]
        if d is None:
            return _F_BUS
        try:
            code = d.sample()
            if code == _FAULT:
                self.chip_status[i] = d.last_fault
                return _F_CHIP
            if code == _NO_DATA:
                v = self.data_ms[i] + dt
                self.data_ms[i] = v if v < _CAP else _CAP
                return _F_STALE if v >= _STALE_MS else -1
            r = d.ratio(code)
        except OSError:
            return _F_BUS
        self.data_ms[i] = 0
        f = 0
        if self.stuck_ms:
            v = self.code_ms[i] + dt
            self.code_ms[i] = v if v < _CAP else _CAP
            if code != self.code[i]:
                self.code[i] = code
                self.code_ms[i] = 0
            elif self.code_ms[i] >= self.stuck_ms:
                f = _F_STUCK
        r -= self.lead[i]
        t = rtd.temperature_mC(r) + self.cal[i]
        self.reading[i] = t
        if t < self.lo or t > self.hi:
            f |= _F_RANGE
        return f

    def _allowed(self, dt_ms):
        if dt_ms > _RATE_DT_CAP_MS:
            return -1
        return (self.rate * dt_ms) // 1000 + _NOISE_MC

    def _judge(self, i, f):
        t = self.reading[i]
        if f == 0 and self.have_good[i]:
            a = self._allowed(self.good_ms[i])
            if a >= 0 and (t - self.temp[i] > a or self.temp[i] - t > a):
                f = _F_RATE
        if f:
            self.fault[i] = f
            self.good[i] = False
            self.streak[i] = 0
            return
        if self.good[i]:
            self.temp[i] = t
            self.good_ms[i] = 0
            return
        # recovering: consecutive agreeing readings before the channel counts again
        if self.streak[i]:
            a = self._allowed(self.prev_ms[i])
            if a < 0 or t - self.prev[i] > a or self.prev[i] - t > a:
                self.streak[i] = 0
        self.streak[i] += 1
        self.prev[i] = t
        self.prev_ms[i] = 0
        if self.streak[i] >= _RECOVER_READS:
            self.good[i] = True
            self.have_good[i] = True
            self.fault[i] = 0
            self.chip_status[i] = 0
            self.temp[i] = t
            self.good_ms[i] = 0
