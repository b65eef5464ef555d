"""The controller's one link client: a port, the board's hello, commands, signed commands, request/answer, frames,
and the board's clock across its 2^30 ms wrap (docs/protocol.md).

Used by ``tcomp monitor``, ``tcomp record``, ``tcomp linuxcnc`` (stream mode: host/board/linuxcnc/bridge.py
``StreamLink``) and the HIL rig (hil_tests/rig/harness.py ``LinkClient``, ``RealDut``). Frames are decoded by
host/board/link.py; commands are signed by host/board/linkauth.py. No numpy: this runs on the controller.

Two ways bytes come in, one decoder: ``receive()`` reads the port itself (monitor, record, the bridge); a reader
thread (the rig's ``SerialReader``) calls ``feed()`` instead. ``request()`` and ``wait()`` take a ``step``: the
rig passes one that lets simulated time move, a real port passes none and waits in wall-clock time.

    from host.board.client import BoardLink
    link = BoardLink.open("/dev/ttyACM0")          # LinkError naming the port if it cannot be opened
    hello = link.read_hello()                       # V -> H; LinkError on another protocol version
    frame = link.request("S", kinds="TE")           # the T frame (temperatures) answering S
    ms = link.clock.extend(frame.t_ms)              # a board time that keeps counting across the wrap
"""
from __future__ import annotations

from collections.abc import Callable
import threading
import time
from typing import TYPE_CHECKING, Any, cast

from firmware.wire import PROTOCOL_VERSION
from host.board.link import Frame, StreamDecoder, command_line

if TYPE_CHECKING:  # pyserial is imported where a port is opened: the bridge and the rig import this module first
    import serial

    from host.board.linkauth import LinkSigner

# MicroPython's ticks_ms() wraps here (docs/protocol.md, Units): the board's t_ms counts 0 .. WRAP_MS - 1
WRAP_MS = 1 << 30
# hello fields after the frame kind (docs/protocol.md, frame H); the counter, nonce and error reference are
# firmware/wire.py's HELLO_* indices
HELLO_NAMES = ("protocol", "firmware", "slot", "table_crc", "provenance", "kind", "axis", "channels", "refs")


class LinkError(RuntimeError):
    """The link cannot do what was asked: the port, a silent board, a board of another protocol (names which)."""


class ClockError(ValueError):
    """The board's t_ms went backwards: not a wrap but a restarted board (or a frame from another one)."""


class BoardClock:
    """The board's t_ms (wrapping at WRAP_MS) as a monotonic millisecond count from the first frame seen.

    Between two frames the board's clock may move forward by less than half the wrap (6.2 days): a step
    that reads as more than that backwards is refused (ClockError), never taken as 12 days of silence."""

    def __init__(self, wrap_ms: int = WRAP_MS) -> None:
        self.wrap_ms = wrap_ms
        self.last_raw: int | None = None
        self.ms = 0  # board milliseconds since the first frame, across every wrap
        self.wraps = 0

    def extend(self, t_ms: int | str) -> int:
        """``t_ms`` of a frame -> board milliseconds since the first frame this clock saw."""
        t = int(t_ms)
        if not 0 <= t < self.wrap_ms:
            raise ClockError("t_ms %d is outside the board's clock range 0..%d" % (t, self.wrap_ms - 1))
        if self.last_raw is None:
            self.last_raw = t
            return 0
        step = (t - self.last_raw) % self.wrap_ms
        if step >= self.wrap_ms // 2:
            raise ClockError("the board's clock went back from t_ms %d to %d: the board restarted"
                             % (self.last_raw, t))
        if t < self.last_raw:
            self.wraps += 1
        self.last_raw = t
        self.ms += step
        return self.ms


class Hello:
    """A board's hello frame (H) by name: protocol, firmware, slot, table_crc, provenance, kind, axis, channels
    (an int), refs, counter, nonce, error_reference (None for a firmware before it)."""

    # the frame's text fields (HELLO_NAMES, set by name below), None when the frame ends before them
    protocol: str | None
    firmware: str | None
    slot: str | None
    table_crc: str | None
    provenance: str | None
    kind: str | None
    axis: str | None
    channels: int | None
    refs: str | None

    def __init__(self, frame: Frame) -> None:
        from firmware.wire import HELLO_COUNTER, HELLO_ERROR_REFERENCE, HELLO_NONCE
        f = frame.fields
        self.frame = frame
        for i, name in enumerate(HELLO_NAMES):
            setattr(self, name, f[i] if i < len(f) else None)
        try:
            self.channels = int(cast(str, self.channels))  # the loop above set the frame's text (or None)
        except (TypeError, ValueError):
            self.channels = None
        self.counter = f[HELLO_COUNTER] if len(f) > HELLO_COUNTER else None
        self.nonce = f[HELLO_NONCE] if len(f) > HELLO_NONCE else None
        self.error_reference = f[HELLO_ERROR_REFERENCE] if len(f) > HELLO_ERROR_REFERENCE else None

    def as_dict(self) -> dict[str, Any]:
        """What a record of the board keeps (never the nonce: it is a session's, not the board's)."""
        return {name: getattr(self, name) for name in HELLO_NAMES + ("error_reference",)}


