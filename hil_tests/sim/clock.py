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
"""

TICKS_PERIOD = 1 << 30
TICKS_MAX = TICKS_PERIOD - 1
TICKS_HALF = TICKS_PERIOD // 2


class SimClock:
    def __init__(self, start_ms=0):
        self.us = 0  # simulated time since power-on
        self.start_ms = start_ms
        self.limit_us = 0
        self.gate = None
        self.watchdog = None  # a SimWDT checked whenever the firmware sleeps
        self.slept_ms = 0

    # --- the firmware's interface (firmware/board.py) ---------------------
    def ticks_ms(self):
        return (self.start_ms + self.us // 1000) & TICKS_MAX

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
        return self.us // 1000


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

    def now_ms(self):
        return self.us // 1000
