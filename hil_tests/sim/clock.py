"""Simulated time: the firmware's ``board.clock`` and the time base of every simulated chip.

Time is an integer count of microseconds. ``sleep_ms`` advances it instantly, so
hours of thermal behaviour run in seconds; bus transfers advance it by their
duration on the wire (``spend_us``), so polling loops inside one firmware cycle
see time pass as on hardware. The test bounds how far time may run: when
``sleep_ms`` would pass ``limit_us``, the clock calls ``gate()`` (the rig's
control channel), which blocks until the test grants more time.

``ticks_ms``/``ticks_diff`` follow MicroPython's ``time`` module exactly,
including the wrap of the tick counter at 2**30 ms (``start_ms`` near the wrap
tests the firmware's wrap handling).

Epochs: ``us`` counts microseconds since the present epoch began, not since
power-on, so that it stays a small int on a 32-bit MicroPython (2**30 us is
17.9 minutes; past that every chip access would compute with heap-allocated
long ints, inside the firmware's heap-locked cycle). When ``us`` reaches
2**29 (8.9 min) at a ``sleep_ms``, a new epoch begins 2**28 us (4.5 min)
before the present moment, rounded to whole milliseconds: ``epoch_ms`` grows
by the shift, ``us`` and the time limit shrink by it, and every part that
keeps times in ``us`` (the chips, the watchdog: ``on_epoch``) moves its
stored times by the same amount (``shift_epoch``). Absolute time is
``epoch_ms`` + ``us`` // 1000 (``now_ms``, ``ms_at``), the same on every
interpreter; the shift is exact (whole milliseconds, whole conversion periods).
"""
from hil_tests.sim.buses import hardware_begin, hardware_end

TICKS_PERIOD = 1 << 30
TICKS_MAX = TICKS_PERIOD - 1
TICKS_HALF = TICKS_PERIOD // 2
EPOCH_US = 1 << 29  # a new epoch begins once ``us`` reaches this
EPOCH_KEEP_US = 1 << 28  # the new epoch starts this long before the present moment
_US_CAP = (1 << 30) - 1  # the largest small int: a limit beyond the epoch's reach is capped here
_CAP_MS = _US_CAP // 1000


class SimClock:
    def __init__(self, start_ms=0):
        self.us = 0  # simulated time since the present epoch began (power-on is epoch 0)
        self.epoch_ms = 0  # power-on to the present epoch's start, in ms
        self.start_ms = start_ms
        self.limit_us = 0  # in the present epoch's us (tests may set a huge one directly)
        self.limit_ms = None  # the granted time since power-on (grant), when the rig set it
        self.gate = None
        self.watchdog = None  # a SimWDT checked whenever the firmware sleeps
        self.slept_ms = 0
        self.epochs = 0
        self._listeners = []

    def on_epoch(self, part):
        """``part.shift_epoch(shift_us)`` is called at each new epoch (before ``us`` moves)."""
        self._listeners.append(part)

    def grant(self, until_ms):
        """Time may run to ``until_ms`` since power-on (the rig's control channel)."""
        self.limit_ms = until_ms
        self._limit()

    def _limit(self):
        dm = self.limit_ms - self.epoch_ms
        self.limit_us = dm * 1000 if dm < _CAP_MS else _US_CAP  # small ints only: runs in the locked cycle

    def _new_epoch(self):
        shift_ms = (self.us - EPOCH_KEEP_US) // 1000
        shift = shift_ms * 1000
        hardware_begin()  # the chips' side of the shift runs unlocked, as their bus work does
        try:
            for part in self._listeners:
                part.shift_epoch(shift)
        finally:
            hardware_end()
        self.us -= shift
        self.epoch_ms += shift_ms
        self.epochs += 1
        if self.limit_ms is None:
            self.limit_us -= shift
        else:
            self._limit()

    def ms_at(self, us):
        """Milliseconds since power-on at ``us`` of the present epoch."""
        return self.epoch_ms + us // 1000

    def abs_us(self):
        """Microseconds since power-on (a long int on a 32-bit board after 17.9 min: reports only)."""
        return self.epoch_ms * 1000 + self.us

    # --- the firmware's interface (firmware/board.py) ---------------------
    def ticks_ms(self):
        return (self.start_ms + self.epoch_ms + self.us // 1000) & TICKS_MAX

    def ticks_diff(self, a, b):
        return ((a - b + TICKS_HALF) & TICKS_MAX) - TICKS_HALF

    def ticks_add(self, a, d):
        return (a + d) & TICKS_MAX

    def sleep_ms(self, ms):
        if ms <= 0:
            return
        self.slept_ms += ms
        if self.watchdog is not None:
            self.watchdog.check()
        if self.us >= EPOCH_US:
            self._new_epoch()
        target = self.us + ms * 1000
        while target > self.limit_us and self.gate is not None:
            self.us = self.limit_us
            self.gate()
        self.us = target

    # --- the rig's side ---------------------------------------------------
    def spend_us(self, us):
        """Time taken by a bus transfer (never blocks on the gate: a transfer cannot be paused)."""
        self.us += us

    def now_ms(self):
        """Milliseconds since power-on (not wrapped)."""
        return self.epoch_ms + self.us // 1000


class WallClock:
    """Real time for the chips of a board that runs on the interpreter's own clock (the flashed
    board of scenario 5 uses firmware.board.SystemClock): same ``us``/``spend_us`` interface."""

    def __init__(self):
        import time
        self._time = time
        self._micro = hasattr(time, "ticks_us")
        self._last = self._raw()
        self._acc = 0
        self.watchdog = None

    def _raw(self):
        t = self._time
        return t.ticks_us() if self._micro else t.monotonic_ns() // 1000

    @property
    def us(self):
        now = self._raw()
        d = self._time.ticks_diff(now, self._last) if self._micro else now - self._last
        self._last = now
        self._acc += d
        return self._acc

    def spend_us(self, us):
        # a simulated transfer returns at once; the chips see the time a real one takes
        self._acc += us

    def on_epoch(self, part):
        pass  # one epoch: real time on a flashed board (scenario 5) runs minutes, not hours

    def ms_at(self, us):
        return us // 1000

    def abs_us(self):
        return self.us

    def now_ms(self):
        return self.us // 1000
