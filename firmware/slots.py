"""Two table slots in flash and the upload into the inactive one.

Files in ``table_dir``: ``table_a.bin``, ``table_b.bin`` and ``active`` (one
letter, ``A`` or ``B``). An upload is written into the slot that is not active;
only after the whole table has been received, its length and CRC-32 match what
the uploader announced and ``firmware.table.parse_table`` accepts it, ``active``
is replaced by write-new-then-rename (atomic on littlefs and POSIX). A power cut
at any point therefore leaves either the old or the new table in force, never
a mix. At boot the active slot is loaded; if it is unusable the other one is
tried, and the reason for each refusal is kept for the hello/error frames.

``refs.bin`` keeps the reference temperatures latched for a run-start table
(table.ref_mode 1), so that a warm restart does not latch warm ones: b"TR",
version 1, the table's CRC-32 (little-endian), the sensor count, one int32
(little-endian, milli-degC) per sensor, and the CRC-16/CCITT-FALSE of all that
(little-endian). Written once per latch, by the same write-new-then-rename.
"""

import os
import struct

from firmware.crc16 import crc16_ccitt
from firmware.crc32 import crc32
from firmware.table import parse_table, TableError
from firmware.auth import hasher

SLOT_NAMES = ("A", "B")
MAX_TABLE = 16384
# why stored references were not used (App.ref_state codes, docs/firmware.md)
REFS_MISSING = 4
REFS_CORRUPT = 5
REFS_FOREIGN = 6


def _exists(path):
    try:
        os.stat(path)
        return True
    except OSError:
        return False


class UploadError(Exception):
    """An upload step the firmware refuses; ``code`` is a protocol error word."""

    def __init__(self, code, detail):
        super().__init__(detail)  # MicroPython has no Exception.__init__ to call directly
        self.code = code
        self.detail = detail


