"""Output limiter: slew limit, maximum magnitude, hold-then-ramp-to-zero fallback.

Works on the evaluator's units (offsets in 0.01 um, slopes in 0.01 um/m) and
on three outputs: the offset at the reference position ``ref``, the slope
``slope`` and the total offset at the reported position ``total``.

The pair (ref, slope) depends on temperatures (and screw state) only, so it is
slew-limited and clamped directly. The total also moves with the axis
position, which is legitimate at any speed, so in normal operation it is
``raw total + (limited ref - raw ref) + (limited slope - raw slope) * (P - P_ref)``:
position changes pass at once, temperature-driven steps are ramped exactly as
the pair is. In fallback (model not usable, or output disabled) and while
recovering from it, the total itself ramps at the slew limit towards zero or
back to the model's value. The slope's limits are the offset limits spread
over the table's position span, so its contribution anywhere in the envelope
obeys the same um and um/s bounds.

No floats, no allocation; integers stay far below 2**30.
"""

from firmware import status as st


class Limiter:
    """``slew_um_per_s``, ``max_um``: limits; ``span_um``: largest |P - P_ref| in the envelope."""

    def __init__(self, slew_um_per_s, max_um, span_um):
        self.configure(slew_um_per_s, max_um, span_um)
        self.ref = 0
        self.slope = 0
        self.total = 0
        self.recovering = False
        self.flags = 0
        self._acc = 0  # sub-unit remainders of the step budgets (exact long-run rate)
        self._acc_s = 0

    def configure(self, slew_um_per_s, max_um, span_um):
        if span_um < 1000:
            span_um = 1000
        self.span_mm = span_um // 1000
        self.rate = slew_um_per_s * 100  # 0.01 um per second
        self.max = max_um * 100
        # slope (0.01 um/m) whose contribution over the span equals the offset limits
        self.rate_s = self.rate * 1000 // self.span_mm
        self.max_s = self.max * 1000 // self.span_mm

    def update(self, raw_ref, raw_slope, raw_total, dp_mm, usable, dt_ms):
        """Advance by ``dt_ms``; ``usable`` False means ramp to zero.

        ``dp_mm`` is P - P_ref in mm (clamped to the envelope). Returns the flags
        (RATE_LIMITED, MAG_LIMITED, RECOVERING) also kept in ``self.flags``.
        Written without helper calls returning tuples: those would allocate.
        """
        if dt_ms < 0:
            dt_ms = 0
        if dt_ms > 10000:  # a stalled loop must not earn a huge step
            dt_ms = 10000
        a = self.rate * dt_ms + self._acc
        step = a // 1000
        self._acc = a - step * 1000
        a = self.rate_s * dt_ms + self._acc_s
        step_s = a // 1000
        self._acc_s = a - step_s * 1000
        fl = 0
        if not usable:
            raw_ref = 0
            raw_slope = 0
            raw_total = 0
            self.recovering = True
        m = self.max
        ms = self.max_s
        # magnitude first, then rate: the output never exceeds either limit
        t = raw_ref
        if t > m or t < -m:
            t = m if t > 0 else -m
            fl = st.MAG_LIMITED
        v = self.ref
        if t > v + step:
            v += step
            fl |= st.RATE_LIMITED
        elif t < v - step:
            v -= step
            fl |= st.RATE_LIMITED
        else:
            v = t
        self.ref = v
        t = raw_slope
        if t > ms or t < -ms:
            t = ms if t > 0 else -ms
            fl |= st.MAG_LIMITED
        v = self.slope
        if t > v + step_s:
            v += step_s
            fl |= st.RATE_LIMITED
        elif t < v - step_s:
            v -= step_s
            fl |= st.RATE_LIMITED
        else:
            v = t
        self.slope = v
        if self.recovering:
            t = raw_total
            if t > m or t < -m:
                t = m if t > 0 else -m
                fl |= st.MAG_LIMITED
            v = self.total
            if t > v + step:
                v += step
                fl |= st.RATE_LIMITED
                if usable:
                    fl |= st.RECOVERING
            elif t < v - step:
                v -= step
                fl |= st.RATE_LIMITED
                if usable:
                    fl |= st.RECOVERING
            else:
                v = t
                if usable:
                    self.recovering = False
            self.total = v
        else:
            v = raw_total + (self.ref - raw_ref) + ((self.slope - raw_slope) * dp_mm) // 1000
            if v > m or v < -m:
                v = m if v > 0 else -m
                fl |= st.MAG_LIMITED
            self.total = v
        self.flags = fl
        return fl
