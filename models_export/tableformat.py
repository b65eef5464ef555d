"""Write the binary coefficient table (docs/table-format.md); firmware/table.py reads it.

``pack(fields)`` takes the same names the firmware's Table exposes and lays
them out in the order ``payload_words`` gives. That order is not written here:
it is firmware/table.py's section specs (``model_sections``, ``CERT``,
``PER_SENSOR``, ``SENSOR_FIELDS``), the ones the loader reads by, so the two
cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
import struct
import types

from firmware.crc32 import crc32
# The ignores: firmware/table.py defines these as _NAME consts (free on MicroPython) and publishes them under
# NAME through globals() on CPython only, which pyright cannot follow.
from firmware.table import (AXIS_SIZE, CERT, HEADER_SIZE, KINDS, MAGIC,  # pyright: ignore[reportAttributeAccessIssue]
                            NAME_FORBIDDEN, NAME_SIZE, PER_SENSOR, SENSOR_FIELDS,  # pyright: ignore[reportAttributeAccessIssue]
                            SENSOR_SIZE, UNIT_CODE, VERSION, list_length, model_sections)  # pyright: ignore[reportAttributeAccessIssue]

KIND_CODES = {name: code for code, name in KINDS.items()}  # the firmware's table owns the codes


def spec_names(spec: str) -> list[tuple[str, bool]]:
    """The field names of one section spec of firmware/table.py, in order, each as (name, is_list);
    the per-sensor group ``@`` gives PER_SENSOR's names as lists."""
    out = []
    for word in spec.split():
        if word == "|":
            continue
        if word == "@":
            out += [(p.split(":")[0], True) for p in PER_SENSOR.split()]
        elif word[-2:-1] == "=":
            out.append((word[:-2], True))
        else:
            out.append((word.split(":")[0], False))
    return out


def payload_words(f: Mapping[str, Any]) -> list[tuple[str, int]]:
    """The payload as a list of (name, int) in table order; the certificate closes it."""
    t = types.SimpleNamespace(**{k: v for k, v in f.items() if isinstance(k, str) and k.isidentifier()})
    out = []
    for spec in list(model_sections(KIND_CODES[f["kind"]], t)) + [CERT]:
        out += _section_words(spec, f, t)
    return out


def _section_words(spec, f, t):
    out = []
    for word in spec.split():
        if word == "|":
            continue
        if word == "@":
            names = [p.split(":")[0] for p in PER_SENSOR.split()]
            for i in range(len(f["sensors"])):
                out += [("%s[%d]" % (name, i), _entry(f, name, i)) for name in names]
        elif word[-2:-1] == "=":
            name = word[:-2]
            n = list_length(word[-1], t)
            if len(f[name]) != n:
                raise ValueError("table field %s has %d entries, the table's layout needs %d" % (name, len(f[name]), n))
            out += [("%s[%d]" % (name, j), v) for j, v in enumerate(f[name])]
        else:
            name = word.split(":")[0]
            out.append((name, f[name]))
    return out


def _entry(f, name, i):
    if len(f[name]) != len(f["sensors"]):
        raise ValueError("table field %s has %d entries for %d sensors" % (name, len(f[name]), len(f["sensors"])))
    return f[name][i]


def _fixed(text, size, what):
    try:
        raw = text.encode("ascii")
    except UnicodeEncodeError:
        raw = b""  # refused below with the same message as an empty or long name
    if not raw or len(raw) > size or any(c < 32 or c > 126 or c in NAME_FORBIDDEN for c in raw):
        raise ValueError("%s %r must be 1..%d ASCII characters, printable, without , * $ (the firmware's rule)"
                         % (what, text, size))
    return raw + b"\x00" * (size - len(raw))


def pack(f: Mapping[str, Any]) -> bytes:
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
    out += _fixed(f["axis"], AXIS_SIZE, "axis name")
    out += struct.pack("<I", len(words))
    out += struct.pack("<BBB", f.get("ref_mode", 0), 1 if f.get("edited") else 0, f.get("error_ref", 0))
    out += b"\x00" * 5
    for name in sensors:
        out += _fixed(name, NAME_SIZE, "sensor name")
    # the training range (format 3) defaults to the envelope: nothing extrapolates
    train = {"train_lo": f.get("train_lo") or f["env_lo"], "train_hi": f.get("train_hi") or f["env_hi"]}
    for i in range(n):
        row = []
        for name in SENSOR_FIELDS.split():
            v = train[name][i] if name in train else f[name][i]
            if not -(1 << 31) <= v < (1 << 31):
                raise ValueError("sensor %s: %s=%r mC is not a 32-bit integer" % (sensors[i], name, v))
            row.append(v)
        v = dict(zip(SENSOR_FIELDS.split(), row))
        if not v["env_lo"] <= v["train_lo"] <= v["train_hi"] <= v["env_hi"]:
            raise ValueError("sensor %s: training range %d..%d mC is not inside the envelope %d..%d mC"
                             % (sensors[i], v["train_lo"], v["train_hi"], v["env_lo"], v["env_hi"]))
        out += struct.pack("<iiiii", *row)
    for _, v in words:
        out += struct.pack("<i", v)
    out += struct.pack("<I", crc32(bytes(out)))
    assert len(out) == total
    return bytes(out)
