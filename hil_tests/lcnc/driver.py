"""A headless LinuxCNC "display": started by the ``linuxcnc`` script as [DISPLAY]DISPLAY, it drives the
machine through LinuxCNC's ``linuxcnc`` module and reads/writes HAL pins for the test, which talks to it
over a unix socket (path in TCOMP_LCNC_CTL), one JSON request per line, one JSON answer per line.
When it exits, LinuxCNC shuts down.

Requests: ``start`` (e-stop reset, machine on, home all), ``machine`` {on}, ``mdi`` {cmd} (waits until
the interpreter is idle), ``get`` {pins}, ``set`` {pin, value}, ``sample`` {pins, seconds, dt} (rows
``[t_before, values..., t_after]`` taken here, so socket latency does not blur a ramp), ``quit``.
"""
import json
import os
import socket
import sys
import time

import hal
import linuxcnc


class Machine:
    def __init__(self):
        self.stat = linuxcnc.stat()
        self.cmd = linuxcnc.command()
        self.comp = hal.component("tcomp-test-driver")  # hal.get_value needs a component in this process
        self.comp.ready()

    def wait(self, pred, timeout=10.0, what="condition"):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.stat.poll()
            if pred(self.stat):
                return
            time.sleep(0.005)
        raise RuntimeError("timeout waiting for %s" % what)

    def machine(self, on):
        if on:
            self.cmd.state(linuxcnc.STATE_ESTOP_RESET)
            self.cmd.state(linuxcnc.STATE_ON)
            self.wait(lambda s: s.task_state == linuxcnc.STATE_ON and hal.get_value("motion.motion-enabled"),
                      what="machine on")
        else:
            self.cmd.state(linuxcnc.STATE_OFF)
            self.wait(lambda s: not hal.get_value("motion.motion-enabled"), what="machine off")
        return {}

    def start(self):
        self.machine(True)
        self.cmd.mode(linuxcnc.MODE_MANUAL)
        self.cmd.wait_complete()
        self.cmd.teleop_enable(0)
        self.cmd.wait_complete()
        self.cmd.home(-1)
        self.wait(lambda s: all(s.homed[i] for i in range(s.joints)), what="homing")
        self.cmd.mode(linuxcnc.MODE_MDI)
        self.cmd.wait_complete()
        return {}

    def mdi(self, cmd):
        self.cmd.mode(linuxcnc.MODE_MDI)
        self.cmd.wait_complete()
        self.cmd.mdi(cmd)
        self.cmd.wait_complete()
        self.wait(lambda s: s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.inpos,
                  what="MDI %s" % cmd)
        return {}

    def get(self, pins):
        return {"values": {p: hal.get_value(p) for p in pins}}

    def set(self, pin, value):
        hal.set_p(pin, str(value))
        return {}

    def sample(self, pins, seconds, dt=0.01):
        rows = []
        t0 = time.monotonic()
        while True:
            # the time before and after reading: a process descheduled in between widens the
            # interval the values may come from instead of misdating them
            t = time.monotonic() - t0
            values = [hal.get_value(p) for p in pins]
            rows.append([t] + values + [time.monotonic() - t0])
            if t >= seconds:
                return {"rows": rows}
            time.sleep(dt)


def main():
    m = Machine()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(os.environ["TCOMP_LCNC_CTL"])
    f = sock.makefile("rwb")
    for line in f:
        req = json.loads(line)
        op = req.pop("op")
        if op == "quit":
            break
        try:
            ans = getattr(m, op)(**req)
            ans["ok"] = True
        except Exception as exc:  # reported to the test, which fails with it
            ans = {"ok": False, "error": "%s: %s" % (type(exc).__name__, exc)}
        f.write((json.dumps(ans) + "\n").encode())
        f.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
