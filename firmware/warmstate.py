"""The screw model's segment state across a warm restart (docs/firmware.md, "Warm restarts").

``heat.bin`` in ``table_dir`` holds two record slots; writes alternate between them (the record's
sequence number picks the slot), so a power cut during a write can only tear the slot being
written: the other one still holds the previous record, and the loader takes the valid record with
the highest sequence number. A torn record fails its CRC-16, so the state restored is always a
complete old or new one, never a mix. The file stays open from the table's switch-in on: a write
is seek + write + flush into a buffer allocated once, so it runs inside the allocation-free cycle
(tests/firmware/test_fw_warmstate.py runs it under micropython.heap_lock()).

Record, little-endian: b"TH", version 1, M (u8), sequence (u32), the table's CRC-32 (u32), the tag
of the reference temperatures in use (u16, CRC-16/CCITT-FALSE of the int32 references), two
reserved zero bytes, M int32 segment states (the evaluator's units, 2**-ft K), and the
CRC-16/CCITT-FALSE of all preceding bytes (u16): 18 + 4*M bytes.
"""

import struct

from micropython import const

from firmware.crc16 import crc16_ccitt

_HEAD = const(16)
_SEQ_MAX = const(0x3FFFFFFF)  # a small int on a 32-bit port; at one write per 10 min, 20 000 years
# Written every _SAVE_MS of cycle time (docs/firmware.md, "Warm restarts of the screw state": the
# wear figure), at every latch (zeroed) and before an X reset (firmware/app.py).
_SAVE_MS = const(600000)


def ref_tag(refs):
    """CRC-16 of the reference temperatures (int32 each): ties a state to the references it was computed with."""
    return crc16_ccitt(struct.pack("<%di" % len(refs), *refs))


class HeatStore:
    """``heat.bin`` for ``table`` (a screw_reduced firmware.table.Table) in ``directory``."""

    def __init__(self, directory, table, tag):
        self.path = directory + "/heat.bin"
        m = self.m = table.M
        self.lo = table.Tlo
        self.hi = table.Tmax
        self.size = _HEAD + 4 * m + 2
        self.crc = struct.pack("<I", table.crc)  # bytes: the CRC-32 is no small int on a 32-bit port
        self.buf = bytearray(self.size)
        self.seq = 0
        self.f = None
        self.ms = 0  # cycle time since the last write
        self.retag(tag)

    def retag(self, tag):
        """The references changed (a latch): from now on records carry ``tag``."""
        b = self.buf
        b[0] = 84  # T
        b[1] = 72  # H
        b[2] = 1
        b[3] = self.m
        b[8:12] = self.crc
        b[12] = tag & 0xFF
        b[13] = tag >> 8
        self.tag = tag

    def load(self):
        """The newest valid state for this table and tag (a list of M ints), or None."""
        try:
            with open(self.path, "rb") as f:
                data = f.read(2 * self.size + 1)
        except OSError:
            return None
        best = None
        n = self.size
        head = bytes(self.buf[0:4])  # bytes: MicroPython never finds bytes equal to a bytearray
        ident = bytes(self.buf[8:14])
        for off in (0, n):
            r = bytes(data[off:off + n])
            if len(r) != n or r[0:4] != head or r[8:14] != ident:
                continue
            if crc16_ccitt(r, 0, n - 2) != r[n - 2] | r[n - 1] << 8:
                continue
            seq = struct.unpack_from("<I", r, 4)[0]
            T = list(struct.unpack_from("<%di" % self.m, r, _HEAD))
            if seq > _SEQ_MAX or any(v < self.lo or v > self.hi for v in T):
                continue
            if best is None or seq > best[0]:
                best = (seq, T)
        if best is None:
            return None
        self.seq = best[0]
        return best[1]

    def open(self):
        """Open the file for the cycle's writes (creating it, both slots empty, if its size is not this table's)."""
        n = 2 * self.size
        try:
            f = open(self.path, "r+b")
            f.seek(0, 2)
            if f.tell() == n:
                self.f = f
                return True
            f.close()
        except OSError:
            pass
        try:
            with open(self.path, "wb") as f:
                f.write(bytearray(n))
            self.f = open(self.path, "r+b")
            return True
        except OSError:
            self.f = None
            return False

    def tick(self, dt, T):
        """``dt`` ms of cycle time passed: write ``T`` when _SAVE_MS have since the last write."""
        v = self.ms + dt
        if v >= _SAVE_MS:
            self.save(T)
            v = 0
        self.ms = v

    def save(self, T):
        """Write ``T`` into the slot after the last record's (no allocation); False if the flash refused."""
        f = self.f
        if f is None:
            return False
        s = self.seq + 1 if self.seq < _SEQ_MAX else 1
        b = self.buf
        b[4] = s & 0xFF
        b[5] = (s >> 8) & 0xFF
        b[6] = (s >> 16) & 0xFF
        b[7] = s >> 24
        o = _HEAD
        for i in range(self.m):
            v = T[i]
            b[o] = v & 0xFF
            b[o + 1] = (v >> 8) & 0xFF
            b[o + 2] = (v >> 16) & 0xFF
            b[o + 3] = (v >> 24) & 0xFF
            o += 4
        c = crc16_ccitt(b, 0, o)
        b[o] = c & 0xFF
        b[o + 1] = c >> 8
        self.ms = 0
        try:
            f.seek(self.size if s & 1 else 0)
            f.write(b)
            f.flush()
        except OSError:
            return False
        self.seq = s
        return True

    def close(self):
        if self.f is not None:
            try:
                self.f.close()
            except OSError:
                pass
            self.f = None
