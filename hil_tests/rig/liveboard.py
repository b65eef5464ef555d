"""A simulated board that runs in real time for a user (``tcomp board``): the rig's firmware process
(hil_tests/rig/harness.py ``Rig``) with its serial port left to whoever opens the pty (``tcomp monitor``,
``tcomp record``, ``tcomp linuxcnc``, a PLC's Modbus master), time granted at the wall clock's pace and
the sensors heading for the temperatures the caller names.

Unlike the tests' rig, nobody on this side reads the serial port. A real UART whose receiver nobody
services loses bytes; the pty instead keeps them, and once its buffer is full the firmware's write
blocks and simulated time stops. So bytes that wait unread in the pty for ``STALE_S`` are dropped
(``tcflush``): a client that opens the port later reads the board's present frames, not an hour-old
backlog, and the board never stalls for want of a reader.
"""
import fcntl
import os
import termios
import time

from hil_tests.rig import interpreters
from hil_tests.rig.harness import QEMU_IMAGE, Rig, RigError

STALE_S = 1.0  # unread serial bytes older than this are dropped (a receiver nobody services)


def board_problem(interpreter):
    """Why the board of ``interpreter`` cannot start (a sentence naming the make target), or None."""
    if interpreter == "micropython":
        try:
            it = interpreters.get()
        except interpreters.InterpreterMissing as exc:
            return str(exc)
        if not it.exists():
            return ("the 32-bit MicroPython is not built (%s): run `make setup` (its target %s builds it), "
                    "or set %s to a MicroPython executable" % (it.path, "ports/linux32/build/micropython",
                                                               interpreters.ENV)) if it.kind == "linux32" else \
                ("MicroPython (%s) not found at %s: %s" % (it.kind, it.path, it.about))
        return None
    if interpreter == "qemu":
        import shutil
        if shutil.which("qemu-system-arm") is None:
            return "qemu-system-arm is not installed: run `make setup` (its target sysdeps installs it)"
        if not os.path.exists(QEMU_IMAGE):
            return ("the emulated Cortex-M3 board image is not built (%s): run `make qemu-image` "
                    "(part of `make setup`)" % QEMU_IMAGE)
        return None
    return "interpreter must be micropython or qemu, not %r" % (interpreter,)


class LiveBoard:
    """``start()``; then ``step(run_ms)`` as often as the caller likes (simulated time follows); ``close()``.

    ``key``: the board key provisioned into its flash (b"": none, every signed command is refused).
    ``table``: the table in slot A (None: a board without a table)."""

    def __init__(self, config, table=None, interpreter="micropython", temps=None, key=b"", noise_uohm=2000,
                 dynamic=False):
        heap = None
        if interpreter == "micropython" and dynamic:
            heap = interpreters.heap("rig_dynamic")  # the dynamic table's filters need more (interpreters.HEAPS)
        self.rig = Rig(config, table, interpreter=interpreter, temps=temps, noise_uohm=noise_uohm, open_port=False,
                       key=key, heap=heap)
        self.port = self.rig.port
        self.t0_ms = 0
        self._unread_since = None
        self._tx = self._tx_seen = 0  # bytes the firmware wrote since power-up (the rig's "at" events)
        self._waiting = 0
        self.dropped_bytes = 0

    def start(self):
        self.rig.start()
        self.t0_ms = self.rig.t_ms
        return self

    @property
    def t_ms(self):
        """Simulated milliseconds since the board started."""
        return self.rig.t_ms - self.t0_ms

    def head_for(self, at_ms, temps):
        """From now on the sensors ramp linearly to ``temps`` (deg C by channel name) at board time ``at_ms``."""
        self.rig.ramp(self.t0_ms + int(at_ms), temps)

    def jump(self, temps):
        self.rig.jump(temps)

    def step(self, until_ms):
        """Let the board run to ``until_ms`` (board time, ms since start); drop serial bytes nobody read."""
        if until_ms > self.t_ms:
            ev = self.rig.run(self.t0_ms + int(until_ms), sync=False)
            self._tx = ev.get("tx", self._tx)
        self._drop_stale()

    def _drop_stale(self):
        """Flush the pty's input when nothing of it was read for STALE_S (bytes written since the last look
        minus the growth of the queue: what a reader took)."""
        waiting = _unread(self.rig.slave)
        now = time.monotonic()
        taken = (self._tx - self._tx_seen) - (waiting - self._waiting)
        self._tx_seen, self._waiting = self._tx, waiting
        if not waiting or taken > 0:
            self._unread_since = None if not waiting else now
        elif self._unread_since is None:
            self._unread_since = now
        elif now - self._unread_since >= STALE_S:
            termios.tcflush(self.rig.slave, termios.TCIFLUSH)
            self.dropped_bytes += waiting
            self._unread_since = None
            self._waiting = 0

    @property
    def alive(self):
        return self.rig.alive

    def log(self):
        return self.rig.log()

    def close(self):
        self.rig.close()


def _unread(fd):
    """Bytes waiting in the pty for a reader of the controller's side."""
    buf = bytearray(4)
    fcntl.ioctl(fd, termios.FIONREAD, buf)
    return int.from_bytes(buf, "little")


__all__ = ["LiveBoard", "RigError", "board_problem"]
