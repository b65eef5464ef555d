"""The rig's side of the emulated board (QEMU mps2-an385, ports/mps2): runs ON the board.

The firmware's serial link is UART0 of the board file firmware/boards/mps2_an385.py (a real
UART driver of the image, on the pty the controller reads with pyserial); the rig's control
channel is UART1, carrying the same JSON lines the unix-socket channel carries. The chips, buses,
chip-select pins, watchdog and clock are the simulated ones of hil_tests/sim, handed to the
board file's ``make_board`` as a real board's drivers would be.
"""

import machine


class UartControl:
    """The control channel: events out over UART1 (``write``), requests in by a blocking
    ``readline()`` from the rig's named pipe ``requests`` through semihosting (the debug probe's
    channel: one host read per call, whatever the pipe holds), or, without one, from UART1 (it waits
    for an interrupt between polls: the UART's receive interrupt fills the image's ring buffer).

    Why the pipe: QEMU hands the CMSDK UART one received byte per turn of its main loop, and on a
    loaded machine each turn waits for the scheduler: a 200-byte request took 50-70 ms there, the pipe
    takes one read (docs/hil.md, "Where the board's time goes")."""

    def __init__(self, ident, requests=None):
        self.uart = machine.UART(ident, baudrate=115200)
        self.pipe = open(requests, "rb") if requests else None
        self.buf = bytearray(512)
        self.line = bytearray()

    def write(self, data):
        self.uart.write(data)

    def _receive(self, buf):
        """Bytes into ``buf``: 0 when none waits (UART), at least 1 (the pipe blocks)."""
        if self.pipe is not None:
            k = self.pipe.readinto1(buf)
            if not k:
                raise SystemExit(0)  # the rig closed the pipe: it went away
            return k
        return self.uart.readinto(buf)

    def readline(self):
        buf = self.buf
        while True:
            line = self.line
            i = line.find(b"\n")  # a line may already be waiting behind the previous one
            if i >= 0:
                out = bytes(line[:i + 1])
                self.line = line[i + 1:]
                return out
            k = self._receive(buf)
            if k:
                line.extend(memoryview(buf)[:k])
            else:
                machine.idle()


class CountingSerial:
    """The board's UART with byte counts (the rig's ``at`` events report ``tx`` so the controller
    can wait until every byte arrived); allocation-free like the UART itself."""

    def __init__(self, uart):
        self._u = uart
        self.rx_bytes = 0
        self.tx_bytes = 0

    def readinto(self, buf, nbytes=-1):
        k = self._u.readinto(buf) if nbytes < 0 else self._u.readinto(buf, nbytes)
        if k:
            self.rx_bytes += k
        return k

    def any(self):
        return self._u.any()

    def wait_received(self, n):
        """Until ``n`` bytes have arrived since power-up (read by the firmware or waiting in the
        UART's ring): the rig's gate, so that simulated time never runs ahead of serial input QEMU
        is still handing over one byte per main-loop turn."""
        while self.rx_bytes + self._u.any() < n:
            machine.idle()

    def write(self, buf, n=-1):
        if n < 0:
            n = len(buf)
        self._u.write(buf, n)
        self.tx_bytes += n
        return n


def make_board(world, config):
    from firmware.boards.mps2_an385 import make_board as board_file
    wdt = world.watchdog(config["watchdog_ms"]) if config.get("watchdog_ms") else None
    world.clock.watchdog = wdt
    buses = {}
    for ch in config["channels"]:
        name = ch["bus"]
        if name in buses:
            continue
        b = world.bus(name, ch["driver"])
        if hasattr(b, "pins"):
            b.init(1000000, 0, 1, 8)
        else:
            b.init(freq=400000)
            b.timeout = 50000
        buses[name] = b

    def pin(cs):
        p = world.pin(cs)
        p.value(1)
        return p

    board = board_file(config, buses=buses, pin=pin, clock=world.clock, watchdog=wdt)
    board.serial = CountingSerial(board.serial)
    world.uart = board.serial
    return board
