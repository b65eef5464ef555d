"""The controller's half of the board's authorisation (firmware/auth.py, docs/protocol.md).

Everything that changes what a board outputs is signed with that board's key:
HMAC-SHA256 over the board's session nonce and the command's bytes up to a
counter, truncated to 16 bytes; the counter must grow from one command to the
next (by at most the board's window), and the nonce, read from the board's
hello (or Modbus input registers 51-52), expires after a minute or two. A
table upload's chunks and commit are bound to its U,B instead. This module is
CPython's hmac/hashlib, written independently of the firmware's code so that
the tests compare two implementations.

API (used by `tcomp flash`, the HIL rig, and any bridge that sends `L` or
uploads a table)::

    from host.board.linkauth import LinkSigner, read_key
    signer = LinkSigner(read_key("board.key"))
    signer.observe_hello(hello_fields)        # the board's last counter and session nonce (H frame)
    signer.observe(counter, nonce)            # the same from Modbus input registers 48-49 and 51-52
    line = signer.stream_line("L")            # b"$TC,L,<counter>,<tag>*CRC\\r\\n"
    lines = signer.upload_lines(table_bytes)  # U,B (signed), U,D... (tagged), U,C (signed over the table's sha256)
    regs = signer.modbus_auth(1, 0, [1])      # HR 8..17 to write (FC16) before writing HR 0 = 1

Key file: the 32-byte key as 64 hex digits and a newline, mode 0600,
created by `tcomp flash --key FILE` when FILE does not exist.
"""

from __future__ import annotations

from collections.abc import Sequence
import binascii
import hashlib
import hmac
import os
import struct

from firmware.wire import HELLO_COUNTER, HELLO_NONCE, MAX_COUNTER, TAG_BYTES  # the board checks the same sizes
from host.board.link import body as stream_body, command_line

KEY_BYTES = 32
UPLOAD_CHUNK = 48  # table bytes per U,D line (at most 64)


class KeyFileError(ValueError):
    pass


class CounterError(ValueError):
    """The board's counter or session nonce as reported cannot be used (names what is wrong)."""


def counter_mark(mark: int = 0) -> bytes:
    """``auth.bin`` holding ``mark`` as the board's last counter (firmware/auth.py's format, written here
    independently): staged with a new key, so the new key's counters start from ``mark``."""
    b = b"TA\x01" + struct.pack("<I", mark)
    return b + struct.pack("<H", binascii.crc_hqx(b, 0xFFFF))


def generate_key() -> bytes:
    return os.urandom(KEY_BYTES)


