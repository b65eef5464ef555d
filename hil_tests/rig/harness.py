"""The controller's side of the rig: start the firmware's process on a pty, talk to it like a PLC.

``Rig(config, ...)`` creates a pseudo-terminal in raw mode, opens its device
node with pyserial (exactly as a controller opens /dev/ttyACM0), starts
hil_tests/rig/dut.py under MicroPython or CPython with the pty as its
stdin/stdout and the board's flash directory as its working directory, and
accepts the DUT's connection on the control socket. A reader thread drains
the serial port continuously (the DUT blocks when the pty buffer is full) and
decodes $TC frames (or keeps raw bytes in Modbus mode).

Simulated time only moves inside ``run(until_ms)``; between runs the DUT is
parked in its clock and the test may change temperatures and inject faults.
"""
import io
import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty
import serial

from hil_tests.rig import interpreters
from host.board.client import BoardLink, LinkError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MP_DIR = os.path.join(ROOT, "hil_tests", "mp")
DUT = os.path.join(ROOT, "hil_tests", "rig", "dut.py")
VENV_BIN = os.path.join(ROOT, ".venv", "bin")
# The emulated Cortex-M3 board (ports/mps2, built by make setup): the firmware and the rig's board
# side in its ROM; heap for the firmware plus the chip simulators (the firmware alone: docs/firmware.md).
QEMU_IMAGE = os.environ.get("TCOMP_QEMU_IMAGE", os.path.join(ROOT, "build", "mps2-cortex-m3-rig", "firmware-rig.elf"))
QEMU_HEAP = os.environ.get("TCOMP_QEMU_HEAP", "256K")


class RigError(RuntimeError):
    pass


def micropython_path():
    """The chosen MicroPython (hil_tests/rig/interpreters.py: TCOMP_MICROPYTHON), None when it is not there."""
    try:
        it = interpreters.get()
    except interpreters.InterpreterMissing:
        return None
    return it.path if it.exists() else None


def _die_with_parent():
    """QEMU gets SIGKILL when the rig's process ends, however it ends (Linux prctl PR_SET_PDEATHSIG):
    an emulator left running keeps a core busy."""
    import ctypes
    ctypes.CDLL(None).prctl(1, signal.SIGKILL)


def qemu_cmd(serial_fd, ctl_path, code, heap=QEMU_HEAP, image=QEMU_IMAGE):
    """qemu-system-arm running ``code`` on the emulated board: UART0 on ``serial_fd`` (the pty's DUT
    side, passed as a QEMU fd set), UART1 connected to the unix socket ``ctl_path`` (or no UART1)."""
    exe = shutil.which("qemu-system-arm")
    if exe is None or not os.path.exists(image):
        raise RigError("QEMU board image not found (%s; make setup builds it with qemu-system-arm)" % image)
    argv = [exe, "-M", "mps2-an385", "-display", "none", "-monitor", os.environ.get("TCOMP_QEMU_MONITOR", "none"), "-nodefaults", "-net", "none",
            "-add-fd", "fd=%d,set=1" % serial_fd, "-chardev", "serial,id=uart0,path=/dev/fdset/1",
            "-serial", "chardev:uart0"]
    if ctl_path:
        argv += ["-chardev", "socket,id=uart1,path=" + ctl_path, "-serial", "chardev:uart1"]
    argv += ["-semihosting-config", "enable=on,target=native", "-kernel", image]
    return argv + ["-append", "heap=%s%s" % (heap, (" -c " + code) if code else "")]


def rig_heap():
    """The DUT's -X heapsize: TCOMP_HIL_HEAP, else the measured one for the chosen interpreter's word size."""
    return os.environ.get("TCOMP_HIL_HEAP") or interpreters.heap("rig")


def interpreter_cmd(name, heap=None):
    if name == "micropython":
        try:
            return interpreters.get().argv(heap or rig_heap())
        except interpreters.InterpreterMissing as e:
            raise RigError(str(e))
    if name == "cpython":
        return [sys.executable, "-u"]
    raise RigError("interpreter must be micropython, cpython or qemu, got %r" % (name,))


