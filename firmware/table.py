"""Coefficient-table loader (docs/table-format.md): verify, then parse into a Table.

The table is data: it is parsed field by field, nothing in it is executed or
imported. Every rejection raises TableError whose ``reason`` is one of the
REASON_* strings below, so callers (and the protocol's error frames) can name it.
Runs unchanged on MicroPython and CPython.

Integer constants are ``_``-prefixed ``const()`` (folded into the bytecode, no
name stored on MicroPython); on CPython the end of the module publishes them
under their public names (``VERSION``, ``HEADER_SIZE``, ``KIND_*``, ...) for
the exporter (models_export/tableformat.py) and the tests.
"""
import struct

from firmware.crc32 import crc32

try:
    from micropython import const
except ImportError:  # CPython
    const = lambda x: x  # noqa: E731

MAGIC = b"TCTB"
_VERSION = const(1)
_HEADER_SIZE = const(64)
_NAME_SIZE = const(16)
_MAX_SENSORS = const(24)
_MAX_SEGMENTS = const(32)
_MAX_DEGREE = const(6)
_UNIT_CODE = const(1)  # offsets in 0.01 um, slopes in 0.01 um/m
_REF_FIXED = const(0)  # the model uses the table's reference temperatures
_REF_LATCHED = const(1)  # certified for any reference in the envelope (models fitted on rises from the run start)

_KIND_POLY_SLOPE = const(1)
_KIND_LINEAR_DIRECT = const(2)
_KIND_SCREW_REDUCED = const(3)
KINDS = {1: "poly_slope", 2: "linear_direct", 3: "screw_reduced"}

REASON_TRUNCATED = "truncated"
REASON_MAGIC = "bad magic"
REASON_VERSION = "unsupported version"
REASON_KIND = "unknown model kind"
REASON_LENGTH = "length mismatch"
REASON_CRC = "CRC mismatch"
REASON_SENSORS = "sensor count mismatch"
REASON_UNIT = "unsupported output unit"
REASON_FIELD = "invalid field"


class TableError(ValueError):
    """A table the firmware must not use. ``reason`` is a REASON_* constant; str() adds detail."""

    def __init__(self, reason, detail=""):
        self.reason = reason
        self.detail = detail
        super().__init__(reason + (": " + detail if detail else ""))


class Table:
    """A verified table. Attributes (ints unless noted; temperatures in milli-degC,
    positions in um; scales are fraction bits):

    kind (str), kind_code, version, axis (str), sensors (list of str, channel order),
    n_sensors, env_lo/env_hi/ref (lists, milli-degC), ref_mode (0: references fixed,
    1: certified for references latched anywhere in the envelope), pos_lo/pos_hi/pos_ref (um),
    unit_code, provenance (32 bytes, the model document's sha256), crc,
    and the kind-specific coefficients documented in docs/table-format.md
    (fo, Lt, nt, S0, fS, b, shb, fb, ...).
    """

    def __init__(self):
        self.version = 0
        self.kind_code = 0
        self.kind = ""
        self.n_sensors = 0
        self.unit_code = 0
        self.ref_mode = 0
        self.provenance = b""
        self.axis = ""
        self.crc = 0
        self.sensors = []
        self.env_lo = []
        self.env_hi = []
        self.ref = []


class _Words:
    """Sequential reader of the payload's int32 words (parse time only)."""

    def __init__(self, buf, off, count):
        self.buf = buf
        self.off = off
        self.end = off + 4 * count

    def take(self, name):
        if self.off + 4 > self.end:
            raise TableError(REASON_LENGTH, "payload too short at field " + name)
        v = struct.unpack_from("<i", self.buf, self.off)[0]
        self.off += 4
        return v

    def take_list(self, name, n):
        out = []
        for i in range(n):
            out.append(self.take("%s[%d]" % (name, i)))
        return out

    def take_range(self, name, lo, hi):
        v = self.take(name)
        if v < lo or v > hi:
            raise TableError(REASON_FIELD, "%s=%d outside %d..%d" % (name, v, lo, hi))
        return v


