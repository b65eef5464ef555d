"""The host side of the board link: the $TC frame codec (docs/protocol.md).

Used by ``tcomp monitor`` and by the HIL rig (hil_tests/rig). It is written
independently of the firmware's frame code: CRC-16/CCITT-FALSE comes from
``binascii.crc_hqx``, so a firmware CRC bug cannot cancel itself out.
"""

from __future__ import annotations

from collections.abc import Iterable
import binascii
from dataclasses import dataclass, field

from firmware import wire
from firmware.wire import FALLBACK, HELD, PROTOCOL_VERSION, RATE_LIMITED, RECOVERING, SENSOR_MASK  # noqa: F401
from firmware.wire import ERROR_REFERENCE_START, HELLO_COUNTER, HELLO_ERROR_REFERENCE  # noqa: F401

# {bit: name} of the flag bits above the sensor bits, in bit order, read from the wire contract
STATUS_BITS = dict(sorted((value, name) for name, value in vars(wire).items()
                          if name.isupper() and isinstance(value, int) and value > SENSOR_MASK
                          and value & (value - 1) == 0))


def crc16(body: bytes) -> int:
    return binascii.crc_hqx(body, 0xFFFF)


def body(fields: Iterable[bytes | str | int]) -> bytes:
    """``TC,<fields>``: the bytes the CRC covers (and an authorised command's tag, up to its counter)."""
    return b"TC," + b",".join(f if isinstance(f, bytes) else str(f).encode() for f in fields)


def command_line(*fields: bytes | str | int) -> bytes:
    """``$TC,<fields>*CRC\\r\\n`` as bytes."""
    b = body(fields)
    return b"$" + b + b"*%04X\r\n" % crc16(b)


@dataclass
class Frame:
    seq: int
    status: int
    kind: str
    fields: list
    raw: bytes
    arrival: float = 0.0
    extra: dict = field(default_factory=dict)

    def status_names(self) -> list[str]:
        names = [n for bit, n in STATUS_BITS.items() if self.status & bit]
        sensors = self.status & SENSOR_MASK
        if sensors:
            names.append("SENSORS:%04X" % sensors)
        return names

    # O / Q frames: t_ms, pos_um, total um, offset at ref um, slope um/m
    @property
    def t_ms(self) -> int:
        return int(self.fields[0])

    @property
    def total_um(self) -> float:
        return float(self.fields[2])

    @property
    def pos_um(self) -> int:
        return int(self.fields[1])


def hello_error_reference(frame: Frame) -> str | None:
    """The error reference an ``H`` frame reports: "start", a sensor name, "-" (no table), or None (a firmware before it)."""
    return frame.fields[HELLO_ERROR_REFERENCE] if len(frame.fields) > HELLO_ERROR_REFERENCE else None


def describe_error_reference(ref: str | None) -> str:
    """What the offsets of a table with error reference ``ref`` compensate (docs/linuxcnc.md, "Error reference")."""
    if ref is None:
        return "not reported (a firmware before issue 19: raw errors)"
    if ref == "-":
        return "none (no table)"
    if ref == ERROR_REFERENCE_START:
        return "start: offsets bring the axis to its positions relative to the cold machine"
    return "%s: offsets bring the axis to the positions of a workpiece at sensor %s's temperature" % (ref, ref)


class FrameError(ValueError):
    pass


def parse_line(line: bytes) -> Frame:
    """One line without CR LF -> Frame; FrameError naming what is wrong."""
    if not line.startswith(b"$") or len(line) < 9 or line[-5:-4] != b"*":
        raise FrameError("not a $...*XXXX frame: %r" % line[:80])
    body = line[1:-5]
    try:
        crc = int(line[-4:], 16)
    except ValueError:
        raise FrameError("bad CRC digits: %r" % line[:80])
    if crc16(body) != crc:
        raise FrameError("CRC mismatch (%04X computed, %04X sent): %r" % (crc16(body), crc, line[:80]))
    parts = body.decode("ascii").split(",")
    if parts[0] != "TC" or len(parts) < 4 or len(parts[3]) != 1:
        raise FrameError("bad header: %r" % line[:80])
    return Frame(int(parts[1]), int(parts[2], 16), parts[3], parts[4:], bytes(line))


class StreamDecoder:
    """Feed bytes, get frames; keeps malformed lines in ``bad``."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.bad = []

    def feed(self, data: bytes, arrival: float = 0.0) -> list[Frame]:
        self.buf += data
        out = []
        while True:
            i = self.buf.find(b"\n")
            if i < 0:
                break
            line = bytes(self.buf[:i]).rstrip(b"\r")
            del self.buf[:i + 1]
            if not line:
                continue
            try:
                f = parse_line(line)
                f.arrival = arrival
                out.append(f)
            except (FrameError, ValueError, UnicodeDecodeError) as exc:
                self.bad.append((line, str(exc)))
        return out
