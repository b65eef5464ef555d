"""json for tcomp's MicroPython ports (the core has no json module without extmod).

``dumps``/``loads`` are C (``_json``, ports/common/modjson.c): dumps writes with CPython's default
separators (", " and ": "), loads reads what CPython's json writes. Enough for the HIL rig's control
channel and the DUT's spec file; ``separators`` and the other keyword arguments are not supported.
"""

from _json import dumps, loads


def dump(obj, stream):
    stream.write(dumps(obj))


def load(stream):
    return loads(stream.read())
