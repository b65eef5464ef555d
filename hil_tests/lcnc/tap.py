"""A serial line with a switch in it: board pty <-> tap <-> the bridge's pty.

The tap relays bytes between the rig's pty (the board) and a pty of its own
that the bridge opens, records what passes, and on request breaks the line
the ways a real link breaks: ``corrupt`` (one CRC digit of every board line
changed: a bad CRC), ``replay`` (every board line replaced by the last good
O/Q line: stale frames from a stuck gateway), ``drop`` (nothing passes either
way: link loss). Stream mode decodes the board's frames with the rig's
codec; Modbus mode keeps the board's raw bytes.
"""
import fcntl
import os
import select
import threading
import time
import tty

from host.board.link import FrameError, parse_line


class LinkTap(threading.Thread):
    def __init__(self, board_port, stream=True):
        super().__init__(daemon=True)
        self.board = os.open(board_port, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.board)
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        fcntl.fcntl(self.master, fcntl.F_SETFL, fcntl.fcntl(self.master, fcntl.F_GETFL) | os.O_NONBLOCK)
        self.port = os.ttyname(self.slave)
        self.stream = stream
        self.mode = "pass"
        self.lock = threading.Lock()
        self.frames = []      # (monotonic time, Frame) the board sent, whatever the mode
        self.commands = []    # (monotonic time, line) the bridge sent, stream mode
        self.board_raw = bytearray()
        self.bridge_raw = bytearray()
        # (monotonic time, offset in board_raw / bridge_raw) of each chunk read: when a Modbus frame passed
        self.board_marks = []
        self.bridge_marks = []
        self._down = bytearray()
        self._up = bytearray()
        self.last_good = None
        self.frozen = None
        self.stop = False

    def _to_bridge(self, data):
        try:
            os.write(self.master, data)
        except BlockingIOError:
            pass  # nobody reads the bridge's side: the bytes are lost, as on a cable

    def _board_lines(self, data):
        self._down += data
        while True:
            i = self._down.find(b"\n")
            if i < 0:
                return
            line = bytes(self._down[:i + 1])
            del self._down[:i + 1]
            body = line.rstrip(b"\r\n")
            try:
                f = parse_line(body)
            except (FrameError, ValueError, UnicodeDecodeError):
                f = None
            now = time.monotonic()
            with self.lock:
                if f is not None:
                    self.frames.append((now, f))
                    if f.kind in ("O", "Q"):
                        self.last_good = line
                mode = self.mode
                frozen = self.frozen
            if mode == "pass":
                self._to_bridge(line)
            elif mode == "corrupt" and len(body) > 5:
                digit = body[-1:]
                self._to_bridge(body[:-1] + (b"0" if digit != b"0" else b"1") + b"\r\n")
            elif mode == "replay" and frozen and f is not None and f.kind in ("O", "Q"):
                self._to_bridge(frozen)

    def _bridge_bytes(self, data):
        now = time.monotonic()
        with self.lock:
            self.bridge_marks.append((now, len(self.bridge_raw)))
            self.bridge_raw += data
            mode = self.mode
            if self.stream:
                self._up += data
                while b"\n" in self._up:
                    i = self._up.find(b"\n")
                    self.commands.append((now, bytes(self._up[:i]).rstrip(b"\r")))
                    del self._up[:i + 1]
        if mode != "drop":
            os.write(self.board, data)

    def run(self):
        while not self.stop:
            r, _, _ = select.select([self.board, self.master], [], [], 0.05)
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    time.sleep(0.01)
                    continue
                if fd == self.board:
                    if self.stream:
                        self._board_lines(data)
                    else:
                        with self.lock:
                            self.board_marks.append((time.monotonic(), len(self.board_raw)))
                            self.board_raw += data
                        if self.mode != "drop":
                            self._to_bridge(data)
                else:
                    self._bridge_bytes(data)

    def set_mode(self, mode):
        with self.lock:
            self.mode = mode
            self.frozen = self.last_good

    def close(self):
        self.stop = True
        self.join(timeout=1)
        for fd in (self.board, self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
