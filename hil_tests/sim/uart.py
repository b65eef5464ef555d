"""The firmware's serial port: this process's stdin/stdout, which the rig connects to a pty.

``readinto(buf)`` never blocks (poll first, then one byte at a time, because
a stream read blocks until its buffer is full); ``write(buf, n)`` sends the
first ``n`` bytes. Neither allocates on MicroPython (``ipoll`` and stream
``write(buf, n)`` are allocation-free), so the cycle can run under heap_lock.
On a USB board the REPL's stdin/stdout is the CDC serial port the controller
opens, so this is also how a real board looks from the outside.
"""

import sys

try:
    import select
except ImportError:  # pragma: no cover
    import uselect as select

_MICROPYTHON = sys.implementation.name == "micropython"


class StdioUART:
    def __init__(self):
        self._poll = select.poll()
        self._poll.register(sys.stdin, select.POLLIN)
        self._b1 = bytearray(1)
        self.rx_bytes = 0
        self.tx_bytes = 0
        if _MICROPYTHON:
            self._in = sys.stdin.buffer
            self._out = sys.stdout.buffer
        else:
            import os
            self._os = os

    def _ready(self):
        if _MICROPYTHON:
            for _ in self._poll.ipoll(0):
                return True
            return False
        return bool(self._poll.poll(0))

    def any(self):
        return 1 if self._ready() else 0

    def readinto(self, buf, nbytes=-1):
        lim = len(buf) if nbytes < 0 else nbytes
        if not _MICROPYTHON:
            if not self._ready():
                return 0
            data = self._os.read(0, lim)
            n = len(data)
            buf[:n] = data
            self.rx_bytes += n
            return n
        k = 0
        b1 = self._b1
        while k < lim and self._ready():
            if not self._in.readinto(b1):
                break
            buf[k] = b1[0]
            k += 1
        self.rx_bytes += k
        return k

    def read(self, n=-1):
        buf = bytearray(256 if n < 0 else n)
        k = self.readinto(buf)
        return bytes(buf[:k]) if k else None

    def write(self, buf, n=-1):
        if n < 0:
            n = len(buf)
        if _MICROPYTHON:
            self._out.write(buf, n)
        else:
            mv = memoryview(buf)[:n]
            while mv:
                k = self._os.write(1, mv)
                mv = mv[k:]
        self.tx_bytes += n
        return n
