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
import sys

from firmware.crc32 import crc32

from micropython import const

MAGIC = b"TCTB"
NAME_FORBIDDEN = b",*$"  # besides non-printable bytes: the $TC frames' separators (names are sent in the hello)
_VERSION = const(8)  # 8: settle_nr after the tauc words (SETTLING of a start without the controller's values, issue 21; a version 7, 6 or 5 table still loads: 7 with SETTLING until the values come); 7: the lag states the controller supplies (tauc after the dynamic block, issue 21; a version 6 or 5 table still loads, without them); 6: the screw table's observer (obs settle_s sn sr Rn Lr nr Gn shGn rN after the screw block, issue 21; a version 5 table still loads, without it); 5: screw effect terms for speed_dependent_heat (fg g0 Gv shGv Lgu ngu) and moving_convection (D shD fe Ly ny) (issue 19), the dynamic table's observer (obs settle_s LO nO Go shO gO rG, issue 21); 4: screw effect terms Bu, shBu, Rv (issue 19), dynamic tables' power inputs Lp np shp2 shp (mr_poly, issue 23), the error reference (header byte 58, issue 19); 3: per-sensor training range (EXTRAPOLATING, issue 13); 2: screw air channel (issue 11); older tables are refused
_HEADER_SIZE = const(64)
_NAME_SIZE = const(16)
_AXIS_SIZE = const(8)
_SENSOR_SIZE = const(20)  # per sensor: envelope lo, hi, reference, training lo, hi (int32 milli-degC)
_MAX_SENSORS = const(24)
_MAX_SEGMENTS = const(32)
_MAX_DEGREE = const(6)
_MAX_SUPPLIED = const(4)  # wire.MAX_SUPPLIED: lag states the controller supplies, per table
_MAX_TAU_MS = const(1073741823)
_SETTLE_NEVER = const(1073741823)  # settle_nr of a format 7 table: SETTLING until the controller's values come
_UNIT_CODE = const(1)  # offsets in 0.01 um, slopes in 0.01 um/m
_REF_FIXED = const(0)  # the model uses the table's reference temperatures
_REF_LATCHED = const(1)  # certified for any reference in the envelope (models fitted on rises from the run start)

_KIND_POLY_SLOPE = const(1)
_KIND_LINEAR_DIRECT = const(2)
_KIND_SCREW_REDUCED = const(3)
_KIND_DYNAMIC = const(4)
KINDS = {_KIND_POLY_SLOPE: "poly_slope", _KIND_LINEAR_DIRECT: "linear_direct", _KIND_SCREW_REDUCED: "screw_reduced",
         _KIND_DYNAMIC: "dynamic"}
_MAX_FILTERS = const(8)  # dynamic: lag-filtered terms (host/learning/empirical/dynamic.py max_terms)

