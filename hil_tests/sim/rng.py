"""xorshift32: the same noise sequence on CPython and MicroPython for the same seed (integers only)."""


class XorShift32:
    def __init__(self, seed=1):
        self.s = (seed & 0xFFFFFFFF) or 0x9E3779B9

    def next(self):
        x = self.s
        x ^= (x << 13) & 0xFFFFFFFF
        x ^= x >> 17
        x ^= (x << 5) & 0xFFFFFFFF
        self.s = x
        return x

    def below(self, n):
        return self.next() % n

    def noise(self, sigma):
        """Approximately normal integer noise with standard deviation ``sigma`` (Irwin-Hall of 4 uniforms)."""
        if sigma <= 0:
            return 0
        # sum of 4 uniforms on [0, 4096) has variance 4 * 4096**2 / 12
        s = self.next() & 0xFFF
        s += (self.next() & 0xFFF) + (self.next() & 0xFFF) + (self.next() & 0xFFF)
        return ((s - 8190) * sigma) // 2365
