"""Model states across a warm restart (docs/firmware.md, "Warm restarts"): the screw's segment state (``heat.bin``)
and a dynamic table's lag-filter states (``lags.bin``).

Each file in ``table_dir`` holds two record slots; writes alternate between them (the record's
sequence number picks the slot), so a power cut during a write can only tear the slot being
written: the other one still holds the previous record, and the loader takes the valid record with
the highest sequence number. A torn record fails its CRC-16, so the state restored is always a
complete old or new one, never a mix. The file stays open from the table's switch-in on: a write
is seek + write + flush into a buffer allocated once, so it runs inside the allocation-free cycle
(tests/firmware/test_fw_warmstate.py and test_fw_lagstate.py run it under micropython.heap_lock()).

Record, little-endian: a two-letter magic, version 1, a count (u8), sequence (u32), the table's
CRC-32 (u32), the tag of the reference temperatures in use (u16, CRC-16/CCITT-FALSE of the int32
references), a second count (u8) and a zero byte, the int32 words, and the CRC-16/CCITT-FALSE of
all preceding bytes (u16): 18 + 4*words bytes.
- ``heat.bin`` (b"TH"): count M, second count 0; M segment states (the evaluator's units, 2**-ft K).
- ``lags.bin`` (b"TL"): count nf, second count n (the table's sensors); nf filter states Y (the
  evaluator's units; a term without a lag holds no state and is written as the evaluator has it),
  n temperatures as the board read them at the write (milli-degC), the spindle speed (rpm) and feed
  (mm/min) in use, and the seconds the state had been settling (saturated at the larger of the table's settle_s and
  settle_nr, the latter SETTLING's end for a start without the controller's supplied states).
"""

import struct

from micropython import const

from firmware.crc16 import crc16_ccitt

_HEAD = const(16)
_SEQ_MAX = const(0x3FFFFFFF)  # a small int on a 32-bit port; at one write per 10 min, 20 000 years
# Written every _SAVE_MS of cycle time (docs/firmware.md, "Warm restarts of the screw state": the
# wear figure), at every latch and before an X reset (firmware/app.py).
_SAVE_MS = const(600000)


def ref_tag(refs):
    """CRC-16 of the reference temperatures (int32 each): ties a state to the references it was computed with."""
    return crc16_ccitt(struct.pack("<%di" % len(refs), *refs))


class _Slots:
    """The two record slots of one file (the module doc): ``words`` int32 after the head."""

    def __init__(self, path, magic, count, count2, table, tag, words):
        self.path = path
        self.size = _HEAD + 4 * words + 2
        self.words = words
        b = self.buf = bytearray(self.size)
        b[0] = magic[0]
        b[1] = magic[1]
        b[2] = 1
        b[3] = count
        b[8:12] = struct.pack("<I", table.crc)  # bytes: the CRC-32 is no small int on a 32-bit port
        b[14] = count2
        self.seq = 0
        self.f = None
        self.ms = 0  # cycle time since the last write
        self.retag(tag)

    def retag(self, tag):
        """The references changed (a latch): from now on records carry ``tag``."""
        b = self.buf
        b[12] = tag & 0xFF
        b[13] = tag >> 8
        self.tag = tag

    def _ok(self, words):
        # a subclass checks the values against its table's bounds
        return len(words) == self.words

    def load(self):
        """The words of the newest valid record for this table and tag (a list of ints), or None. Either way the next
        write's sequence number follows the highest of any intact record in the file (another table's or other
        references' too), so that a stale record can never outrank the writes from now on."""
        try:
            with open(self.path, "rb") as f:
                data = f.read(2 * self.size + 1)
        except OSError:
            return None
        best = None
        top = 0
        n = self.size
        head = bytes(self.buf[0:4])  # bytes: MicroPython never finds bytes equal to a bytearray
        ident = bytes(self.buf[8:16])
        for off in (0, n):
            r = bytes(data[off:off + n])
            if len(r) != n or r[0:4] != head or crc16_ccitt(r, 0, n - 2) != r[n - 2] | r[n - 1] << 8:
                continue
            seq = struct.unpack_from("<I", r, 4)[0]
            if seq > _SEQ_MAX:
                continue
            if seq > top:
                top = seq
            if r[8:16] != ident:
                continue
            w = list(struct.unpack_from("<%di" % self.words, r, _HEAD))
            if self._ok(w) and (best is None or seq > best[0]):
                best = (seq, w)
        self.seq = top
        return None if best is None else best[1]

    def open(self):
        """Open the file for the cycle's writes (creating it, both slots empty, if its size is not this record's)."""
        n = 2 * self.size
        try:
            f = open(self.path, "r+b")
            if f.seek(0, 2) == n:  # seek returns the new position; a port may have no tell() (QEMU's semihosting files)
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

    def _put(self, o, v):
        """Word ``v`` (int32) at byte ``o`` of the record; returns the next offset."""
        b = self.buf
        b[o] = v & 0xFF
        b[o + 1] = (v >> 8) & 0xFF
        b[o + 2] = (v >> 16) & 0xFF
        b[o + 3] = (v >> 24) & 0xFF
        return o + 4

    def _commit(self):
        """Sequence number and CRC into the record filled by _put, written into the slot after the last record's (no
        allocation); False if the flash refused."""
        f = self.f
        if f is None:
            return False
        s = self.seq + 1 if self.seq < _SEQ_MAX else 1
        b = self.buf
        b[4] = s & 0xFF
        b[5] = (s >> 8) & 0xFF
        b[6] = (s >> 16) & 0xFF
        b[7] = s >> 24
        o = self.size - 2
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

    def due(self, dt):
        """``dt`` ms of cycle time passed: True when _SAVE_MS have since the last write (the caller writes)."""
        v = self.ms + dt
        if v >= _SAVE_MS:
            self.ms = 0
            return True
        self.ms = v
        return False

    def close(self):
        if self.f is not None:
            try:
                self.f.close()
            except OSError:
                pass
            self.f = None


