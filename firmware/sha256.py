"""SHA-256 (FIPS 180-4) for a MicroPython port built without ``hashlib``.

firmware/auth.py imports ``hashlib.sha256`` when the port has it and this
module otherwise; it has the same ``update``/``digest`` interface (``digest``
finalises, as MicroPython's does). Only commands and uploads use it, never the
cycle. On a 32-bit port the 32-bit words are big ints (small ints stop at
2**30): slow, but only the authorised commands pay for it.
tests/firmware/test_fw_auth.py checks it against hashlib on both interpreters.
"""

import struct

_K = (
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2,
)
_M = 0xFFFFFFFF


def _ror(x, n):
    return ((x >> n) | (x << (32 - n))) & _M


class sha256:  # lower case: hashlib's name, so the board code says sha256() either way
    def __init__(self, data=None):
        self._h = [0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                   0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19]
        self._buf = b""
        self._n = 0
        self._done = False
        if data:
            self.update(data)

    def update(self, data):
        if self._done:
            raise ValueError("hash is final")
        data = self._buf + bytes(data)
        self._n += len(data) - len(self._buf)
        k = len(data) & ~63
        for off in range(0, k, 64):
            self._block(data, off)
        self._buf = data[k:]

    def _block(self, b, off):
        w = list(struct.unpack_from(">16I", b, off))
        for i in range(16, 64):
            x = w[i - 15]
            y = w[i - 2]
            s0 = _ror(x, 7) ^ _ror(x, 18) ^ (x >> 3)
            s1 = _ror(y, 17) ^ _ror(y, 19) ^ (y >> 10)
            w.append((w[i - 16] + s0 + w[i - 7] + s1) & _M)
        a, b_, c, d, e, f, g, h = self._h
        for i in range(64):
            t1 = (h + (_ror(e, 6) ^ _ror(e, 11) ^ _ror(e, 25)) + ((e & f) ^ (~e & g)) + _K[i] + w[i]) & _M
            t2 = ((_ror(a, 2) ^ _ror(a, 13) ^ _ror(a, 22)) + ((a & b_) ^ (a & c) ^ (b_ & c))) & _M
            h, g, f, e, d, c, b_, a = g, f, e, (d + t1) & _M, c, b_, a, (t1 + t2) & _M
        hs = self._h
        for i, v in enumerate((a, b_, c, d, e, f, g, h)):
            hs[i] = (hs[i] + v) & _M

    def digest(self):
        if self._done:
            return self._d
        self._done = True
        n = self._n
        tail = self._buf + b"\x80" + bytes((55 - n) % 64) + struct.pack(">II", n >> 29, (n << 3) & _M)
        for off in range(0, len(tail), 64):
            self._block(tail, off)
        self._d = struct.pack(">8I", *self._h)
        return self._d