class TableStore:
    def __init__(self, directory, accept=None):
        """``accept(table)`` may raise TableError to refuse a table that parses but
        does not fit the board (e.g. a sensor name it has no channel for)."""
        self.dir = directory.rstrip("/") or "/"
        self.accept = accept
        self._mkdirs()
        self.active = None  # slot index in force, or None
        self.refusals = []  # (slot letter, reason) of tables refused at boot or commit
        self._up = None  # open upload: [file, size, crc, received, running crc, sha256 (then its digest)]
        self.idle_ms = 0  # since the open upload last moved (App.cycle times it out)

    def _mkdirs(self):
        path = "/" if self.dir.startswith("/") else ""
        for part in self.dir.split("/"):
            if not part:
                continue
            path = path + part if path in ("", "/") else path + "/" + part
            if not _exists(path):
                os.mkdir(path)

    def path(self, slot):
        return "%s/table_%s.bin" % (self.dir, SLOT_NAMES[slot].lower())

    def _pointer(self):
        for name in ("active", "active.new"):
            try:
                with open(self.dir + "/" + name, "rb") as f:
                    c = f.read(1)
                if c in (b"A", b"B"):
                    return 0 if c == b"A" else 1
            except OSError:
                pass
        return None

    def _parse(self, data):
        t = parse_table(data)
        if self.accept is not None:
            self.accept(t)
        return t

    def _read(self, slot):
        path = self.path(slot)
        size = os.stat(path)[6]
        if size > MAX_TABLE:
            raise TableError("length mismatch", "%d bytes, at most %d" % (size, MAX_TABLE))
        with open(path, "rb") as f:
            return f.read(size)

    def load(self):
        """The table in force and its slot index, or (None, None); refusals recorded."""
        self.refusals = []
        first = self._pointer()
        order = (0, 1) if first is None or first == 0 else (1, 0)
        for slot in order:
            if not _exists(self.path(slot)):
                if slot == first:
                    self.refusals.append((SLOT_NAMES[slot], "missing"))
                continue
            try:
                t = self._parse(self._read(slot))
            except TableError as e:
                self.refusals.append((SLOT_NAMES[slot], str(e)))
                continue
            except OSError:
                self.refusals.append((SLOT_NAMES[slot], "unreadable"))
                continue
            self.active = slot
            return t, slot
        self.active = None
        return None, None

    # --- upload ---------------------------------------------------------------
    @property
    def uploading(self):
        return self._up is not None

    def inactive(self):
        return 1 if self.active == 0 else 0

    def begin(self, size, crc):
        if not 68 <= size <= MAX_TABLE:
            raise UploadError("range", "size %d outside 68..%d" % (size, MAX_TABLE))
        if self._up is not None:  # someone's upload: they finish or abort it, or it times out
            raise UploadError("state", "upload open")
        f = open(self.path(self.inactive()), "wb")
        self._up = [f, size, crc, 0, 0, hasher()]
        self.idle_ms = 0
        return self.inactive()

    def write(self, offset, data):
        """Append ``data`` (bytes) at ``offset``, which must be the count received so far."""
        up = self._up
        if up is None:
            raise UploadError("state", "no upload open")
        if offset != up[3]:
            raise UploadError("state", "chunk at %d, expected %d" % (offset, up[3]))
        if up[3] + len(data) > up[1]:
            raise UploadError("range", "chunk ends at %d beyond size %d" % (up[3] + len(data), up[1]))
        up[0].write(data)
        up[3] += len(data)
        up[4] = crc32(data, up[4])
        up[5].update(data)
        self.idle_ms = 0
        return up[3]

    def digest(self):
        """sha256 of the complete upload (what a commit's tag covers); the upload stays open."""
        up = self._up
        if up is None:
            raise UploadError("state", "no upload open")
        if up[3] != up[1]:
            raise UploadError("table", "received %d of %d bytes" % (up[3], up[1]))
        if not isinstance(up[5], bytes):
            up[5] = up[5].digest()  # final: no chunk can follow a complete upload
        return up[5]

    def commit(self):
        """Verify and switch to the uploaded table; returns (table, slot)."""
        up = self._up
        if up is None:
            raise UploadError("state", "no upload open")
        f, size, crc, got, running, _ = up
        self._up = None
        f.close()
        if got != size:
            raise UploadError("table", "received %d of %d bytes" % (got, size))
        if running != crc:
            raise UploadError("table", "CRC-32 %08X, announced %08X" % (running, crc))
        slot = self.inactive()
        try:
            t = self._parse(self._read(slot))
        except TableError as e:
            self.refusals = [(SLOT_NAMES[slot], str(e))]
            raise UploadError("table", str(e))
        self.replace_file("active", SLOT_NAMES[slot].encode())
        self.active = slot
        return t, slot

    def replace_file(self, name, data):
        # write-new-then-rename; '<name>.new' is read at boot when '<name>' is missing
        tmp = self.dir + "/" + name + ".new"
        with open(tmp, "wb") as g:
            g.write(data)
        try:
            os.rename(tmp, self.dir + "/" + name)
        except OSError:  # FAT cannot rename over a file
            os.remove(self.dir + "/" + name)
            os.rename(tmp, self.dir + "/" + name)

    # --- latched reference temperatures -----------------------------------------
    def load_refs(self, table):
        """The references stored for ``table`` (list, milli-degC), or why not (a REFS_* code).

        A reference outside the table's envelope counts as corrupt: the latch clamps."""
        n = table.n_sensors
        size = 10 + 4 * n
        why = REFS_MISSING
        # a complete refs.bin.new is the newest (a cut before or during the rename); a
        # partial one fails its CRC and refs.bin is used
        for name in ("refs.bin.new", "refs.bin"):
            try:
                with open(self.dir + "/" + name, "rb") as f:
                    b = f.read(size + 1)
            except OSError:
                continue
            why = REFS_CORRUPT
            if len(b) != size or b[:3] != b"TR\x01" or crc16_ccitt(b, 0, size - 2) != b[-2] | b[-1] << 8:
                continue
            crc, m = struct.unpack_from("<IB", b, 3)
            refs = list(struct.unpack_from("<%di" % n, b, 8))
            if m != n:
                continue
            if crc != table.crc:
                why = REFS_FOREIGN
                continue
            for i in range(n):
                if not table.env_lo[i] <= refs[i] <= table.env_hi[i]:
                    break
            else:
                return refs
        return why

    def save_refs(self, table, refs):
        """Store ``refs`` for ``table``; False if the flash refused (the latch stands)."""
        b = b"TR\x01" + struct.pack("<IB%di" % len(refs), table.crc, len(refs), *refs)
        try:
            self.replace_file("refs.bin", b + struct.pack("<H", crc16_ccitt(b)))
            return True
        except OSError:
            return False

    def abort(self):
        if self._up is not None:
            try:
                self._up[0].close()
            except OSError:
                pass
            self._up = None