REASON_TRUNCATED = "truncated"
REASON_MAGIC = "bad magic"
REASON_VERSION = "unsupported version"
REASON_KIND = "unknown model kind"
REASON_LENGTH = "length mismatch"
REASON_CRC = "CRC mismatch"
REASON_SENSORS = "sensor count mismatch"
REASON_UNIT = "unsupported output unit"
REASON_FIELD = "invalid field"
REASON_CERT = "certificate"


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
    n_sensors, env_lo/env_hi/ref (lists, milli-degC; env_* is the certified envelope, inputs beyond
    it are clamped), train_lo/train_hi (lists, milli-degC: the range the model was fitted over,
    inside the envelope; beyond it the model extrapolates), ref_mode (0: references fixed,
    1: certified for references latched anywhere in the envelope), edited (1: exported from a
    model document whose recorded sha256 did not match), error_ref (the errors the model was fitted on:
    0 raw, relative to the machine at the run's start; 1 + i corrected to sensor i's temperature),
    pos_lo/pos_hi/pos_ref (um),
    cert_out/cert_ref/cert_slope (the certified output bounds),
    unit_code, provenance (32 bytes, the model document's sha256), crc,
    and the kind-specific coefficients documented in docs/table-format.md
    (fo, Lt, nt, S0, fS, b, shb, fb, ...).
    """

    # set by parse_table (annotations are for the type checker only, they cost no flash)
    version: int
    kind_code: int
    kind: str
    n_sensors: int
    unit_code: int
    ref_mode: int
    edited: int
    error_ref: int  # 0: offsets relative to the machine at its cold start; 1 + i: to a workpiece at sensor i's temperature
    positional: int  # dynamic tables: 1 when the position block follows (slope target)
    cert_out: int
    cert_ref: int
    cert_slope: int
    provenance: bytes
    axis: str
    crc: int
    sensors: list
    env_lo: list
    env_hi: list
    ref: list
    train_lo: list
    train_hi: list


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
        raise TableError(REASON_MAGIC)
    version = buf[4]
    if version > _VERSION or version < _VERSION - 3:  # formats 5 to 7 differ only by words at the end of a block
        raise TableError(REASON_VERSION, "table format version %d is no longer supported; re-export the model "
                         "with this tcomp (format %d)" % (version, _VERSION) if version < _VERSION else "%d" % version)
    kind = buf[5]
    if kind not in KINDS:
        raise TableError(REASON_KIND, "%d" % kind)
    total = struct.unpack_from("<I", buf, 8)[0]
    if total != n:
        raise TableError(REASON_TRUNCATED if total > n else REASON_LENGTH, "%d bytes, header declares %d" % (n, total))
    stored = struct.unpack_from("<I", buf, n - 4)[0]
    if crc32(memoryview(buf)[0:n - 4]) != stored:
        raise TableError(REASON_CRC, "stored 0x%08x" % stored)
    # Past the CRC every field is as the exporter wrote it; the checks below
    # guard against an exporter/firmware mismatch rather than corruption.
    ns = buf[6]
    if ns > _MAX_SENSORS:
        raise TableError(REASON_SENSORS, "%d > %d" % (ns, _MAX_SENSORS))
    if expected_sensors is not None and ns != expected_sensors:
        raise TableError(REASON_SENSORS, "table has %d sensors, board has %d" % (ns, expected_sensors))
    if buf[7] != _UNIT_CODE:
        raise TableError(REASON_UNIT, "%d" % buf[7])
    nwords = struct.unpack_from("<I", buf, 52)[0]
    for i in range(56, 64):
        if i != 58 and buf[i] > (i < 58):  # the reference mode (0 or 1), the edited mark (0 or 1), then reserved zeros
            raise TableError(REASON_FIELD, "header byte %d" % i)
    if buf[58] > ns:  # the error reference: 0 the run's start, 1 + i sensor i
        raise TableError(REASON_FIELD, "error reference %d (table has %d sensors)" % (buf[58], ns))
    payload = _HEADER_SIZE + ns * (_NAME_SIZE + _SENSOR_SIZE)
    if payload + 4 * nwords + 4 != n:
        raise TableError(REASON_LENGTH, "%d sensors, %d words" % (ns, nwords))
    t = Table()
    t.version = version
    t.kind_code = kind
    t.kind = KINDS[kind]
    t.n_sensors = ns
    t.unit_code = buf[7]
    t.ref_mode = buf[56]
    t.edited = buf[57]
    t.error_ref = buf[58]
    t.provenance = bytes(buf[12:44])
    t.axis = _name(buf, 44, _AXIS_SIZE)
    t.crc = stored
    t.sensors = []
    t.env_lo = []
    t.env_hi = []
    t.ref = []
    t.train_lo = []
    t.train_hi = []
    for i in range(ns):
        name = _name(buf, _HEADER_SIZE + i * _NAME_SIZE, _NAME_SIZE)
        if name in t.sensors:  # one channel would feed two coefficients
            raise TableError(REASON_FIELD, "sensor %s twice" % name)
        t.sensors.append(name)
        row = struct.unpack_from("<iiiii", buf, _HEADER_SIZE + ns * _NAME_SIZE + _SENSOR_SIZE * i)
        lo, hi, ref, tlo, thi = row  # the order of SENSOR_FIELDS
        if lo > hi:
            raise TableError(REASON_FIELD, "sensor %s envelope %d > %d" % (t.sensors[i], lo, hi))
        if not lo <= tlo <= thi <= hi:
            raise TableError(REASON_FIELD, "sensor %s training range %d..%d not inside the envelope %d..%d"
                             % (t.sensors[i], tlo, thi, lo, hi))
        k = 0
        for name in SENSOR_FIELDS.split():
            getattr(t, name).append(row[k])
            k += 1
    w = [payload, payload + 4 * nwords]  # read offset, end
    for spec in model_sections(kind, t):
        _fields(t, buf, w, spec)
    if w[0] == w[1]:
        raise TableError(REASON_CERT, "missing")
    _fields(t, buf, w, _CERT)
    if w[0] != w[1]:
        raise TableError(REASON_LENGTH, "%d unread payload words" % ((w[1] - w[0]) // 4))
    return t


def _name(buf, off, size):
    raw = bytes(buf[off:off + size])
    end = raw.find(b"\x00")
    if end < 0:
        end = size
    if end == 0:
        raise TableError(REASON_FIELD, "empty name at byte %d" % off)
    if raw[end:] != bytes(size - end):
        raise TableError(REASON_FIELD, "name at byte %d not NUL-padded" % off)
    # printable ASCII without the frames' separators: a name goes into the hello frame as it is,
    # and bytes that are not text would kill the decode below (a crash, issue 24)
    for i in range(end):
        c = raw[i]
        if c < 32 or c > 126 or c in NAME_FORBIDDEN:
            raise TableError(REASON_FIELD, "name at byte %d: byte %d is 0x%02x, not printable ASCII without , * $"
                             % (off, off + i, c))
    return raw[:end].decode()


_SH = const(62)  # shifts beyond this are exporter bugs; a 31-bit port could not use them
_SCALE = const(1000)  # fraction bits of a coefficient (informational, not used by the evaluation)

# The payload's fields in order (docs/table-format.md), as data rather than one
# statement per field (a third of the module's flash). A word is "name",
# "name:r" (range-checked, r indexes _RANGE_CODES) or "name=n" (a list, n
# indexes _COUNT_CODES); "|" runs a consistency check on what was read so far;
# "@" is one PER_SENSOR group per sensor (b[0] shb[0] fb[0] b[1] ...). These strings are the one
# statement of the payload's order: the exporter (models_export/tableformat.py) writes by them and
# the C header (models_export/cheader.py) takes its coefficient names from them.
_RANGE_CODES = "fLn4scdMtFThaAPN"
_LO = (0, 1, 1, 1, -_SH, -_SCALE, 0, 1, 1, 0, 0, 0, -1, -(1 << 30) + 1, 0, 1)
_HI = (30, 29, 6, 4, _SH, _SCALE, _MAX_DEGREE, _MAX_SEGMENTS, 3600000, 1 << 20, (1 << 30) - 1, _SH, _MAX_SENSORS - 1, 0, 1,
       _MAX_FILTERS)
_COUNT_CODES = "DdEQmjO"  # degree + 1, degree, M + 1, M * M, M, nf, nf * nf
PER_SENSOR = "b shb:s fb:c"  # a sensor's slope coefficient, its shift and its fraction bits
# the per-sensor block between the names and the payload: int32 each, milli-degC (_SENSOR_SIZE bytes)
SENSOR_FIELDS = "env_lo env_hi ref train_lo train_hi"
_COMMON = "pos_lo pos_hi pos_ref | fo:f Lt:L nt:4 S0 fS:c @ rL"
_POSITION = "Lw:L nw:n shw:s KS shK:s fK:f rK rT degree:d Lg:L ng:n G=D fG=D shg=d rO"
# the certificate, last: the largest |offset_at|, |ref_offset| (0.01 um) and |slope| (0.01 um/m)
# the exporter proved for every input inside the envelope; the firmware never outputs more
_CERT = "cert_out:T cert_ref:T cert_slope:T"
_SCREW = ("M:M dt_ms:t fixed_end fmax:F edges=E | ft:f Tmax:T Ls:L ns:n fc:h gs:f C=Q umax:T Lu:L nu:4 "
          "B=m shB=m rS=m G2=m shG2=m H shH:s fh:c Lx:L nx:n shX:s KC Lc:L nc:n shC:s "
          "air:a Tlo:A W0=m shW0=m W1=m shW1=m Ka shKa:s Bu=m shBu=m Rv fg:f g0 Gv shGv:s Lgu:L ngu:n D=m shD=m fe:f Ly:L ny:n |")
# dynamic: first-order lags of temperature rises, spindle speed (and its square) and feed (docs/table-format.md);
# then the observer (issue 21): obs (1: the lag states are estimated from the inputs at the first all-good cycle),
# settle_s (SETTLING until then), the gains Go[j*nf + m] (filter j's state from filter m's input), their shifts shO,
# each row's guard bits gO and rounding bias rG
# the screw's observer (format 6, issue 21): obs (1: the segment states are estimated from the nut sensor sn's rise over
# sensor sr when no stored state is restored), settle_s (SETTLING until then), the rise's clamp Rn (milli-K) and limbs,
# per segment the gain Gn, its shift shGn and the constant rN (state units)
_SCREW_OBS = "obs:P settle_s:T sn:a sr:a Rn:T Lr:L nr:4 Gn=m shGn=m rN=m |"
# the lag states the controller supplies (format 7, issue 21): per filter tauc, 0 (the board sets the state: its
# observer, or rest) or the filter's time constant in ms (the controller runs that lag over its own record of the
# spindle speed, its square or the feed, and sends the state at the table's start: `Y`, docs/protocol.md; until it
# does, the observer's row estimates it, or without gains the state is its present input)
# settle_nr (format 8): SETTLING of a start without the controller's values (those states at their rows' estimate),
# seconds after the start as settle_s; 0 without supplied states; a format 7 table reads _SETTLE_NEVER (until they come)
_DYNAMIC_SUPPLY = "tauc=j settle_nr:T |"
_DYNAMIC_SUPPLY_7 = "tauc=j |"
_DYNAMIC = ("positional:P dt_ms:t smax:F Lq:L nq:4 shq:s fmax:F Lp:L np:4 shp2:s shp:s LX:L nX:4 LY:L nY:4 nf:N "
            "src=j A=j shA=j gA=j rA=j fy=j Ylo=j Yhi=j bY=j shY=j obs:P settle_s:T LO:L nO:4 Go=O shO=O gO=j rG=j |")


def model_sections(kind, t):
    """The payload's sections before the certificate, in table order, for kind code ``kind``;
    ``t`` has the fields read so far (a dynamic table's ``positional`` flag, read in its own section,
    says whether the position section follows). The exporter writes exactly these."""
    yield _COMMON
    if kind == _KIND_DYNAMIC:
        yield _DYNAMIC
        version = getattr(t, "version", _VERSION)
        if version == _VERSION:
            yield _DYNAMIC_SUPPLY
        elif version == _VERSION - 1:  # format 7: SETTLING until the controller's values come
            yield _DYNAMIC_SUPPLY_7
            t.settle_nr = _SETTLE_NEVER if any(t.tauc) else 0
        else:  # format 5 or 6: every lag state is the board's
            t.tauc = [0] * t.nf
            t.settle_nr = 0
    if kind != _KIND_LINEAR_DIRECT and (kind != _KIND_DYNAMIC or t.positional):
        yield _POSITION
    if kind == _KIND_SCREW_REDUCED:
        yield _SCREW
        if getattr(t, "version", _VERSION) >= _VERSION - 2:
            yield _SCREW_OBS
        else:  # format 5: no observer, the cold start
            t.obs = 0
            t.settle_s = 0


def list_length(code, t):
    """Entries of a list field whose count code (_COUNT_CODES) is ``code``, from the fields ``t`` has so far."""
    g = getattr(t, "degree", 0)
    m = getattr(t, "M", 0)
    nf = getattr(t, "nf", 0)
    return (g + 1, g, m + 1, m * m, m, nf, nf * nf)[_COUNT_CODES.index(code)]


def _take(buf, w, name, r=-1):
    if w[0] + 4 > w[1]:
        raise TableError(REASON_LENGTH, "payload too short at field " + name)
    v = struct.unpack_from("<i", buf, w[0])[0]
    w[0] += 4
    if r >= 0 and not _LO[r] <= v <= _HI[r]:
        raise TableError(REASON_FIELD, "%s=%d outside %d..%d" % (name, v, _LO[r], _HI[r]))
    return v


def _fields(t, buf, w, spec):
    for f in spec.split():
        if f == "|":
            _check(t)
        elif f == "@":
            per = PER_SENSOR.split()
            for p in per:
                setattr(t, p.split(":")[0], [])
            for i in range(t.n_sensors):
                for p in per:
                    name = p.split(":")[0]
                    getattr(t, name).append(_take(buf, w, "%s[%d]" % (name, i), _RANGE_CODES.index(p[-1]) if ":" in p else -1))
        elif f[-2:-1] == "=":
            name = f[:-2]
            setattr(t, name, [_take(buf, w, "%s[%d]" % (name, i)) for i in range(list_length(f[-1], t))])
        elif f[-2:-1] == ":":
            setattr(t, f[:-2], _take(buf, w, f[:-2], _RANGE_CODES.index(f[-1])))
        else:
            setattr(t, f, _take(buf, w, f))


def _check(t):
    if hasattr(t, "nf"):
        for j in range(t.nf):
            if not -4 - 3 * t.n_sensors < t.src[j] < t.n_sensors:  # <= -4: a power of sensor (-4 - src) // 3's rise
                raise TableError(REASON_FIELD, "filter %d reads source %d" % (j, t.src[j]))
            if t.Ylo[j] > 0 or t.Yhi[j] < 0 or t.fy[j] < 0 or t.fy[j] > 28 or t.A[j] < 0:
                raise TableError(REASON_FIELD, "filter %d state box %d..%d" % (j, t.Ylo[j], t.Yhi[j]))
            if not -28 <= t.gO[j] <= 28 or (not t.obs and (t.gO[j] or t.rG[j])):
                raise TableError(REASON_FIELD, "observer row %d: guard bits %d, bias %d" % (j, t.gO[j], t.rG[j]))
            for m in range(t.nf):
                k = j * t.nf + m
                if not -_SH <= t.shO[k] <= _SH or (t.Go[k] and (not t.obs or not t.A[j])):  # gains only into lag states
                    raise TableError(REASON_FIELD, "observer gain %d,%d" % (j, m))
        if hasattr(t, "tauc"):
            k = 0
            for j in range(t.nf):
                c = t.tauc[j]
                if c:  # only a lag of the controller's signals, only with an observer (its row: the start without the values)
                    k += 1
                    if not (0 < c <= _MAX_TAU_MS and t.A[j] and -3 <= t.src[j] <= -1 and t.obs):
                        raise TableError(REASON_FIELD, "supplied state %d: tau %d ms, source %d" % (j, c, t.src[j]))
            if k > _MAX_SUPPLIED:
                raise TableError(REASON_FIELD, "%d supplied states, at most %d" % (k, _MAX_SUPPLIED))
            nr = getattr(t, "settle_nr", None)  # None: a format 7 table (set after its section)
            if nr is not None and ((not k and nr) or (k and nr < t.settle_s)):
                raise TableError(REASON_FIELD, "settle_nr %d s with %d supplied states, settle_s %d s" % (nr, k, t.settle_s))
        return
    if hasattr(t, "rN"):
        if t.sn >= t.n_sensors or t.sr >= t.n_sensors or (t.obs and (t.sn < 0 or t.sr < 0 or t.sn == t.sr)) or (
                not t.obs and (t.sn >= 0 or t.sr >= 0 or t.Rn)):
            raise TableError(REASON_FIELD, "screw observer sensors %d, %d" % (t.sn, t.sr))
        return
    if hasattr(t, "Ka"):
        if t.air >= t.n_sensors:
            raise TableError(REASON_FIELD, "air channel %d of %d sensors" % (t.air, t.n_sensors))
        return
    if not hasattr(t, "M"):
        if t.pos_lo > t.pos_hi or not t.pos_lo <= t.pos_ref <= t.pos_hi:
            raise TableError(REASON_FIELD, "position envelope %d..%d, reference %d" % (t.pos_lo, t.pos_hi, t.pos_ref))
        return
    if t.edges[0] != 0:
        raise TableError(REASON_FIELD, "edges[0]=%d, must be 0" % t.edges[0])
    for i in range(t.M):
        if t.edges[i + 1] <= t.edges[i]:
            raise TableError(REASON_FIELD, "edges not ascending at %d" % (i + 1))


if sys.implementation.name != "micropython":  # CPython: the constants under their public names (see the module docstring)
    _g = globals()
    for _k in [k for k in _g if k[:1] == "_" and k[1:2].isupper() and k == k.upper()]:
        _g[_k[1:]] = _g[_k]
