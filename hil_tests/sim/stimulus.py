"""What the simulated sensors measure: one ``Rtd`` per sensor, driven by the test.

The test sets temperatures at points of simulated time; in between the
resistance follows a straight line (``ramp_to``), computed in integer
micro-ohm so that a chip conversion allocates nothing (MicroPython
``heap_lock``). The float IEC 60751 relation is evaluated only at the ramp
ends, in the control channel. Over a ramp of a few kelvin the straight line
differs from the curve by less than 1e-5 ohm, three orders below the
MAX31865's LSB.

Sensor conditions a test can inject: ``open`` (broken element: no current,
the chip sees full scale), ``short`` (element bridged: lead resistance only),
``stuck`` (the resistance freezes at its present value), each cleared by ``ok``.
"""

from hil_tests.sim.iec60751 import resistance_uohm
from hil_tests.sim.intmath import muldiv
from hil_tests.sim.rng import XorShift32

OK = 0
OPEN = 1
SHORT = 2
STUCK = 3
CONDITIONS = {"ok": OK, "open": OPEN, "short": SHORT, "stuck": STUCK}
OPEN_UOHM = 1 << 40  # "infinite" for a broken element
SHORT_UOHM = 50000  # 0.05 ohm of bridge and lead


class Rtd:
    def __init__(self, name, t_c=20.0, noise_uohm=0, seed=1, lead_uohm=0):
        self.name = name
        self.t0_ms = 0
        self.r0 = resistance_uohm(t_c)
        self.t1_ms = 0
        self.r1 = self.r0
        self.t_c = t_c  # temperature at the end of the present ramp (for reports)
        self.noise = noise_uohm
        self.rng = XorShift32(seed)
        self.lead = lead_uohm  # total lead resistance in series (2-wire)
        self.condition = OK
        self.stuck_at = 0

    def set_now(self, now_ms, t_c):
        """Step to ``t_c`` at ``now_ms`` (a jump)."""
        r = resistance_uohm(t_c)
        self.t0_ms = now_ms
        self.r0 = r
        self.t1_ms = now_ms
        self.r1 = r
        self.t_c = t_c

    def ramp_to(self, now_ms, until_ms, t_c):
        """Straight line from the present resistance at ``now_ms`` to ``t_c`` at ``until_ms``."""
        r = self.uohm(now_ms)
        self.t0_ms = now_ms
        self.r0 = r
        self.t1_ms = until_ms if until_ms > now_ms else now_ms
        self.r1 = resistance_uohm(t_c)
        self.t_c = t_c

    def uohm(self, t_ms):
        """Noise-free element resistance at ``t_ms``."""
        if t_ms >= self.t1_ms:
            return self.r1
        if t_ms <= self.t0_ms:
            return self.r0
        d = self.r1 - self.r0
        span = self.t1_ms - self.t0_ms
        if d >= 0:  # floor(d * dt / span), as Python's // (muldiv: no long ints on a 32-bit board)
            return self.r0 + muldiv(d, t_ms - self.t0_ms, span)
        return self.r0 - muldiv(-d, t_ms - self.t0_ms, span, span - 1)

    def set_condition(self, cond, now_ms):
        if cond == STUCK and self.condition != STUCK:
            self.stuck_at = self.measured(now_ms)
        self.condition = cond

    def measured(self, t_ms):
        """Resistance between the chip's inputs at ``t_ms`` (condition, leads and noise included)."""
        c = self.condition
        if c == OPEN:
            return OPEN_UOHM
        if c == SHORT:
            return SHORT_UOHM + self.lead
        if c == STUCK:
            return self.stuck_at
        return self.uohm(t_ms) + self.lead + self.rng.noise(self.noise)
