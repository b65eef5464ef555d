"""Write the binary coefficient table (docs/table-format.md); firmware/table.py reads it.

``pack(fields)`` takes the same names the firmware's Table exposes and lays
them out in the order ``payload_words`` gives, which is the order
firmware/table.py consumes them in.
"""
import struct

from firmware.crc32 import crc32
from firmware.table import HEADER_SIZE, KINDS, MAGIC, NAME_SIZE, SENSOR_SIZE, UNIT_CODE, VERSION

KIND_CODES = {name: code for code, name in KINDS.items()}  # the firmware's table owns the codes

COMMON = ("pos_lo", "pos_hi", "pos_ref", "fo", "Lt", "nt", "S0", "fS")
POSITION = ("Lw", "nw", "shw", "KS", "shK", "fK", "rK", "rT", "degree", "Lg", "ng")
SCREW_HEAD = ("M", "dt_ms", "fixed_end", "fmax")
SCREW_STATE = ("ft", "Tmax", "Ls", "ns", "fc", "gs")
SCREW_TRAVEL = ("umax", "Lu", "nu")
SCREW_TAIL = ("H", "shH", "fh", "Lx", "nx", "shX", "KC", "Lc", "nc", "shC")
SCREW_AIR_HEAD = ("air", "Tlo")  # format 2: the air channel (-1: none) and the state's lower bound
SCREW_AIR_TAIL = ("Ka", "shKa")


DYNAMIC_HEAD = ("positional", "dt_ms", "smax", "Lq", "nq", "shq", "fmax", "LX", "nX", "LY", "nY", "nf")
DYNAMIC_LISTS = ("src", "A", "shA", "gA", "rA", "fy", "Ylo", "Yhi", "bY", "shY")  # nf entries each

CERTIFICATE = ("cert_out", "cert_ref", "cert_slope")


def payload_words(f):
    """The payload as a list of (name, int) in table order; the certificate closes it."""
    return _model_words(f) + [(k, f[k]) for k in CERTIFICATE]


def _model_words(f):
    out = [(k, f[k]) for k in COMMON]
    for i in range(len(f["sensors"])):
        out += [("b[%d]" % i, f["b"][i]), ("shb[%d]" % i, f["shb"][i]), ("fb[%d]" % i, f["fb"][i])]
    out.append(("rL", f["rL"]))
    if f["kind"] == "dynamic":
        out += [(k, f[k]) for k in DYNAMIC_HEAD]
        for name in DYNAMIC_LISTS:
            out += [("%s[%d]" % (name, j), v) for j, v in enumerate(f[name])]
        if not f["positional"]:
            return out
    if f["kind"] == "linear_direct":
        return out
    out += [(k, f[k]) for k in POSITION]
    out += [("G[%d]" % j, v) for j, v in enumerate(f["G"])]
    out += [("fG[%d]" % j, v) for j, v in enumerate(f["fG"])]
    out += [("shg[%d]" % j, v) for j, v in enumerate(f["shg"])]
    out.append(("rO", f["rO"]))
    if f["kind"] != "screw_reduced":
        return out
    out += [(k, f[k]) for k in SCREW_HEAD]
    out += [("edges[%d]" % i, v) for i, v in enumerate(f["edges"])]
    out += [(k, f[k]) for k in SCREW_STATE]
    out += [("C[%d]" % i, v) for i, v in enumerate(f["C"])]
    out += [(k, f[k]) for k in SCREW_TRAVEL]
    for name in ("B", "shB", "rS", "G2", "shG2"):
        out += [("%s[%d]" % (name, i), v) for i, v in enumerate(f[name])]
    out += [(k, f[k]) for k in SCREW_TAIL]
    out += [(k, f[k]) for k in SCREW_AIR_HEAD]
    for name in ("W0", "shW0", "W1", "shW1"):
        out += [("%s[%d]" % (name, i), v) for i, v in enumerate(f[name])]
    out += [(k, f[k]) for k in SCREW_AIR_TAIL]
    return out


def _fixed(text, size, what):
    try:
        raw = text.encode("ascii")
    except UnicodeEncodeError:
        raw = b""  # refused below with the same message as an empty or long name
    if not raw or len(raw) > size or b"\x00" in raw:
        raise ValueError("%s %r must be 1..%d ASCII characters" % (what, text, size))
    return raw + b"\x00" * (size - len(raw))


def pack(f):
    """Serialise a fields dict to table bytes (header, sensors, payload words, CRC-32)."""
    words = payload_words(f)
    for name, v in words:
        if not isinstance(v, int) or not -(1 << 31) <= v < (1 << 31):
            raise ValueError("table field %s=%r is not a 32-bit integer" % (name, v))
    sensors = f["sensors"]
    n = len(sensors)
    total = HEADER_SIZE + n * (NAME_SIZE + SENSOR_SIZE) + 4 * len(words) + 4
    prov = bytes(f["provenance"])
    if len(prov) != 32:
        raise ValueError("provenance must be 32 bytes (sha256), got %d" % len(prov))
    out = bytearray()
    out += MAGIC
    out += struct.pack("<BBBBI", VERSION, KIND_CODES[f["kind"]], n, UNIT_CODE, total)
    out += prov
    out += _fixed(f["axis"], 8, "axis name")
    out += struct.pack("<I", len(words))
    out += struct.pack("<BBB", f.get("ref_mode", 0), 1 if f.get("edited") else 0, f.get("error_ref", 0))
    out += b"\x00" * 5
    for name in sensors:
        out += _fixed(name, NAME_SIZE, "sensor name")
    # the training range (format 3) defaults to the envelope: nothing extrapolates
    train = {"train_lo": f.get("train_lo") or f["env_lo"], "train_hi": f.get("train_hi") or f["env_hi"]}
    for i in range(n):
        row = []
        for name in ("env_lo", "env_hi", "ref", "train_lo", "train_hi"):
            v = train[name][i] if name in train else f[name][i]
            if not -(1 << 31) <= v < (1 << 31):
                raise ValueError("sensor %s: %s=%r mC is not a 32-bit integer" % (sensors[i], name, v))
            row.append(v)
        if not row[0] <= row[3] <= row[4] <= row[1]:
            raise ValueError("sensor %s: training range %d..%d mC is not inside the envelope %d..%d mC"
                             % (sensors[i], row[3], row[4], row[0], row[1]))
        out += struct.pack("<iiiii", *row)
    for _, v in words:
        out += struct.pack("<i", v)
    out += struct.pack("<I", crc32(bytes(out)))
    assert len(out) == total
    return bytes(out)
