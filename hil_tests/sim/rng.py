"""xorshift32: the same noise sequence on CPython and MicroPython for the same seed (integers only).

The 32-bit state is kept as two 16-bit halves: on a 32-bit port small ints stop at 2**30, and a
32-bit value would be a long int whose every operation allocates, while the simulated chips draw
noise inside the firmware's heap-locked cycle. The sequence is xorshift32's (13, 17, 5) exactly.
"""


class XorShift32:
    def __init__(self, seed=1):
        s = (seed & 0xFFFFFFFF) or 0x9E3779B9
        self.hi = s >> 16
        self.lo = s & 0xFFFF

    def _step(self):
        hi, lo = self.hi, self.lo
        hi ^= ((hi << 13) | (lo >> 3)) & 0xFFFF  # x ^= x << 13 (32 bits)
        lo ^= (lo << 13) & 0xFFFF
        lo ^= hi >> 1  # x ^= x >> 17
        hi ^= ((hi << 5) | (lo >> 11)) & 0xFFFF  # x ^= x << 5
        lo ^= (lo << 5) & 0xFFFF
        self.hi, self.lo = hi, lo

    @property
    def s(self):
        """The state as one 32-bit int (a long int on a 32-bit port: not for the cycle)."""
        return self.hi << 16 | self.lo

    def next(self):
        self._step()
        return self.s

    def below(self, n):
        """next() % n for 0 < n < 2**14, without forming the 32-bit value."""
        self._step()
        return ((self.hi % n) * (0x10000 % n) + self.lo) % n

    def noise(self, sigma):
        """Approximately normal integer noise with standard deviation ``sigma`` (Irwin-Hall of 4 uniforms)."""
        if sigma <= 0:
            return 0
        # sum of 4 uniforms on [0, 4096) (the low 12 bits of the state) has variance 4 * 4096**2 / 12
        s = 0
        for _ in range(4):
            self._step()
            s += self.lo & 0xFFF
        return ((s - 8190) * sigma) // 2365