class HeatStore(_Slots):
    """``heat.bin`` for ``table`` (a screw_reduced firmware.table.Table) in ``directory``."""

    def __init__(self, directory, table, tag):
        self.m = table.M
        self.lo = table.Tlo
        self.hi = table.Tmax
        _Slots.__init__(self, directory + "/heat.bin", b"TH", table.M, 0, table, tag, table.M)

    def _ok(self, words):
        for v in words:
            if v < self.lo or v > self.hi:
                return False
        return True

    def tick(self, dt, T):
        """``dt`` ms of cycle time passed: write ``T`` when _SAVE_MS have since the last write."""
        if self.due(dt):
            self.save(T)

    def save(self, T):
        """Write ``T`` (no allocation); False if the flash refused."""
        o = _HEAD
        for i in range(self.m):
            o = self._put(o, T[i])
        return self._commit()


class LagStore(_Slots):
    """``lags.bin`` for ``table`` (a dynamic firmware.table.Table) in ``directory``; load() returns the record's
    words: Y (nf), temperatures (n), spindle, feed, settled seconds (the module doc)."""

    def __init__(self, directory, table, tag):
        self.t = table
        _Slots.__init__(self, directory + "/lags.bin", b"TL", table.nf, table.n_sensors, table, tag,
                        table.nf + table.n_sensors + 3)

    def _ok(self, words):
        w = words
        t = self.t
        for j in range(t.nf):
            if t.A[j] and (w[j] < t.Ylo[j] or w[j] > t.Yhi[j]):
                return False
        k = t.nf + t.n_sensors
        return w[k] >= 0 and w[k + 1] >= 0 and 0 <= w[k + 2] <= max(t.settle_s, t.settle_nr)

    def tick(self, dt, ev, settled):
        """``dt`` ms of cycle time passed: write the state when _SAVE_MS have since the last write."""
        if self.due(dt):
            self.save(ev, settled)

    def save(self, ev, settled):
        """Write the evaluator's lag states, its temperatures, spindle speed and feed and ``settled`` (no allocation)."""
        t = self.t
        o = _HEAD
        Y = ev.Y
        for j in range(t.nf):
            o = self._put(o, Y[j])
        temps = ev.temps
        for i in range(t.n_sensors):
            o = self._put(o, temps[i])
        o = self._put(o, ev.spin)
        o = self._put(o, ev.fin)
        self._put(o, settled)
        return self._commit()