class SerialReader(threading.Thread):
    """Drains a pyserial port into its link's decoder (stream mode: ``link.feed``, host/board/client.py) or a byte
    buffer (Modbus mode)."""

    def __init__(self, ser, stream=True, link=None):
        super().__init__(daemon=True)
        self.ser = ser
        self.stream = stream
        self.link = link if link is not None else BoardLink(ser)
        self.frames = self.link.frames  # one list: what the reader decodes is what the client reads
        self.raw = bytearray()
        self.lock = self.link.lock
        self.stop = False
        self.last_rx = time.monotonic()
        self.busy = False
        self.rx_total = 0
        self.on_frame = None

    @property
    def decoder(self):
        return self.link.decoder

    def _receive(self, fd):
        """Bytes that arrived within ~50 ms, b'' if none (``busy`` once there are some); OSError when
        the other side closed."""
        if fd is None:  # a pySerial URL handler (socket://, loop://, spy://): no descriptor to select on
            waiting = self.ser.in_waiting
            if not waiting:
                time.sleep(0.01)
                return b""
            self.busy = True
            return self.ser.read(waiting)
        r, _, _ = select.select([fd], [], [], 0.05)
        if not r:
            return b""
        self.busy = True
        return os.read(fd, 65536)

    def run(self):
        try:
            fd = self.ser.fileno()
        except (AttributeError, io.UnsupportedOperation):
            fd = None
        while not self.stop:
            try:
                data = self._receive(fd)
            except (OSError, serial.SerialException):
                self.busy = False
                time.sleep(0.01)  # the DUT's side of the pty closed (process ended or restarting)
                continue
            if not data:
                self.busy = False
                continue
            now = time.monotonic()
            with self.lock:
                self.last_rx = now
                self.rx_total += len(data)
                if self.stream:
                    new = self.link.feed(data, now)
                    if self.on_frame is not None:
                        for f in new:
                            self.on_frame(f)
                else:
                    self.raw += data
                self.busy = False
                self.lock.notify_all()

    def until(self, total, timeout=20.0):
        """Wait until ``total`` bytes have been received and decoded (the DUT reports what it sent)."""
        end = time.monotonic() + timeout
        with self.lock:
            while self.rx_total < total:
                left = end - time.monotonic()
                if left <= 0:
                    raise RigError("only %d of %d serial bytes arrived" % (self.rx_total, total))
                self.lock.wait(min(left, 0.05))

    def quiet(self, idle_s=0.003, timeout=5.0):
        """Wait until the port has no pending bytes, nothing is being decoded and nothing arrived
        for ``idle_s`` (the kernel hands pty data over asynchronously)."""
        start = time.monotonic()
        end = start + timeout
        while time.monotonic() < end:
            with self.lock:
                idle = time.monotonic() - max(self.last_rx, start)
            if idle >= idle_s and not self.busy and self.ser.in_waiting == 0:
                return
            time.sleep(0.0005)


class LinkClient(BoardLink):
    """The controller's side of the link for every device under test (the rig, a real port): host/board/client.py's
    BoardLink, fed by a SerialReader thread, whose requests wait by ``advance`` (simulated time on the rig,
    wall-clock time on a real port); ``t_ms`` says where the device's clock is."""

    request_step_ms = 10
    request_timeout_s = 10.0

    def request(self, *fields, kinds=("Q", "A", "E", "H", "T"), step_ms=None, timeout=None):
        """Send a command and return the first reply frame of one of ``kinds`` that follows it."""
        step_ms = self.request_step_ms if step_ms is None else step_ms
        timeout = self.request_timeout_s if timeout is None else timeout
        try:
            return BoardLink.request(self, *fields, kinds=kinds, timeout=timeout, step=lambda: self.advance(step_ms))
        except LinkError:
            raise RigError("no reply to %r within %.1f s (t=%d ms)" % (fields, timeout, self.t_ms))


