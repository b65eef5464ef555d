"""The device under test's process: simulated board around the unmodified firmware.

Run as ``micropython dut.py SPEC.json`` (MICROPYPATH = repo root and
hil_tests/mp) or ``python dut.py SPEC.json``, with stdin/stdout on the pty
the controller opens. SPEC holds the firmware's board ``config``, the
control socket path ``ctl``, initial temperatures, sensor noise and seed.

On the emulated board (``tcomp hil --interpreter qemu``) this runs on the board
itself, from the image's ROM: the spec names the board file (``board``) and
the control channel's events go out on UART1 (``ctl`` = ``uart:1``) and its requests
come from the named pipe ``ctl_requests`` through semihosting (hil_tests/rig/qemu_board.py).

The control channel (a unix socket, one JSON object per line) is served
only while the firmware sleeps past the time the test granted: the firmware
never sees it. Requests (``op``): ``run`` (grant time up to ``until_ms``,
ramping sensors linearly to ``temps`` meanwhile; ``ramp``: a ramp request's
``until_ms`` and ``temps`` taken first; ``rx``: on the emulated board, wait until that many
serial bytes have reached the UART since power-up; ``gc``: collect and report
``mem_free``; ``lock``: run under micropython.heap_lock), ``ramp`` (head
linearly for ``temps`` at ``until_ms``, without running), ``jump`` (step
temperatures now), ``sensor`` (condition ok/open/short/stuck), ``chip``
(``present``, ``ovuv``, ``force_open``), ``bus`` (inject ``kind`` for
``count`` transfers to ``target``), ``stats``, ``quit``. Replies (``ev``):
``at`` (time reached, with statistics), ``stats``, ``crash``, ``watchdog``.
"""

import gc
import sys

from hil_tests.sim.buses import HEAP_LOCKED

try:
    import json
except ImportError:  # the QEMU board image (ports/mps2) has no json module
    from hil_tests.rig import minijson as json

try:
    import micropython
except ImportError:
    micropython = None

MICRO = sys.implementation.name == "micropython"


def _connect(path, requests=None):
    if path.startswith("uart:"):  # the emulated board: events over a UART, requests from a pipe (qemu_board.py)
        from hil_tests.rig.qemu_board import UartControl
        c = UartControl(int(path[5:]), requests)
        return c, c
    import socket
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    if MICRO:
        import struct
        s.connect(struct.pack("H", 1) + path.encode() + b"\0")
        return s, s
    s.connect(path)
    return s, s.makefile("rb")


class Control:
    def __init__(self, path, world, requests=None):
        self.sock, self.rf = _connect(path, requests)
        self.world = world
        self.locked = False
        self.lock_failures = 0
        self.gates = 0

    def send(self, obj):
        data = (json.dumps(obj) + "\n").encode()
        if MICRO:
            self.sock.write(data)
        else:
            self.sock.sendall(data)

    def mem(self, collect):
        if collect:
            gc.collect()
        try:
            return gc.mem_free()
        except AttributeError:  # CPython
            return -1

    def gate(self):
        """Time reached the grant: report, then obey requests until the next ``run``."""
        if self.locked:
            HEAP_LOCKED[0] = False
            micropython.heap_unlock()
            self.locked = False
        self.gates += 1
        w = self.world
        self.send({"ev": "at", "t_ms": w.clock.now_ms(), "ticks_ms": w.clock.ticks_ms(), "mem_free": self.mem(False),
                   "tx": w.uart.tx_bytes if w.uart is not None else 0})
        while True:
            line = self.rf.readline()
            if not line:
                raise SystemExit(0)  # the test went away
            m = json.loads(line)
            op = m.get("op")
            if op == "run":
                if "ramp" in m:  # a ramp sent with the run (harness.Rig.ramp): as a ramp request first
                    r = m["ramp"]
                    w.ramp(r["until_ms"], r["temps"])
                if "rx" in m and hasattr(w.uart, "wait_received"):  # the emulated board (qemu_board.py)
                    w.uart.wait_received(m["rx"])
                until = m["until_ms"]
                if "temps" in m:
                    w.ramp(until, m["temps"])
                w.clock.grant(until)
                if m.get("gc"):
                    self.send({"ev": "mem", "mem_free": self.mem(True)})
                if m.get("lock") and micropython is not None and hasattr(micropython, "heap_lock"):
                    gc.collect()
                    micropython.heap_lock()
                    self.locked = True
                    HEAP_LOCKED[0] = True  # the simulated chips work unlocked (hil_tests/sim/buses.py)
                return
            if op == "jump":
                w.jump(m["temps"])
            elif op == "ramp":
                w.ramp(m["until_ms"], m["temps"])
            elif op == "sensor":
                from hil_tests.sim.stimulus import CONDITIONS
                w.rtds[m["name"]].set_condition(CONDITIONS[m["condition"]], w.clock.now_ms())
            elif op == "chip":
                c = w.chips[m["name"]]
                if "present" in m:
                    c.power(m["present"])
                if "ovuv" in m:
                    c.ovuv = m["ovuv"]
                if "force_open" in m:
                    c.force_open = m["force_open"]
            elif op == "bus":
                b = w.buses[m["bus"]]
                if m.get("kind", "none") == "none":
                    b.faults.clear()
                else:
                    b.faults.inject(m["kind"], m.get("count", 1), m.get("target"))
            elif op == "stats":
                st = w.stats()
                st["ev"] = "stats"
                st["t_ms"] = w.clock.now_ms()
                st["epochs"] = w.clock.epochs  # the simulators' clock epochs begun (hil_tests/sim/clock.py)
                st["mem_free"] = self.mem(m.get("gc", False))
                st["uart"] = [w.uart.rx_bytes, w.uart.tx_bytes] if w.uart is not None else None
                st["wdt_feeds"] = w.wdt.feeds if w.wdt is not None else None
                st["impl"] = sys.implementation.name
                self.send(st)
            elif op == "quit":
                raise SystemExit(0)
            else:
                self.send({"ev": "error", "error": "unknown op %r" % (op,)})


