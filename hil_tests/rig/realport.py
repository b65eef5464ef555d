"""A real board on a serial port (or any pySerial URL) with the Rig's link-level interface (time is wall-clock time)."""
import time

import serial

from hil_tests.rig.harness import LinkClient, SerialReader
from host.board.client import BoardLink


class RealDut(LinkClient):
    real = True
    request_step_ms = 20  # wall-clock time on a real board
    request_timeout_s = 5.0

    def __init__(self, port, baud=115200, key=None):
        """``key``: the board's key (host.board.linkauth.read_key), for commands that change the output."""
        signer = None
        if key:
            from host.board.linkauth import LinkSigner
            signer = LinkSigner(key)
        BoardLink.__init__(self, serial.serial_for_url(port, baud, timeout=0), port, signer)  # a path or a pySerial URL
        self.reader = SerialReader(self.ser, True, link=self)
        self.reader.start()
        self.t0 = time.monotonic()

    @property
    def t_ms(self):
        return int((time.monotonic() - self.t0) * 1000)

    def advance(self, ms, **kw):
        time.sleep(ms / 1000.0)
        self.reader.quiet(0.02, 1.0)

    def run(self, until_ms, **kw):
        self.advance(max(0, until_ms - self.t_ms))

    @property
    def alive(self):
        return True

    def close(self):
        self.reader.stop = True
        self.reader.join(timeout=1)
        self.ser.close()