def parse_table(buf, expected_sensors=None):
    """Verify ``buf`` (bytes/bytearray/memoryview) and return a Table.

    ``expected_sensors``: number of channels the board has wired; a table for a
    different count is refused with REASON_SENSORS. Checks, in order: length,
    magic, version, kind, declared length, CRC-32, unit, field ranges.
    """
    n = len(buf)
    if n < _HEADER_SIZE + 4:
        raise TableError(REASON_TRUNCATED, "%d bytes, header needs %d" % (n, _HEADER_SIZE + 4))
    if bytes(buf[0:4]) != MAGIC:
        raise TableError(REASON_MAGIC, "expected %r" % MAGIC)
    version = buf[4]
    if version != _VERSION:
        raise TableError(REASON_VERSION, "version %d, this firmware reads %d" % (version, _VERSION))
    kind = buf[5]
    if kind not in KINDS:
        raise TableError(REASON_KIND, "kind code %d" % kind)
    total = struct.unpack_from("<I", buf, 8)[0]
    if total > n:
        raise TableError(REASON_TRUNCATED, "%d bytes, header declares %d" % (n, total))
    if total != n:
        raise TableError(REASON_LENGTH, "%d bytes, header declares %d" % (n, total))
    stored = struct.unpack_from("<I", buf, n - 4)[0]
    if crc32(memoryview(buf)[0:n - 4]) != stored:
        raise TableError(REASON_CRC, "stored 0x%08x" % stored)
    # Past the CRC every field is as the exporter wrote it; the checks below
    # guard against an exporter/firmware mismatch rather than corruption.
    ns = buf[6]
    if ns > _MAX_SENSORS:
        raise TableError(REASON_SENSORS, "%d sensors, at most %d" % (ns, _MAX_SENSORS))
    if expected_sensors is not None and ns != expected_sensors:
        raise TableError(REASON_SENSORS, "table has %d sensors, board has %d" % (ns, expected_sensors))
    if buf[7] != _UNIT_CODE:
        raise TableError(REASON_UNIT, "unit code %d" % buf[7])
    nwords = struct.unpack_from("<I", buf, 52)[0]
    if buf[56] > 1:
        raise TableError(REASON_FIELD, "reference mode %d" % buf[56])
    for i in range(57, 64):
        if buf[i] != 0:
            raise TableError(REASON_FIELD, "reserved byte %d is not zero" % i)
    payload = _HEADER_SIZE + ns * (_NAME_SIZE + 12)
    if payload + 4 * nwords + 4 != n:
        raise TableError(REASON_LENGTH, "%d sensors and %d words need %d bytes, table has %d"
                         % (ns, nwords, payload + 4 * nwords + 4, n))
    t = Table()
    t.version = version
    t.kind_code = kind
    t.kind = KINDS[kind]
    t.n_sensors = ns
    t.unit_code = buf[7]
    t.ref_mode = buf[56]
    t.provenance = bytes(buf[12:44])
    t.axis = _name(buf, 44, 8)
    t.crc = stored
    for i in range(ns):
        t.sensors.append(_name(buf, _HEADER_SIZE + i * _NAME_SIZE, _NAME_SIZE))
    off = _HEADER_SIZE + ns * _NAME_SIZE
    for i in range(ns):
        lo, hi, ref = struct.unpack_from("<iii", buf, off + 12 * i)
        if lo > hi:
            raise TableError(REASON_FIELD, "sensor %s envelope %d > %d" % (t.sensors[i], lo, hi))
        t.env_lo.append(lo)
        t.env_hi.append(hi)
        t.ref.append(ref)
    w = _Words(buf, payload, nwords)
    _common(t, w)
    if kind != _KIND_LINEAR_DIRECT:
        _position(t, w)
    if kind == _KIND_SCREW_REDUCED:
        _screw(t, w)
    if w.off != w.end:
        raise TableError(REASON_LENGTH, "%d unread payload words" % ((w.end - w.off) // 4))
    return t


def _name(buf, off, size):
    raw = bytes(buf[off:off + size])
    end = raw.find(b"\x00")
    if end < 0:
        end = size
    if end == 0:
        raise TableError(REASON_FIELD, "empty name at byte %d" % off)
    for c in raw[end:]:
        if c != 0:
            raise TableError(REASON_FIELD, "name at byte %d not NUL-padded" % off)
    return raw[:end].decode()


_SH = const(62)  # shifts beyond this are exporter bugs; a 31-bit port could not use them
_SCALE = const(1000)  # fraction bits of a coefficient (informational, not used by the evaluation)


def _common(t, w):
    t.pos_lo = w.take("pos_lo")
    t.pos_hi = w.take("pos_hi")
    t.pos_ref = w.take("pos_ref")
    if t.pos_lo > t.pos_hi or not t.pos_lo <= t.pos_ref <= t.pos_hi:
        raise TableError(REASON_FIELD, "position envelope %d..%d, reference %d" % (t.pos_lo, t.pos_hi, t.pos_ref))
    t.fo = w.take_range("fo", 0, 30)
    t.Lt = w.take_range("Lt", 1, 29)
    t.nt = w.take_range("nt", 1, 4)
    t.S0 = w.take("S0")
    t.fS = w.take_range("fS", -_SCALE, _SCALE)
    t.b = []
    t.shb = []
    t.fb = []
    for i in range(t.n_sensors):
        t.b.append(w.take("b[%d]" % i))
        t.shb.append(w.take_range("shb[%d]" % i, -_SH, _SH))
        t.fb.append(w.take_range("fb[%d]" % i, -_SCALE, _SCALE))
    t.rL = w.take("rL")


def _position(t, w):
    t.Lw = w.take_range("Lw", 1, 29)
    t.nw = w.take_range("nw", 1, 6)
    t.shw = w.take_range("shw", -_SH, _SH)
    t.KS = w.take("KS")
    t.shK = w.take_range("shK", -_SH, _SH)
    t.fK = w.take_range("fK", 0, 30)
    t.rK = w.take("rK")
    t.rT = w.take("rT")
    t.degree = w.take_range("degree", 0, _MAX_DEGREE)
    t.Lg = w.take_range("Lg", 1, 29)
    t.ng = w.take_range("ng", 1, 6)
    t.G = w.take_list("G", t.degree + 1)
    t.fG = w.take_list("fG", t.degree + 1)
    t.shg = w.take_list("shg", t.degree)
    t.rO = w.take("rO")


def _screw(t, w):
    m = t.M = w.take_range("M", 1, _MAX_SEGMENTS)
    t.dt_ms = w.take_range("dt_ms", 1, 3600000)
    t.fixed_end = w.take("fixed_end")
    t.fmax = w.take_range("fmax", 0, 1 << 20)
    t.edges = w.take_list("edges", m + 1)
    if t.edges[0] != 0:
        raise TableError(REASON_FIELD, "edges[0]=%d, must be 0" % t.edges[0])
    for i in range(m):
        if t.edges[i + 1] <= t.edges[i]:
            raise TableError(REASON_FIELD, "edges not ascending at %d" % (i + 1))
    t.ft = w.take_range("ft", 0, 30)
    t.Tmax = w.take_range("Tmax", 0, (1 << 30) - 1)
    t.Ls = w.take_range("Ls", 1, 29)
    t.ns = w.take_range("ns", 1, 6)
    t.fc = w.take_range("fc", 0, _SH)
    t.gs = w.take_range("gs", 0, 30)
    t.C = w.take_list("C", m * m)
    t.umax = w.take_range("umax", 0, (1 << 30) - 1)
    t.Lu = w.take_range("Lu", 1, 29)
    t.nu = w.take_range("nu", 1, 4)
    t.B = w.take_list("B", m)
    t.shB = w.take_list("shB", m)
    t.rS = w.take_list("rS", m)
    t.G2 = w.take_list("G2", m)
    t.shG2 = w.take_list("shG2", m)
    t.H = w.take("H")
    t.shH = w.take_range("shH", -_SH, _SH)
    t.fh = w.take_range("fh", -_SCALE, _SCALE)
    t.Lx = w.take_range("Lx", 1, 29)
    t.nx = w.take_range("nx", 1, 6)
    t.shX = w.take_range("shX", -_SH, _SH)
    t.KC = w.take("KC")
    t.Lc = w.take_range("Lc", 1, 29)
    t.nc = w.take_range("nc", 1, 6)
    t.shC = w.take_range("shC", -_SH, _SH)


try:
    import micropython  # noqa: F401
except ImportError:  # CPython: the constants under their public names (see the module docstring)
    _g = globals()
    for _k in [k for k in _g if k[:1] == "_" and k[1:2].isupper() and k == k.upper()]:
        _g[_k[1:]] = _g[_k]
