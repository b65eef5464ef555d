"""Datasheet-misuse log shared by the chip models (plain Python: runs on CPython and MicroPython).

A chip model calls ``_violation(text)`` whenever the firmware uses it against its
datasheet; the scenarios assert the count stays zero. The first texts are kept in
a buffer preallocated at construction, so recording one leaves the heap as it was
(the soak scenario measures heap flatness while faults are injected).
"""
_VSLOTS = 8
_VLEN = 96


class ViolationLog:
    """Mixin: needs ``self.name`` and ``self.clock`` (with ``us``); call ``_init_violations()`` in ``__init__``."""

    def _init_violations(self):
        self.violation_count = 0
        self._vbuf = bytearray(_VSLOTS * _VLEN)

    def _violation(self, what):
        k = self.violation_count
        self.violation_count = k + 1
        if k < _VSLOTS:
            text = ("%s at %d us: %s" % (self.name, self.clock.abs_us(), what)).encode()[:_VLEN]
            o = k * _VLEN
            for i in range(_VLEN):
                self._vbuf[o + i] = text[i] if i < len(text) else 0

    @property
    def violations(self):
        out = []
        for k in range(min(self.violation_count, _VSLOTS)):
            raw = bytes(self._vbuf[k * _VLEN:(k + 1) * _VLEN])
            out.append(raw.split(b"\0")[0].decode())
        return out
