"""CRC-32 (IEEE 802.3, reflected, poly 0xEDB88320; the zlib/binascii CRC) for table checks.

Uses ``binascii.crc32`` when the port has it (CPython, the MicroPython unix,
rp2 and stm32 ports) and falls back to a 16-entry nibble table, which costs
64 bytes of RAM instead of the usual 1 kB byte table.
Check value: crc32(b"123456789") == 0xCBF43926.
"""
try:
    from binascii import crc32 as _native
except ImportError:  # pragma: no cover - ports built without MICROPY_PY_BINASCII_CRC32
    _native = None

_NIBBLE = (
    0x00000000, 0x1DB71064, 0x3B6E20C8, 0x26D930AC, 0x76DC4190, 0x6B6B51F4, 0x4DB26158, 0x5005713C,
    0xEDB88320, 0xF00F9344, 0xD6D6A3E8, 0xCB61B38C, 0x9B64C2B0, 0x86D3D2D4, 0xA00AE278, 0xBDBDF21C,
)


def crc32_nibble(data, crc=0):
    """Table-free fallback (16-entry table); same result as binascii.crc32."""
    crc ^= 0xFFFFFFFF
    t = _NIBBLE
    for b in data:
        crc ^= b
        crc = (crc >> 4) ^ t[crc & 15]
        crc = (crc >> 4) ^ t[crc & 15]
    return crc ^ 0xFFFFFFFF


def crc32(data, crc=0):
    """CRC-32 of ``data`` (bytes, bytearray or memoryview), continuing from ``crc``."""
    if _native is not None:
        return _native(data, crc) & 0xFFFFFFFF
    return crc32_nibble(data, crc)
