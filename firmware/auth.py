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
spends one token of the App's flash budget (``spend``). A counter may not
jump more than _WINDOW past the last one used (a signed command cannot spend
the key's counters), and the mark never passes _MAX_COUNTER: a key that
reached it is replaced (re-provisioning, docs/protocol.md).

Every tag is bound to the board's session (docs/protocol.md, "Sessions"): the
message starts with the 4-byte session nonce, which is drawn at boot and moves
on every _SESSION_MS of uptime (``tick``); the current and the previous nonce
are accepted, so a signed command that was captured and held back expires. A
table upload's chunks and commit are bound to their ``U,B`` instead (the
nonce it was accepted with and its counter: ``upload_id``).
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
# firmware.wire's (tests/firmware/test_fw_consts.py checks the copies)
_COUNTER_WINDOW = const(1000)
_SESSION_MS = const(60000)

# refusal reasons: E,8,auth,<REASONS[r]> (stream; BUSY is E,9,busy), Modbus input register 50
OK = 0
NO_KEY = 1
BAD_TAG = 2
REPLAY = 3
NOT_STORED = 4
BUSY = 5
UNSIGNED = 6
JUMP = 7  # the counter is more than the window past the last one used
EXHAUSTED = 8  # the last counter used is MAX_COUNTER: a new key is needed
# firmware.wire.AUTH_REASONS (tests/firmware/test_fw_consts.py checks)
REASONS = (b"", b"no key", b"bad tag", b"replayed counter", b"counter not stored", b"busy", b"unsigned",
           b"counter jump", b"counter exhausted")


def _entropy(seed):
    """4 bytes that differ from boot to boot: the port's random source, else the kernel's (a Linux
    board, the 32-bit port), else a hash of ``seed`` and the microsecond tick at this moment (a board
    without a random source: docs/protocol.md says what that weakens)."""
    try:
        import os
        return bytes(os.urandom(4))
    except (ImportError, AttributeError, OSError):
        pass
    try:
        with open("/dev/urandom", "rb") as f:
            b = f.read(4)
        if len(b) == 4:
            return b
    except OSError:
        pass
    try:
        import time
        us = time.ticks_us()
    except (ImportError, AttributeError):
        us = 0
    h = sha256(seed)
    h.update(str(us).encode())
    return h.digest()[:4]


def hasher():
    """A new sha256 object: hashlib's, or firmware.sha256's on a port without hashlib."""
    return sha256()


class Auth:
    def __init__(self, store, spend, entropy=None):
        """``store``: the TableStore (its directory and atomic file replace);
        ``spend()``: True if a flash write is allowed now (the wear budget);
        ``entropy()``: 4 bytes that differ from boot to boot (the board's, firmware/board.py), or None."""
        self.store = store
        self.spend = spend
        self._ipad = None
        self._opad = None
        self.signed_with = b""  # the prefix the last authorised tag was bound to
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
        # the session nonce: 16-bit halves (small ints: reading them allocates nothing); the low half
        # moves on by one every _SESSION_MS (``tick``), ``epoch`` counts the moves
        e = entropy() if entropy is not None else _entropy(struct.pack("<I", self.last) + (self._ipad or b""))
        self.nonce_hi = e[0] << 8 | e[1]
        self._lo0 = e[2] << 8 | e[3]
        self.nonce_lo = self._lo0
        self.epoch = 0
        self.session_ms = 0

    def tick(self, dt):
        """``dt`` ms of uptime (App.cycle; allocation-free): the nonce moves on every _SESSION_MS."""
        v = self.session_ms + dt
        if v >= _SESSION_MS:
            v = 0 if v >= 2 * _SESSION_MS else v - _SESSION_MS
            self.epoch += 1
            self.nonce_lo = (self._lo0 + self.epoch) & 0xFFFF
        self.session_ms = v

    def nonce(self, back=0):
        """The session nonce (4 bytes, big-endian) ``back`` moves ago."""
        lo = (self._lo0 + self.epoch - back) & 0xFFFF
        return bytes((self.nonce_hi >> 8, self.nonce_hi & 0xFF, lo >> 8, lo & 0xFF))

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
                # a mark above the largest counter (written before the window existed) means exhausted
                v = struct.unpack_from("<I", b, 3)[0]
                return v if v < _MAX_COUNTER else _MAX_COUNTER
        return 0

    def mac(self, msg, extra=b"", prefix=b""):
        """The tag of ``prefix`` + ``msg`` + ``extra``: HMAC-SHA256 (RFC 2104) truncated to _TAG_BYTES."""
        h = sha256(self._ipad)
        if prefix:
            h.update(prefix)
        h.update(msg)
        if extra:
            h.update(extra)
        o = sha256(self._opad)
        o.update(h.digest())
        return o.digest()[:_TAG_BYTES]

    def check(self, counter, tag, msg, extra=b"", bound=None):
        """OK if ``tag`` authorises ``msg`` + ``extra`` with a fresh ``counter`` (now used up),
        else the reason; a refusal changes nothing. The tag is bound to this session's current or
        previous nonce, or to ``bound`` (an upload's ``upload_id``); ``self.signed_with`` is then the
        prefix that held."""
        why = self._check(counter, tag, msg, extra, bound)
        self.why = why
        return why

    def upload_id(self, counter):
        """What binds an upload's chunks and commit to its U,B: the nonce that U,B was signed with and its counter."""
        return self.signed_with + struct.pack(">I", counter)

    def chunk_ok(self, tag, msg, bound):
        """Whether ``tag`` authorises ``msg`` (a U,D line up to its data) for the upload ``bound``; no counter."""
        return self._ipad is not None and self._same(self.mac(msg, b"", bound), tag)

    def _same(self, m, tag):
        d = len(tag) ^ _TAG_BYTES
        if not d:
            for i in range(_TAG_BYTES):  # every byte, whatever the first difference: no timing hint
                d |= m[i] ^ tag[i]
        return not d

    def _check(self, counter, tag, msg, extra, bound):
        if self._ipad is None:
            return NO_KEY
        for p in ((bound,) if bound is not None else (self.nonce(), self.nonce(1)) if self.epoch else (self.nonce(),)):
            if self._same(self.mac(msg, extra, p), tag):
                self.signed_with = p
                break
        else:
            return BAD_TAG
        if counter <= self.last:
            return REPLAY
        if self.last >= _MAX_COUNTER:
            return EXHAUSTED
        if counter > self.last + _COUNTER_WINDOW or counter > _MAX_COUNTER:
            return JUMP
        if counter > self.reserved:
            if not self.spend():
                return BUSY
            mark = counter + _BLOCK
            if mark > _MAX_COUNTER:
                mark = _MAX_COUNTER
            b = b"TA\x01" + struct.pack("<I", mark)
            try:
                self.store.replace_file("auth.bin", b + struct.pack("<H", crc16_ccitt(b)))
            except OSError:
                return NOT_STORED
            self.reserved = mark
        self.last = counter
        return OK
