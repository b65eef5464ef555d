"""The controller's half of the board's authorisation (firmware/auth.py, docs/protocol.md).

Everything that changes what a board outputs is signed with that board's key:
HMAC-SHA256 over the command's bytes up to a counter, truncated to 16 bytes,
and the counter must grow from one command to the next. This module is
CPython's hmac/hashlib, written independently of the firmware's code so that
the tests compare two implementations.

API (used by `tcomp flash`, the HIL rig, and any bridge that sends `L` or
uploads a table)::

    from host.board.linkauth import LinkSigner, read_key
    signer = LinkSigner(read_key("board.key"))
    signer.observe(hello_fields[-1])          # the board's last counter (H frame, or Modbus IR 48-49)
    line = signer.stream_line("L")            # b"$TC,L,<counter>,<tag>*CRC\\r\\n"
    lines = signer.upload_lines(table_bytes)  # U,B (signed), U,D..., U,C (signed over the table's sha256)
    regs = signer.modbus_auth(1, 0, [1])      # HR 8..17 to write (FC16) before writing HR 0 = 1

Key file: the 32-byte key as 64 hex digits and a newline, mode 0600,
created by `tcomp flash --key FILE` when FILE does not exist.
"""
import binascii
import hashlib
import hmac
import os
import struct

from firmware.wire import MAX_COUNTER, TAG_BYTES  # the board checks the same sizes
from host.board.link import body as stream_body, command_line

KEY_BYTES = 32
UPLOAD_CHUNK = 48  # table bytes per U,D line (at most 64)


class KeyFileError(ValueError):
    pass


def generate_key():
    return os.urandom(KEY_BYTES)


def read_key(path):
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


def signer_for_option(path, flag="--key"):
    """The LinkSigner of a verb's ``--key FILE`` (None without one); a bad file is a UserError naming it."""
    if not path:
        return None
    from host.errors import UserError
    try:
        return LinkSigner(read_key(path))
    except KeyFileError as exc:
        raise UserError("%s %s" % (flag, exc))


def write_key(path, key):
    """Create ``path`` holding ``key`` (mode 0600); an existing file is never replaced."""
    tmp = "%s.tmp-%d" % (path, os.getpid())
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(key.hex() + "\n")
        os.link(tmp, path)  # fails if path appeared meanwhile: never over someone's key
    finally:
        os.unlink(tmp)


def stream_line(fields):
    """``$TC,<fields>*CRC\\r\\n`` (host/board/link.py's codec)."""
    return command_line(*fields)


class LinkSigner:
    """Signs commands for one board. ``counter`` is the last one used (the board's, or ours)."""

    def __init__(self, key, counter=0):
        if len(key) != KEY_BYTES:
            raise ValueError("a board key is %d bytes" % KEY_BYTES)
        self._key = bytes(key)
        self.counter = counter

    def __repr__(self):  # never the key
        return "LinkSigner(counter=%d)" % self.counter

    def observe(self, counter):
        """Take note of the board's last counter (the last field of its H frame, '-' if it has no key)."""
        if counter not in ("-", b"-", None):
            self.counter = max(self.counter, int(counter))

    def next_counter(self):
        if self.counter >= MAX_COUNTER:
            raise ValueError("counter exhausted: provision a new key")
        self.counter += 1
        return self.counter

    def tag(self, message, extra=b""):
        return hmac.new(self._key, message + extra, hashlib.sha256).digest()[:TAG_BYTES]

    def stream_fields(self, *fields, extra=b""):
        """``fields`` + (counter, tag hex) for a command that changes the output."""
        ctr = self.next_counter()
        fields = tuple(fields) + (ctr,)
        return fields + (self.tag(stream_body(fields), extra).hex().upper(),)

    def stream_line(self, *fields, extra=b""):
        return stream_line(self.stream_fields(*fields, extra=extra))

    def upload_lines(self, table, chunk=UPLOAD_CHUNK):
        """Every line of a table upload: U,B and U,C signed, the U,D chunks plain."""
        out = [self.stream_line("U", "B", len(table), "%08X" % binascii.crc32(table))]
        for off in range(0, len(table), chunk):
            out.append(stream_line(("U", "D", off, table[off:off + chunk].hex().upper())))
        out.append(self.stream_line("U", "C", extra=hashlib.sha256(table).digest()))
        return out

    def modbus_auth(self, address, start, values):
        """Holding registers 8..17 (counter high/low word, 8 tag words) authorising the next write
        of ``values`` to holding registers ``start``.. at slave ``address``."""
        ctr = self.next_counter()
        msg = b"MB" + struct.pack(">BHH%dHI" % len(values), address, start, len(values), *values, ctr)
        tag = self.tag(msg)
        return [ctr >> 16, ctr & 0xFFFF] + list(struct.unpack(">8H", tag))