class Rig(LinkClient):
    """One simulated board running the firmware. Use as a context manager."""

    def __init__(self, config, table=None, interpreter="micropython", workdir=None, temps=None, noise_uohm=0,
                 seed=1, start_ms=0, heap=None, slot="A", use_mpy=True, open_port=True, key=None):
        """``key``: the board key provisioned into its flash (as tcomp flash does); a random one by
        default, b"" for a board nobody provisioned."""
        self.config = json.loads(json.dumps(config))
        self.interpreter = interpreter
        self.own_dir = workdir is None
        self.workdir = workdir or tempfile.mkdtemp(prefix="tcomp-hil-")
        self.flash = os.path.join(self.workdir, "flash")
        os.makedirs(self.flash, exist_ok=True)
        tdir = os.path.join(self.flash, self.config.get("table_dir", "tables"))
        os.makedirs(tdir, exist_ok=True)
        if table is not None:
            with open(os.path.join(tdir, "table_%s.bin" % slot.lower()), "wb") as f:
                f.write(table)
            with open(os.path.join(tdir, "active"), "w") as f:
                f.write(slot)
        from host.board.linkauth import LinkSigner, generate_key
        key = generate_key() if key is None else key
        BoardLink.__init__(self, None, signer=LinkSigner(key) if key else None)  # the port is opened below
        if key:
            with open(os.path.join(tdir, "key.bin"), "wb") as f:
                f.write(key)
        self.spec = {"config": self.config, "ctl": os.path.join(self.workdir, "ctl.sock"), "temps": temps or {},
                     "noise_uohm": noise_uohm, "seed": seed, "start_ms": start_ms}
        self.requests_path = None
        self.requests_fd = None
        if interpreter == "qemu":  # the board's own files on the emulator; events on UART1, requests by a pipe
            self.spec["board"] = "mps2_an385"
            self.spec["ctl"] = "uart:1"
            self.requests_path = os.path.join(self.workdir, "ctl-requests.fifo")
            self.spec["ctl_requests"] = self.requests_path
        self.ctl_path = os.path.join(self.workdir, "ctl.sock")
        self.heap = heap if interpreter != "qemu" or heap is not None else QEMU_HEAP
        self.use_mpy = use_mpy
        self.stream = (self.config.get("serial") or {}).get("mode", "stream") == "stream"
        self.proc = None
        self.ser = None
        self.reader = None
        self.events = []
        self.t_ms = 0
        self.mem = []  # (t_ms, gc.mem_free after collect) samples
        self.starts = 0
        self.open_port = open_port
        self._free = None
        self._ramp = None  # a ramp not sent yet (ramp())
        self.serial_sent = 0  # bytes written to the serial port since the board's power-up
        self.powered = False
        self.rx_base = 0
        self._open_pty()

    # --- process lifetime --------------------------------------------------------
    def _open_pty(self):
        self.master, self.slave = os.openpty()
        # raw on both sides before anything opens it, or the line discipline echoes frames back
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        if not self.open_port:
            return  # another client (pymodbus, mpremote) opens self.port
        baud = (self.config.get("serial") or {}).get("baud", 115200)
        self.ser = serial.serial_for_url(self.port, baud, timeout=0)
        self.reader = SerialReader(self.ser, self.stream, link=self)
        self.reader.start()

    def start(self):
        ctl = self.ctl_path
        if os.path.exists(ctl):
            os.unlink(ctl)
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.listener.bind(ctl)
        self.listener.listen(1)
        if self.requests_path:
            # a fresh pipe per power-up (nothing a killed board left unread), held open read-write here
            # so that neither side's open() waits for the other
            if self.requests_fd is not None:
                os.close(self.requests_fd)
                self.requests_fd = None
            if os.path.exists(self.requests_path):
                os.unlink(self.requests_path)
            os.mkfifo(self.requests_path)
            self.requests_fd = os.open(self.requests_path, os.O_RDWR)
        spec_path = os.path.join(self.workdir, "spec.json")
        with open(spec_path, "w") as f:
            json.dump(self.spec, f)
        env = dict(os.environ)
        if self.interpreter == "micropython":
            # with .mpy: only the built files (hil_tests/manifest.py), not the checkout, so a module the
            # board manifest misses fails here as it would on a board
            from hil_tests.rig.mpybuild import rig_build
            env["MICROPYPATH"] = ":".join([MP_DIR, rig_build().root if self.use_mpy else ROOT])
            argv = interpreter_cmd("micropython", self.heap) + (["-m", "hil_tests.rig.dut"] if self.use_mpy else [DUT])
            argv = argv + [spec_path]
        elif self.interpreter == "qemu":
            argv = qemu_cmd(self.master, ctl, "from hil_tests.rig import dut\ndut.main(%r)" % spec_path,
                            heap=self.heap)
        else:
            env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
            argv = interpreter_cmd("cpython") + [DUT, spec_path]
        self.serial_sent = 0
        self.stderr_path = os.path.join(self.workdir, "dut-stderr-%d.txt" % self.starts)
        self.stderr = open(self.stderr_path, "wb")
        self.powered = True
        if self.interpreter == "qemu":  # the pty reaches UART0 through QEMU's fd set, not stdio
            self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=self.stderr, stderr=self.stderr,
                                         cwd=self.flash, env=env, pass_fds=(self.master,),
                                         preexec_fn=_die_with_parent)
        else:
            self.proc = subprocess.Popen(argv, stdin=self.master, stdout=self.master, stderr=self.stderr,
                                         cwd=self.flash, env=env)
        self.starts += 1
        self.listener.settimeout(30)
        try:
            self.conn, _ = self.listener.accept()
        except socket.timeout:
            raise RigError("the DUT never connected to the control socket:\n" + self.log())
        self.conn.settimeout(None)
        self.rf = self.conn.makefile("rb")
        ev = self._recv()
        if ev.get("ev") != "at":
            raise RigError("unexpected first control event %r" % ev)
        self.t_ms = ev["t_ms"]
        if self.open_port:
            self.reader.quiet(0.05)  # whatever a previous process left in flight
            self.rx_base = self.reader.rx_total
        return self

    def log(self):
        try:
            with open(self.stderr_path, "rb") as f:
                return f.read().decode(errors="replace")
        except (OSError, AttributeError):
            return ""

    def _recv(self):
        line = self.rf.readline()
        if not line:
            code = self.proc.poll() if self.proc else None
            raise RigError("DUT closed the control channel (exit code %r):\n%s" % (code, self.log()))
        ev = json.loads(line)
        if ev.get("ev") in ("crash", "watchdog"):
            self.events.append(ev)
            raise RigError("DUT %s at %s ms: %s\n%s" % (ev["ev"], ev.get("t_ms"), ev.get("error"), self.log()))
        return ev

    def _send(self, obj):
        if self._ramp is not None:  # a ramp waiting for the next run travels with it (one line, one gate)
            ramp, self._ramp = self._ramp, None
            if obj.get("op") == "run":
                obj = dict(obj, ramp=ramp)
            else:
                self._send(dict(ramp, op="ramp"))
        data = (json.dumps(obj) + "\n").encode()
        if self.requests_fd is not None:
            os.write(self.requests_fd, data)  # one line, far below PIPE_BUF: written whole
        else:
            self.conn.sendall(data)

    def kill(self):
        """Power cut: SIGKILL, no chance to flush or close anything."""
        self.powered = False
        self._ramp = None
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait()
        self._close_ctl()

    def wait_real(self, pred, timeout=5.0, since=0):
        """Wait in real time (time granted by ``free_run``) for a frame from index ``since`` on."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in self.reader.frames[since:]:
                if pred(f):
                    return f
            time.sleep(0.001)
        raise RigError("no matching frame within %.1f s" % timeout)

    def _close_ctl(self):
        if self.requests_fd is not None:
            os.close(self.requests_fd)
            self.requests_fd = None
        for a in ("rf", "conn", "listener"):
            o = getattr(self, a, None)
            if o is not None:
                try:
                    o.close()
                except OSError:
                    pass
                setattr(self, a, None)
        if self.stderr:
            self.stderr.close()
            self.stderr = None

    def restart(self):
        self.kill()
        return self.start()

    def close(self):
        if self.proc and self.proc.poll() is None:
            try:
                self._send({"op": "quit"})
                self.proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired, AttributeError):
                pass
        self.kill()
        if self.reader and self.open_port:
            self.reader.stop = True
            self.reader.join(timeout=1)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.ser and self.open_port:
            try:
                self.ser.close()
            except Exception:
                pass
        if self.own_dir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self):
        if self.proc is None:
            self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    # --- time and stimulus ------------------------------------------------------------
    def run(self, until_ms, temps=None, gc=False, lock=False, sync=True):
        """Let simulated time run to ``until_ms`` (temperatures ramp linearly to ``temps``)."""
        msg = {"op": "run", "until_ms": int(until_ms)}
        if self.interpreter == "qemu" and self.open_port:
            # the board resumes only once every serial byte sent since power-up is in its UART: QEMU
            # delivers them one main-loop turn each, and simulated time must not run ahead of them
            msg["rx"] = self.serial_sent
        if temps:
            msg["temps"] = {k: float(v) for k, v in temps.items()}
        if gc:
            msg["gc"] = True
        if lock:
            msg["lock"] = True
        self._send(msg)
        if gc:
            ev = self._recv()
            self.mem.append((self.t_ms, ev["mem_free"]))
        ev = self._recv()
        self.t_ms = ev["t_ms"]
        if sync and self.open_port:
            self.reader.until(self.rx_base + ev.get("tx", 0))
        return ev

    def advance(self, ms, **kw):
        return self.run(self.t_ms + ms, **kw)

    def ramp(self, until_ms, temps):
        """From now on, sensors head linearly for ``temps`` at ``until_ms`` (time does not move).

        Sent with the next control message (the ``run`` that lets time move, or before any other
        request): on the emulated board every control line costs a gate on the board and its bytes
        cross QEMU's UART one main-loop turn each (docs/hil.md)."""
        self._ramp = {"until_ms": int(until_ms), "temps": {k: float(v) for k, v in temps.items()}}

    def jump(self, temps):
        self._send({"op": "jump", "temps": {k: float(v) for k, v in temps.items()}})

    def sensor(self, name, condition):
        self._send({"op": "sensor", "name": name, "condition": condition})

    def chip(self, name, **kw):
        msg = {"op": "chip", "name": name}
        msg.update(kw)
        self._send(msg)

    def bus_fault(self, bus, kind, count=1, target=None):
        self._send({"op": "bus", "bus": bus, "kind": kind, "count": count, "target": target})

    def stats(self, gc=False):
        self._send({"op": "stats", "gc": gc})
        return self._recv()

    def free_run(self, chunk_ms=20, pace_s=0.002):
        """Context manager: a thread keeps granting time (``chunk_ms`` every ``pace_s`` real seconds)
        so that a blocking client with real-time timeouts (pymodbus) gets answers."""
        rig = self

        class _Free:
            def __enter__(self):
                self.stop = False
                self.error = None

                def loop():
                    try:
                        while not self.stop:
                            rig.run(rig.t_ms + chunk_ms, sync=False)
                            time.sleep(pace_s)
                    except Exception as exc:  # surfaced in __exit__, unless the test cut the power
                        if rig.powered:
                            self.error = exc
                self.th = threading.Thread(target=loop, daemon=True)
                self.th.start()
                return rig

            def __exit__(self, *exc):
                self.stop = True
                self.th.join(timeout=10)
                if self.error is not None and exc[0] is None:
                    raise self.error
        return _Free()

    # --- the serial link (write, send, frames, take_frames: LinkClient) ----------------------
    def write(self, data, flush=True):
        LinkClient.write(self, data, flush)
        self.serial_sent += len(data)

    def take_raw(self):
        with self.reader.lock:
            out = bytes(self.reader.raw)
            self.reader.raw.clear()
        return out

    def wait_frames(self, pred, timeout=10.0, step_ms=10):
        """Advance time in small steps until a received frame satisfies ``pred``; returns it."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in self.reader.frames:
                if pred(f):
                    return f
            self.advance(step_ms)
        raise RigError("no matching frame within %.1f s real time (t=%d ms)" % (timeout, self.t_ms))

