"""$TC line frames: formatting into a preallocated buffer and parsing received lines.

Frame syntax (docs/protocol.md): ``$`` body ``*`` CRC ``\\r\\n``, where body is
comma-separated ASCII fields starting with ``TC`` and CRC is CRC-16/CCITT-FALSE
of the body (the bytes between ``$`` and ``*``) as four upper-case hex digits.

``FrameWriter`` formats numbers digit by digit into its bytearray and hands
``serial.write(buf, n)`` the result: no strings are built. ``LineReader``
collects bytes into a fixed line buffer, checks syntax and CRC and records the
field boundaries, so commands are parsed in place.
"""

from micropython import const

from firmware.crc16 import crc16_ccitt

_HEX = b"0123456789ABCDEF"
_MAX_LINE = const(200)
_MAX_FIELDS = const(16)


class FrameWriter:
    """Builds one frame at a time in ``buf`` and writes it to ``serial``."""

    def __init__(self, serial, size=_MAX_LINE + 8):
        self.serial = serial
        self.buf = bytearray(size)
        self.n = 0
        self.seq = 0  # frame sequence number, 0..65535, one per frame sent

    def begin(self, status, kind):
        """``$TC,<seq>,<status>,<kind>`` with status as 8 hex digits, kind one letter (int)."""
        b = self.buf
        b[0] = 36  # $
        b[1] = 84  # T
        b[2] = 67  # C
        self.n = 3
        self.int(self.seq)
        self.hex(status, 8)
        self.sep()
        b[self.n] = kind
        self.n += 1

    def sep(self):
        self.buf[self.n] = 44  # ,
        self.n += 1

    def raw(self, data):
        """Append bytes (a constant, or a buffer) without a separator."""
        b = self.buf
        n = self.n
        for c in data:
            b[n] = c
            n += 1
        self.n = n

    def text(self, data):
        self.sep()
        self.raw(data)

    def int(self, v):
        """``,<v>`` in decimal."""
        self.sep()
        self._digits(v, 0)

    def fixed(self, v, decimals):
        """``,<v / 10**decimals>`` with exactly ``decimals`` decimals (v an integer)."""
        self.sep()
        self._digits(v, decimals)

    def _digits(self, v, decimals):
        b = self.buf
        if v < 0:
            b[self.n] = 45  # -
            self.n += 1
            v = -v
        # count digits first so they can be written left to right in place
        width = 1
        p = 10
        while p <= v:
            width += 1
            p *= 10
        if width <= decimals:
            width = decimals + 1
        end = self.n + width + (1 if decimals else 0)
        i = end
        d = 0
        while i > self.n:
            i -= 1
            if decimals and d == decimals:
                b[i] = 46  # .
                d += 1
                continue
            b[i] = 48 + v % 10
            v //= 10
            d += 1
        self.n = end

    def hex(self, v, digits):
        """``,<v>`` as ``digits`` upper-case hex digits."""
        self.sep()
        self._hex(v, digits)

    def _hex(self, v, digits):
        b = self.buf
        n = self.n + digits
        i = n
        while i > self.n:
            i -= 1
            b[i] = _HEX[v & 15]
            v >>= 4
        self.n = n

    def hexbytes(self, data, start, end):
        self.sep()
        for i in range(start, end):
            self._hex(data[i], 2)

    def end(self):
        """Close with ``*CRC\\r\\n``, write it, advance the sequence number."""
        crc = crc16_ccitt(self.buf, 1, self.n)
        b = self.buf
        b[self.n] = 42  # *
        self.n += 1
        self._hex(crc, 4)
        b[self.n] = 13
        b[self.n + 1] = 10
        self.n += 2
        self.serial.write(b, self.n)
        self.seq = (self.seq + 1) & 0xFFFF
        return self.n


# LineReader.status values after a complete line
_LINE_OK = const(0)
_LINE_SYNTAX = const(1)  # not "$TC,...*XXXX", bad characters, too many fields
_LINE_CRC = const(2)  # CRC does not match
_LINE_OVERFLOW = const(3)  # longer than _MAX_LINE