def read_key(path: str) -> bytes:
    """The key in ``path`` (64 hex digits); KeyFileError naming the file otherwise."""
    try:
        with open(path, "rb") as f:
            text = f.read(200)
    except OSError as exc:
        raise KeyFileError("%s: cannot read the key: %s" % (path, exc.strerror or exc))
    try:
        key = bytes.fromhex(text.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != KEY_BYTES:
        raise KeyFileError("%s: not a board key (expected %d hex digits)" % (path, 2 * KEY_BYTES))
    return key


def signer_for_option(path: str | None, flag: str = "--key") -> LinkSigner | None:
    """The LinkSigner of a verb's ``--key FILE`` (None without one); a bad file is a UserError naming it."""
    if not path:
        return None
    from host.errors import UserError
    try:
        return LinkSigner(read_key(path))
    except KeyFileError as exc:
        raise UserError("%s %s" % (flag, exc))


def write_key(path: str, key: bytes) -> None:
    """Create ``path`` holding ``key`` (mode 0600); an existing file is never replaced."""
    tmp = "%s.tmp-%d" % (path, os.getpid())
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(key.hex() + "\n")
        os.link(tmp, path)  # fails if path appeared meanwhile: never over someone's key
    finally:
        os.unlink(tmp)


def stream_line(fields: Sequence[bytes | str | int]) -> bytes:
    """``$TC,<fields>*CRC\\r\\n`` (host/board/link.py's codec)."""
    return command_line(*fields)


class LinkSigner:
    """Signs commands for one board. ``counter`` is the last one used (the board's, or ours)."""

    def __init__(self, key: bytes, counter: int = 0, nonce: bytes | None = None) -> None:
        if len(key) != KEY_BYTES:
            raise ValueError("a board key is %d bytes" % KEY_BYTES)
        self._key = bytes(key)
        self.counter = counter
        self.nonce = nonce  # the board's session nonce (4 bytes), from its hello or Modbus IR 51-52

    def __repr__(self) -> str:  # never the key
        return "LinkSigner(counter=%d)" % self.counter

    def observe(self, counter: int | str | bytes | None, nonce: int | str | bytes | None = None) -> None:
        """Take note of the board's last counter ('-' or None if it has no key) and session nonce
        (8 hex digits, 4 bytes or the uint32); CounterError naming what is wrong with either."""
        if isinstance(counter, bytes):
            counter = counter.decode("ascii", "replace")
        if counter not in ("-", None):
            text = str(counter)
            if not text.isdigit() or not text.isascii():
                raise CounterError("the board's counter %r is not a number" % text[:40])
            c = int(text)
            if c > MAX_COUNTER:
                raise CounterError("the board's counter %d is above the largest, %d: the board's counter store is "
                                   "corrupt or from an older firmware; provision a new key (tcomp flash --key NEWFILE)"
                                   % (c, MAX_COUNTER))
            self.counter = max(self.counter, c)
        if nonce is not None:
            if isinstance(nonce, int):
                if not 0 <= nonce < 1 << 32:
                    raise CounterError("the board's session nonce %d is not a uint32" % nonce)
                nonce = struct.pack(">I", nonce)
            elif isinstance(nonce, str):
                try:
                    nonce = bytes.fromhex(nonce) if len(nonce) == 8 else b""
                except ValueError:
                    nonce = b""
                if not nonce:
                    raise CounterError("the board's session nonce is not 8 hex digits")
            if len(nonce) != 4:
                raise CounterError("the board's session nonce is not 4 bytes")
            self.nonce = bytes(nonce)

    def observe_hello(self, fields: Sequence[str]) -> None:
        """The counter and session nonce of a hello frame's fields (after its type)."""
        if len(fields) <= HELLO_NONCE:
            raise CounterError("the board's hello has no session nonce (%d fields): its firmware speaks an older "
                               "protocol (docs/protocol.md)" % len(fields))
        self.observe(fields[HELLO_COUNTER], fields[HELLO_NONCE])

    def next_counter(self) -> int:
        if self.counter >= MAX_COUNTER:
            raise CounterError("the board's counter reached %d, the largest: provision a new key "
                               "(tcomp flash --key NEWFILE, docs/protocol.md)" % MAX_COUNTER)
        self.counter += 1
        return self.counter

    def _prefix(self):
        if self.nonce is None:
            raise CounterError("the board's session nonce is unknown: read its hello (V) or Modbus input "
                               "registers 51-52 first")
        return self.nonce

    def tag(self, message: bytes, extra: bytes = b"", prefix: bytes = b"") -> bytes:
        return hmac.new(self._key, prefix + message + extra, hashlib.sha256).digest()[:TAG_BYTES]

    def stream_fields(self, *fields: bytes | str | int, extra: bytes = b"", bound: bytes | None = None) -> tuple[bytes | str | int, ...]:
        """``fields`` + (counter, tag hex) for a command that changes the output; the tag starts with the
        session nonce, or ``bound`` (an upload's id)."""
        prefix = self._prefix() if bound is None else bound
        ctr = self.next_counter()
        fields = tuple(fields) + (ctr,)
        return fields + (self.tag(stream_body(fields), extra, prefix).hex().upper(),)

    def stream_line(self, *fields: bytes | str | int, extra: bytes = b"", bound: bytes | None = None) -> bytes:
        return stream_line(self.stream_fields(*fields, extra=extra, bound=bound))

    def upload_lines(self, table: bytes, chunk: int = UPLOAD_CHUNK) -> list[bytes]:
        """Every line of a table upload: U,B signed in this session; each U,D chunk and U,C tagged with
        the upload's id (the nonce and U,B's counter), so they belong to this U,B and no other."""
        begin = self.stream_fields("U", "B", len(table), "%08X" % binascii.crc32(table))
        upload_id = self._prefix() + struct.pack(">I", begin[-2])
        out = [stream_line(begin)]
        for off in range(0, len(table), chunk):
            f = ("U", "D", off, table[off:off + chunk].hex().upper())
            out.append(stream_line(f + (self.tag(stream_body(f), b"", upload_id).hex().upper(),)))
        out.append(self.stream_line("U", "C", extra=hashlib.sha256(table).digest(), bound=upload_id))
        return out

    def modbus_auth(self, address: int, start: int, values: Sequence[int]) -> list[int]:
        """Holding registers 8..17 (counter high/low word, 8 tag words) authorising the next write
        of ``values`` to holding registers ``start``.. at slave ``address``."""
        prefix = self._prefix()
        ctr = self.next_counter()
        msg = b"MB" + struct.pack(">BHH%dHI" % len(values), address, start, len(values), *values, ctr)
        tag = self.tag(msg, b"", prefix)
        return [ctr >> 16, ctr & 0xFFFF] + list(struct.unpack(">8H", tag))
