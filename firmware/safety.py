"""Output limiter: slew limit, maximum magnitude, ramp to zero and ramped recovery.

Works in the evaluator's units (offsets 0.01 um, slopes 0.01 um/m) on the
three outputs: the total offset at the reported position, the offset at the
reference position and the slope.

The total may follow the axis at any speed (a position-dependent compensation
must), but not jump because the temperatures, the table or the fault state
changed. So each cycle the model is evaluated at the current position P and
at the previous one P0 with the new state: the output at P0 moves towards the
new model value there by at most the slew step, and then follows the model's
position change from P0 to P unchanged. At a standing axis the total therefore
never moves faster than the slew limit, whatever the model does; when the
model cannot be used the target is zero and position changes are ignored.

The pair (offset at reference, slope) is one affine function of position.
It moves towards its target as a whole, both parts scaled by the same factor,
so that at no position of the table's envelope (the span) it changes by more
than the slew step: a controller applying the pair itself sees the same bound.

No floats, no allocation, no tuple returns; integers stay far below 2**30
(config limits: max_offset_um <= 100000, span <= 100 m).
"""

from micropython import const

# status word bits (firmware/wire.py; tests/firmware/test_fw_consts.py checks the copies)
_MAG_LIMITED = const(0x40000)
_RATE_LIMITED = const(0x20000)
_RECOVERING = const(0x4000000)

_MAX_DT_MS = const(10000)  # a stalled loop must not earn a huge step


def round10(v):
    """0.01 um -> 0.1 um, rounding half away from zero: the outputs' resolution on both links
    (protocol.py's $TC frames and modbus.py's registers send 0.1 um)."""
    return (v + 5) // 10 if v >= 0 else -((5 - v) // 10)


def _clamp(v, m):
    return m if v > m else (-m if v < -m else v)


def _div0(x, r):
    """x / r rounded towards zero (r > 0)."""
    return x // r if x >= 0 else -((-x) // r)


class Limiter:
    """``slew_um_per_s``, ``max_um``: limits; ``span_um``: largest |P - P_ref| in the envelope.

    The magnitudes are the config's limit or the table's certified bound, whichever is smaller:
    a table never drives the output beyond what its exporter proved it can produce."""

    def __init__(self, slew_um_per_s, max_um, span_um):
        self.configure(slew_um_per_s, max_um, span_um)
        self.ref = 0
        self.slope = 0
        self.total = 0
        self.flags = 0
        self.recovering = False
        self._acc = 0  # sub-unit remainder of the step budget (exact long-run rate)
        self._carry = 0  # budget left unused while the pair was too coarse to move

    def configure(self, slew_um_per_s, max_um, span_um, table=None):
        """``table``: its certificate caps the magnitudes further (the config can only lower them)."""
        if span_um < 1000:
            span_um = 1000
        self.span_mm = span_um // 1000
        self.rate = slew_um_per_s * 100  # 0.01 um per second
        m = max_um * 100
        # the slope whose contribution over the span equals the magnitude limit
        s = m * 1000 // self.span_mm
        r = m
        if table is not None:
            m = m if m < table.cert_out else table.cert_out
            r = r if r < table.cert_ref else table.cert_ref
            s = s if s < table.cert_slope else table.cert_slope
        self.max = m
        self.max_ref = r
        self.max_s = s

    def _span_part(self, ds):
        """|ds| * span_mm / 1000: the slope change's effect at the envelope's edge, in 0.01 um."""
        if ds < 0:
            ds = -ds
        return (ds // 1000) * self.span_mm + (ds % 1000) * self.span_mm // 1000

    def update(self, raw_ref, raw_slope, raw_total, raw_total_prev, usable, dt_ms):
        """Advance by ``dt_ms``.

        ``raw_total`` is the model at the current position, ``raw_total_prev``
        the model (same state) at the previous cycle's position; ``usable``
        False ramps everything to zero. Returns the flags (RATE_LIMITED,
        MAG_LIMITED, RECOVERING), also kept in ``self.flags``.
        """
        if dt_ms < 0:
            dt_ms = 0
        elif dt_ms > _MAX_DT_MS:
            dt_ms = _MAX_DT_MS
        a = self.rate * dt_ms + self._acc
        step = a // 1000
        self._acc = a - step * 1000
        m = self.max
        fl = 0
        if usable:
            target = raw_total_prev
            moved = raw_total - raw_total_prev
        else:
            target = 0
            moved = 0
            raw_ref = 0
            raw_slope = 0
            self.recovering = True
        # total: ramp at the previous position, then follow the axis
        if target > m or target < -m:
            target = _clamp(target, m)
            fl = _MAG_LIMITED
        v = self.total
        limited = False
        if target > v + step:
            v += step
            limited = True
        elif target < v - step:
            v -= step
            limited = True
        else:
            v = target
        v += moved
        if v > m or v < -m:
            v = _clamp(v, m)
            fl |= _MAG_LIMITED
        self.total = v
        # pair: move the affine function as a whole within the step budget
        tr = raw_ref
        ts = raw_slope
        rm = self.max_ref
        if tr > rm or tr < -rm:
            tr = _clamp(tr, rm)
            fl |= _MAG_LIMITED
        if ts > self.max_s or ts < -self.max_s:
            ts = _clamp(ts, self.max_s)
            fl |= _MAG_LIMITED
        dr = tr - self.ref
        ds = ts - self.slope
        if dr or ds:
            need = (dr if dr >= 0 else -dr) + self._span_part(ds)
            budget = step + self._carry
            if need <= budget:
                self.ref = tr
                self.slope = ts
                self._carry = 0
            else:
                limited = True
                if budget > 0:
                    if ds == 0:  # one part only: use the whole budget
                        mr = budget if dr > 0 else -budget
                        ms = 0
                    elif dr == 0:
                        mr = 0
                        ms = budget * 1000 // self.span_mm
                        if ds < 0:
                            ms = -ms
                    else:
                        r = (need + budget - 1) // budget  # ceil: the scaled move fits the budget
                        mr = _div0(dr, r)
                        ms = _div0(ds, r)
                    if mr or ms:
                        self.ref += mr
                        self.slope += ms
                        self._carry = 0
                    else:  # moves below one unit: save the budget until one fits
                        self._carry = budget if budget < need else need
        if limited:
            fl |= _RATE_LIMITED
            if usable and self.recovering:
                fl |= _RECOVERING
        elif usable:
            self.recovering = False
        self.flags = fl
        return fl
