"""Who may change the output: HMAC-SHA256 with the board's key, and a counter against replay.

A command that changes what the board outputs (docs/protocol.md, "Who may
change the output") carries a counter and a tag: the first 16 bytes of
HMAC-SHA256(key, message), where the message is the command's own bytes up to
and including the counter (plus, for a table commit, the sha256 of the
uploaded table). The counter must be larger than every counter accepted
before, so a recorded command cannot be played again.

The key is ``key.bin`` (32 bytes) in the table directory, written there by
``tcomp flash``; the board never sends it. Without it every such command is
refused: a board nobody provisioned cannot be changed over the link.

The counter survives a reset without a flash write per command: ``auth.bin``
holds a high-water mark (b"TA", version 1, uint32 little-endian, CRC-16/CCITT
of those 7 bytes) that is raised by _BLOCK ahead of the counters in use, so
one write covers _BLOCK commands. After a reset every counter up to the stored
mark counts as used (a few are skipped, none can be replayed). Each write
spends one token of the App's flash budget (``spend``).
"""

import struct

from micropython import const

try:
    from hashlib import sha256
except ImportError:  # a port built without hashlib
    from firmware.sha256 import sha256

from firmware.crc16 import crc16_ccitt

# firmware.wire's (tests/firmware/test_fw_consts.py checks the copies)
_TAG_BYTES = const(16)
_MAX_COUNTER = const(999999999)
_BLOCK = const(64)  # counters reserved per flash write
_KEY_BYTES = const(32)

# refusal reasons: E,8,auth,<REASONS[r]> (stream; BUSY is E,9,busy), Modbus input register 50
OK = 0
NO_KEY = 1
BAD_TAG = 2
REPLAY = 3
NOT_STORED = 4
BUSY = 5
UNSIGNED = 6
REASONS = (b"", b"no key", b"bad tag", b"replayed counter", b"counter not stored", b"busy", b"unsigned")


def hasher():
    """A new sha256 object: hashlib's, or firmware.sha256's on a port without hashlib."""
    return sha256()


class Auth:
    def __init__(self, store, spend):
        """``store``: the TableStore (its directory and atomic file replace);
        ``spend()``: True if a flash write is allowed now (the wear budget)."""
        self.store = store
        self.spend = spend
        self._ipad = None
        self._opad = None
        try:
            with open(store.dir + "/key.bin", "rb") as f:
                k = f.read(_KEY_BYTES + 1)
        except OSError:
            k = b""
        if len(k) == _KEY_BYTES:
            self._ipad = bytes(c ^ 0x36 for c in k) + b"\x36" * _KEY_BYTES
            self._opad = bytes(c ^ 0x5C for c in k) + b"\x5c" * _KEY_BYTES
        k = None
        self.last = self._load()  # the largest counter used (or skipped)
        self.reserved = self.last  # counters up to this are covered by auth.bin
        self.why = OK if self._ipad is not None else NO_KEY  # the last refusal (Modbus input register 50)

    @property
    def keyed(self):
        return self._ipad is not None

    def _load(self):
        # a complete auth.bin.new is the newest (a cut before the rename), as for refs.bin
        for name in ("auth.bin.new", "auth.bin"):
            try:
                with open(self.store.dir + "/" + name, "rb") as f:
                    b = f.read(10)
            except OSError:
                continue
            if len(b) == 9 and b[:3] == b"TA\x01" and crc16_ccitt(b, 0, 7) == b[7] | b[8] << 8:
                return struct.unpack_from("<I", b, 3)[0]
        return 0

    def mac(self, msg, extra=b""):
        """The tag of ``msg`` + ``extra``: HMAC-SHA256 (RFC 2104) truncated to _TAG_BYTES."""
        h = sha256(self._ipad)
        h.update(msg)
        if extra:
            h.update(extra)
        o = sha256(self._opad)
        o.update(h.digest())
        return o.digest()[:_TAG_BYTES]

    def check(self, counter, tag, msg, extra=b""):
        """OK if ``tag`` authorises ``msg`` + ``extra`` with a fresh ``counter`` (now used up),
        else the reason; a refusal changes nothing."""
        why = self._check(counter, tag, msg, extra)
        self.why = why
        return why

    def _check(self, counter, tag, msg, extra):
        if self._ipad is None:
            return NO_KEY
        m = self.mac(msg, extra)
        d = len(tag) ^ _TAG_BYTES
        if not d:
            for i in range(_TAG_BYTES):  # every byte, whatever the first difference: no timing hint
                d |= m[i] ^ tag[i]
        if d:
            return BAD_TAG
        if not self.last < counter <= _MAX_COUNTER:
            return REPLAY
        if counter > self.reserved:
            if not self.spend():
                return BUSY
            mark = counter + _BLOCK
            b = b"TA\x01" + struct.pack("<I", mark)
            try:
                self.store.replace_file("auth.bin", b + struct.pack("<H", crc16_ccitt(b)))
            except OSError:
                return NOT_STORED
            self.reserved = mark
        self.last = counter
        return OK