def check_protocol(frame: Frame, port: str) -> None:
    """LinkError when hello ``frame`` is of another protocol version than this tcomp's."""
    if frame.fields[:1] != [str(PROTOCOL_VERSION)]:
        raise LinkError("%s: the board's hello frame says protocol version %s; this tcomp speaks %d (docs/protocol.md)"
                        % (port, (frame.fields or ["(none)"])[0], PROTOCOL_VERSION))


class BoardLink:
    """One board on one port. ``frames``: every frame decoded since the last ``take_frames`` (a list shared with a
    reader thread, guarded by ``lock``); ``decoder.bad``: malformed lines; ``last_hello``: the newest H frame."""

    def __init__(self, ser: serial.Serial, port: str = "", signer: LinkSigner | None = None) -> None:
        self.ser = ser
        self.port = port
        self.signer = signer
        self.decoder = StreamDecoder()
        self.frames: list[Frame] = []
        self.lock = threading.Condition()
        self.last_hello: Frame | None = None
        self.clock = BoardClock()

    @classmethod
    def open(cls, port: str, baud: int = 115200, signer: LinkSigner | None = None, timeout: float = 0.05,
             **kw: Any) -> BoardLink:
        """Open ``port`` (a device path, a pty, or a pySerial URL: socket://, loop://, spy://); LinkError naming it."""
        import serial
        try:
            ser = serial.serial_for_url(port, baud, timeout=timeout, **kw)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError("cannot open %s: %s" % (port, exc))
        return cls(ser, port, signer)

    # --- out -------------------------------------------------------------------------------
    def write(self, data: bytes, flush: bool = True) -> None:
        """``flush=False`` for a caller on a deadline (the LinuxCNC bridge): the port's write timeout bounds it."""
        self.ser.write(data)
        if flush:
            self.ser.flush()

    def send(self, *fields: bytes | str | int) -> None:
        self.write(command_line(*fields))

    def _signer(self) -> LinkSigner:
        # only a link opened with a key signs (the verbs check --key first); None.<method> was the error before
        assert self.signer is not None, "this link has no key to sign with"
        return self.signer

    def _observe_counter(self):
        # the board's last counter and session nonce are in its newest hello (boot, V, table switch)
        if self.last_hello is not None:
            self._signer().observe_hello(self.last_hello.fields)

    def signed_line(self, *fields: bytes | str | int, extra: bytes = b"") -> bytes:
        """A command that changes the output, signed with the board's key (``signer``) for the newest hello's
        session; linkauth's CounterError when the hello's counter or nonce cannot be used."""
        self._observe_counter()
        return self._signer().stream_line(*fields, extra=extra)

    def upload_lines(self, table: bytes) -> list[bytes]:
        self._observe_counter()
        return self._signer().upload_lines(table)

    def send_signed(self, *fields: bytes | str | int, extra: bytes = b"") -> None:
        self.write(self.signed_line(*fields, extra=extra))

    # --- in --------------------------------------------------------------------------------
    def feed(self, data: bytes, arrival: float = 0.0) -> list[Frame]:
        """Decode ``data``; the new frames are appended to ``frames`` and returned."""
        with self.lock:
            new = self.decoder.feed(data, arrival)
            for f in new:
                if f.kind == "H":
                    self.last_hello = f
            self.frames.extend(new)
            self.lock.notify_all()
        return new

    def receive(self) -> list[Frame]:
        """Read what the port has (waiting up to the port's timeout for the first byte), decode it; the new frames.
        The port's errors (unplugged, closed) come through as pyserial's SerialException (an OSError)."""
        data = self.ser.read(self.ser.in_waiting or 1)
        out = []
        while data:
            out += self.feed(data, time.monotonic())
            data = self.ser.read(self.ser.in_waiting) if self.ser.in_waiting else b""
        return out

    def take_frames(self) -> list[Frame]:
        with self.lock:
            out = list(self.frames)
            self.frames.clear()
        return out

    def wait(self, pred: Callable[[Frame], bool], timeout: float, since: int = 0, step: Callable[[], object] | None = None,
             what: str = "a matching frame") -> Frame:
        """The first frame from index ``since`` of ``frames`` that satisfies ``pred``, within ``timeout`` real
        seconds; between looks ``step()`` (simulated time moves) or, without one, the port is read."""
        end = time.monotonic() + timeout
        while True:
            with self.lock:
                for f in self.frames[since:]:
                    if pred(f):
                        return f
            if time.monotonic() >= end:
                raise LinkError("%s: no %s within %.3g s" % (self.port or "the board", what, timeout))
            if step is not None:
                step()
            else:
                self.receive()

    def request(self, *fields: bytes | str | int, kinds: str = "QAEHT", timeout: float = 10.0,
                step: Callable[[], object] | None = None) -> Frame:
        """Send a command and return the first frame of one of ``kinds`` that follows it."""
        with self.lock:
            n0 = len(self.frames)
        self.send(*fields)
        return self.wait(lambda f: f.kind in kinds, timeout, n0, step, "reply to %s" % ",".join(map(str, fields)))

    def read_hello(self, timeout: float = 5.0, step: Callable[[], object] | None = None) -> Hello:
        """Ask for the hello (V); its Hello, after checking the protocol version (LinkError otherwise)."""
        f = self.request("V", kinds="H", timeout=timeout, step=step)
        check_protocol(f, self.port)
        return Hello(f)

    def close(self) -> None:
        try:
            self.ser.close()
        except (OSError, ValueError):
            pass