def make_board(world, config, board_file=None):
    if board_file == "mps2_an385":  # the emulated board: its board file, UART0 (qemu_board.py)
        from hil_tests.rig.qemu_board import make_board as qemu_make_board
        return qemu_make_board(world, config)
    from firmware.board import Board
    from hil_tests.sim.uart import StdioUART
    uart = StdioUART()
    world.uart = uart
    wdt = world.watchdog(config["watchdog_ms"]) if config.get("watchdog_ms") else None
    world.clock.watchdog = wdt
    names = []
    for ch in config["channels"]:
        if ch["bus"] not in names:
            names.append(ch["bus"])
    buses = {}
    if MICRO:
        import machine  # hil_tests/mp/machine.py: the simulated hardware
        for name in names:
            b = world.buses[name]
            if hasattr(b, "pins"):
                buses[name] = machine.SPI(b.ident, baudrate=1000000, polarity=0, phase=1)
            else:
                buses[name] = machine.I2C(b.ident, freq=400000)

        def pin(cs):
            return machine.Pin(cs, machine.Pin.OUT, value=1)
    else:
        from firmware.linux_adapters import SMBusI2C
        from hil_tests.sim.buses import SMBus
        for name in names:
            b = world.buses[name]
            buses[name] = b if hasattr(b, "pins") else SMBusI2C(SMBus(b))

        def pin(cs):
            return world.pin(cs)
    return Board(config, buses, pin, uart, clock=world.clock, watchdog=wdt, reset=None)


def main(spec_path):
    with open(spec_path) as f:
        spec = json.load(f)
    from hil_tests.sim import world as world_mod
    config = spec["config"]
    w = world_mod.World(config, spec.get("temps"), spec.get("noise_uohm", 0), spec.get("seed", 1),
                        spec.get("start_ms", 0))
    w.uart = None
    world_mod.set_current(w)
    ctl = Control(spec["ctl"], w, spec.get("ctl_requests"))
    w.clock.gate = ctl.gate
    board = make_board(w, config, spec.get("board"))
    ctl.gate()  # initial stimulus and faults before power-up
    from firmware.app import main as fw_main
    try:
        fw_main(board)
    except world_mod.WatchdogExpired as e:
        ctl.send({"ev": "watchdog", "t_ms": w.clock.now_ms(), "error": str(e)})
        raise SystemExit(3)
    except Exception as e:
        if ctl.locked:
            HEAP_LOCKED[0] = False
            micropython.heap_unlock()
            ctl.locked = False
        if MICRO:
            sys.print_exception(e, sys.stderr)
        else:
            import traceback
            traceback.print_exc()
        ctl.send({"ev": "crash", "t_ms": w.clock.now_ms(), "error": "%s: %s" % (type(e).__name__, e)})
        raise SystemExit(1)


if __name__ == "__main__":
    main(sys.argv[1])
