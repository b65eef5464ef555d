"""CRC-16 variants used on the serial link (table-driven, allocation-free).

- CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout;
  check value for b"123456789" is 0x29B1) protects $TC frames and upload chunks.
- CRC-16/MODBUS (poly 0x8005 reflected = 0xA001, init 0xFFFF, reflected,
  no xorout; check 0x4B37) protects Modbus RTU frames, sent low byte first.
"""

from array import array


def _table(poly, reflected):
    t = array("H", bytes(512))
    for i in range(256):
        if reflected:
            c = i
            for _ in range(8):
                c = (c >> 1) ^ poly if c & 1 else c >> 1
        else:
            c = i << 8
            for _ in range(8):
                c = ((c << 1) ^ poly) & 0xFFFF if c & 0x8000 else (c << 1) & 0xFFFF
        t[i] = c
    return t


_CCITT = _table(0x1021, False)
_MODBUS = _table(0xA001, True)


def crc16_ccitt(buf, start=0, end=-1, crc=0xFFFF):
    """CRC-16/CCITT-FALSE of ``buf[start:end]`` (end=-1: to the end), no slicing."""
    if end < 0:
        end = len(buf)
    t = _CCITT
    for i in range(start, end):
        crc = ((crc << 8) & 0xFF00) ^ t[(crc >> 8) ^ buf[i]]
    return crc


def crc16_modbus(buf, start=0, end=-1, crc=0xFFFF):
    """CRC-16/MODBUS of ``buf[start:end]`` (end=-1: to the end)."""
    if end < 0:
        end = len(buf)
    t = _MODBUS
    for i in range(start, end):
        crc = (crc >> 8) ^ t[(crc ^ buf[i]) & 0xFF]
    return crc