class LineReader:
    """Assembles received bytes into lines and validates them.

    ``feed(byte)`` returns True when a line ended; then ``status`` is one of
    LINE_*, and on _LINE_OK ``nf`` fields (the first after ``TC``) are
    available through ``fs``/``fe`` (start/end offsets into ``buf``).
    Bytes before a ``$`` are ignored, so a reader resynchronises on the next
    frame after garbage.
    """

    def __init__(self):
        self.buf = bytearray(_MAX_LINE)
        self.n = 0
        self.active = False
        self.overflow = False
        self.status = _LINE_OK
        self.fs = [0] * _MAX_FIELDS
        self.fe = [0] * _MAX_FIELDS
        self.nf = 0

    def reset(self):
        self.n = 0
        self.active = False
        self.overflow = False

    def feed(self, c):
        if c == 36:  # $ always starts a new line (resynchronisation)
            cut = self.active and self.n > 0
            self.active = True
            self.n = 0
            self.overflow = False
            if cut:  # an unfinished line was cut off by this new one: report it as bad
                self.status = _LINE_SYNTAX
                return True
            return False
        if not self.active:
            if c == 10 or c == 13:
                return False
            # garbage outside a frame: report once at its end of line
            self.active = True
            self.n = 0
            self.overflow = False
            self.buf[0] = 0  # marks "did not start with $"
            self.n = 1
            return False
        if c == 13:
            return False
        if c == 10:
            self.active = False
            self._check()
            return True
        if self.n >= _MAX_LINE:
            self.overflow = True
            return False
        self.buf[self.n] = c
        self.n += 1
        return False

    def _check(self):
        b = self.buf
        n = self.n
        if self.overflow:
            self.status = _LINE_OVERFLOW
            return
        self.status = _LINE_SYNTAX
        # body "TC,..." then "*XXXX"
        if n < 8 or b[0] != 84 or b[1] != 67 or b[2] != 44 or b[n - 5] != 42:
            return
        crc = 0
        for i in range(n - 4, n):
            h = _hexval(b[i])
            if h < 0:
                return
            crc = (crc << 4) | h
        end = n - 5
        nf = 0
        s = 3
        for i in range(3, end + 1):
            if i == end or b[i] == 44:
                if nf >= _MAX_FIELDS:
                    return
                self.fs[nf] = s
                self.fe[nf] = i
                nf += 1
                s = i + 1
            elif b[i] < 32 or b[i] > 126 or b[i] == 42 or b[i] == 36:
                return
        if crc16_ccitt(b, 0, end) != crc:
            self.status = _LINE_CRC
            return
        self.nf = nf
        self.status = _LINE_OK

    # --- field access (valid after _LINE_OK) ---------------------------------
    def letter(self, k):
        """The single character of field k, or 0 if it is not one character."""
        s = self.fs[k]
        if self.fe[k] - s != 1:
            return 0
        return self.buf[s]

    def int(self, k, lo, hi):
        """Decimal integer field k within lo..hi, or None (not a number / out of range)."""
        s = self.fs[k]
        e = self.fe[k]
        b = self.buf
        neg = False
        if s < e and b[s] == 45:
            neg = True
            s += 1
        if s >= e or e - s > 10:
            return None
        v = 0
        for i in range(s, e):
            c = b[i] - 48
            if c < 0 or c > 9:
                return None
            v = v * 10 + c
            if v > 2000000000:  # stay a small int on 32-bit ports
                return None
        if neg:
            v = -v
        if v < lo or v > hi:
            return None
        return v

    def hexint(self, k, digits):
        """Field k as exactly ``digits`` hex digits, or -1."""
        s = self.fs[k]
        if self.fe[k] - s != digits:
            return -1
        v = 0
        for i in range(s, s + digits):
            h = _hexval(self.buf[i])
            if h < 0:
                return -1
            v = (v << 4) | h
        return v


def _hexval(c):
    if 48 <= c <= 57:
        return c - 48
    if 65 <= c <= 70:
        return c - 55
    if 97 <= c <= 102:
        return c - 87
    return -1
