"""xorshift32: the same noise sequence on CPython and MicroPython for the same seed (integers only).

The state is kept as two 16-bit halves so that a step never makes an integer above 2**30: on a
32-bit MicroPython (the emulated Cortex-M3 board, ports/mps2) a larger one is a heap-allocated
long int, and the noise is drawn inside the heap-locked cycle. ``next()`` (used only when a test
injects a bus fault) returns the whole 32-bit word.
"""


class XorShift32:
    def __init__(self, seed=1):
        s = (seed & 0xFFFFFFFF) or 0x9E3779B9
        self.hi = s >> 16
        self.lo = s & 0xFFFF

    def _step(self):
        hi = self.hi
        lo = self.lo
        # x ^= x << 13 (mod 2**32)
        hi ^= ((hi << 13) | (lo >> 3)) & 0xFFFF
        lo ^= (lo << 13) & 0xFFFF
        # x ^= x >> 17
        lo ^= hi >> 1
        # x ^= x << 5 (mod 2**32)
        hi ^= ((hi << 5) | (lo >> 11)) & 0xFFFF
        lo ^= (lo << 5) & 0xFFFF
        self.hi = hi
        self.lo = lo

    @property
    def s(self):
        return (self.hi << 16) | self.lo

    def next(self):
        self._step()
        return (self.hi << 16) | self.lo

    def below(self, n):
        return self.next() % n

    def noise(self, sigma):
        """Approximately normal integer noise with standard deviation ``sigma`` (Irwin-Hall of 4 uniforms)."""
        if sigma <= 0:
            return 0
        # sum of 4 uniforms on [0, 4096) has variance 4 * 4096**2 / 12
        s = 0
        for _ in range(4):
            self._step()
            s += self.lo & 0xFFF
        return ((s - 8190) * sigma) // 2365
