"""Integer evaluation of a coefficient table (poly_slope, linear_direct, screw_reduced, dynamic).

This is the evaluation order the exporter certifies (models_export/plan.py
mirrors it operation by operation): change one, change the other. Only integer
operations appear; with a certified table every intermediate stays inside
|x| < 2**30, the small-int range of a 32-bit MicroPython port, so evaluation
never allocates and gives the same bits on every port and on CPython.

Units: temperatures in milli-degC, positions in um (axis coordinates); offsets
in 0.01 um, slopes in 0.01 um/m. Steady-state calls (update, offset_at,
ref_offset, slope, advance_position, step) allocate nothing: all state lives in
lists created by the constructor.

Checking mode (``Evaluator(table, check=True)``, for tests; off in production)
checks every intermediate against +-2**30 (OverflowError; an ``if``, not an
``assert``, so it works in code compiled with ``mpy-cross -O3``) and records
per-accumulator minima and maxima in ``lo``/``hi`` (accumulator numbers are the ACC_*
constants), which the tests compare with the exporter's interval bounds.

The module's constants are ``_``-prefixed ``const()``: MicroPython folds those
into the bytecode and stores no name for them (public constants cost a global
and a name each, ~0.6 kB of .mpy here). On CPython the end of this module
publishes each under its public name (``ACC_D``, ``FEED_W_BITS``, ``CLAMP_*``,
...) for the exporter (models_export/plan.py) and the tests.
"""
import sys

from micropython import const

# table format values (docs/table-format.md, firmware/table.py), as local consts:
# folded into the bytecode (tests/firmware/test_fw_consts.py checks they agree)
_KIND_LINEAR_DIRECT = const(2)
_KIND_SCREW_REDUCED = const(3)
_KIND_DYNAMIC = const(4)
_REF_LATCHED = const(1)

_MAXV = const(0x3FFFFFFF)  # |intermediate| must stay <= 2**30 - 1

# Bits of Evaluator.flags: bit i (i < 24) = sensor i was clamped to its envelope.
_SENSOR_BITS = const(0xFFFFFF)
_CLAMP_POSITION = const(0x1000000)  # the last position given was outside the envelope
_CLAMP_TRAVEL = const(0x2000000)  # nut travel or feed beyond the table's bound (screw)
_CLAMP_STATE = const(0x4000000)  # a segment state hit the table's state bound (screw)
_CLAMP_INPUT = const(0x8000000)  # spindle speed or feed beyond the table's envelope (dynamic)

# Check-mode accumulators (numbered intermediates whose minima and maxima the checking mode records; not the
# table slots of firmware/slots.py): a _mul call site uses accumulator s for its limb products and s+1 for its
# shifted terms and partial sums.
_ACC_D = const(0)
_ACC_SMUL = const(1)
_ACC_S = const(3)
_ACC_P = const(4)
_ACC_THMUL = const(5)
_ACC_GEOMUL = const(7)
_ACC_GEO = const(9)
_ACC_SUM = const(10)
_ACC_OUT = const(11)
_ACC_KMUL = const(12)
_ACC_SLOPE = const(14)
_ACC_ROWMUL = const(15)
_ACC_ROW = const(16)
_ACC_LIMB = const(17)
_ACC_BMUL = const(18)
_ACC_STATE = const(20)
_ACC_CUMMUL = const(21)
_ACC_CUM = const(23)
_ACC_HMUL = const(24)
_ACC_SEGMUL = const(26)
_ACC_XL = const(28)
_ACC_TRAVEL = const(29)
_ACC_FEEDMUL = const(30)
_ACC_CMUL = const(32)
_ACC_DE = const(34)
_ACC_AMUL = const(35)
_ACC_QMUL = const(37)  # dynamic: the spindle speed squared
_ACC_DX = const(39)  # dynamic: input minus filter state
_ACC_DMUL = const(40)  # dynamic: the filter increment
_ACC_Y = const(42)  # dynamic: filter states
_ACC_YMUL = const(43)  # dynamic: coefficient x filter state
_ACC_PMUL = const(45)  # dynamic: a power of a temperature rise (S004's Eq. 12, mr_poly), one factor at a time
_ACC_GMUL = const(47)  # screw: the speed heat factor g(U) (speed_dependent_heat)
_ACC_UGMUL = const(49)  # screw: a segment's effective travel u_i x g
_ACC_EMUL = const(51)  # screw: a segment's extra convection weight D_i x U (moving_convection)
_ACC_CONVY = const(53)  # screw: a segment's state minus the air (state units)
_ACC_LMUL = const(54)  # screw: the extra convection loss, weight x (state - air)
_ACC_OMUL = const(56)  # dynamic: observer gain x filter input (issue 21)
_ACC_OSUM = const(58)  # dynamic: an observer row's sum (guard bits finer than the state)
_ACC_NMUL = const(59)  # screw observer (issue 21): gain x the nut sensor's rise
_ACC_NSUM = const(61)  # screw observer: a segment's estimate before its clamp
_N_ACCS = const(62)

_FEED_W_BITS = const(19)  # feed/range weights: fraction of the range per segment, 2**-19
_FEED_LIMB = const(10)


class Evaluator:
    """Evaluate ``table`` (a firmware.table.Table).

    Write temperatures (milli-degC, channel order) into ``temps`` or with
    ``set_temperature``, call ``update()``, then ``offset_at(pos_um)``,
    ``ref_offset()`` and ``slope()`` as often as needed. Screw tables also need
    ``advance_position(pos_um)`` on every position report (or ``set_feed``) and
    ``step()`` once per ``table.dt_ms``. A screw table with an air channel
    (``table.air`` >= 0) reads that channel in ``update()``: the screw exchanges
    heat with it (air at the previous and the current step, linear in between),
    and the state starts in equilibrium with it (construction, ``latch_references``).
    """

    def __init__(self, table, check=False):
        t = self.table = table
        self.kind = table.kind_code
        self.check = check
        n = table.n_sensors
        self.temps = [0] * n
        self.ref = list(table.ref)
        for i in range(n):
            lo, hi = table.env_lo[i], table.env_hi[i]
            self.temps[i] = 0 if lo <= 0 <= hi else lo
        self.flags = 0
        self.extrap = 0  # bit i: sensor i is evaluated outside the table's training range (inside the envelope or clamped to it)
        self.S = t.S0
        self.pos_ref = t.pos_ref
        self.direct = table.kind_code == _KIND_LINEAR_DIRECT or (table.kind_code == _KIND_DYNAMIC and not t.positional)
        self.lo = [_MAXV] * _N_ACCS
        self.hi = [-_MAXV] * _N_ACCS
        if self.kind == _KIND_SCREW_REDUCED:
            m = t.M
            self.T = [0] * m
            self.Tn = [0] * m
            self.u = [0] * m
            self.w = [0] * m
            self.limbs = [0] * (m * t.ns)
            self.cum = [0] * (m + 1)
            self.segslope = [0] * m
            self.feed = False
            self.F = 0
            self.have_x = False
            self.x = 0
            self.da = 0  # air over its reference (milli-K, clamped) at the last update() and at the last step
            self.da0 = 0
            self.dir = 0  # direction of the last position change (+1, -1; 0: none yet, or feed/range mode)
        if self.kind == _KIND_DYNAMIC:
            self.d = [0] * n  # clamped temperature minus reference, per sensor (the rises the filters read)
            self.Y = [0] * t.nf  # filter states, 2**-fy[j] input units
            self.U0 = [0] * t.nf  # each filter's input at the last step (held over the step, as the host's)
            self.Uc = [0] * t.nf  # each filter's input now
            self.spin = 0  # spindle speed (rpm) and feed (mm/min) as the controller reported them
            self.fin = 0
            self.sup_set = False  # the controller's supplied states (table.tauc) came (supply()): the board keeps them
            self.Slin = t.S0
        self.update()
        if self.kind == _KIND_SCREW_REDUCED:
            self.settle()
        elif self.kind == _KIND_DYNAMIC:
            self.rest()

    # -- checking mode ------------------------------------------------------
    def _note(self, acc_id, v):
        if v > _MAXV or v < -_MAXV:
            raise OverflowError("accumulator %d: %d outside +-2**30" % (acc_id, v))
        if v < self.lo[acc_id]:
            self.lo[acc_id] = v
        if v > self.hi[acc_id]:
            self.hi[acc_id] = v

    def _mul(self, acc_id, c, x, L, n, sh):
        """floor-ish c*x/2**sh with x split into n limbs of L bits (top limb signed).

        Each limb product c*limb stays small when |c| * 2**L < 2**30; every
        limb whose shift is positive rounds down, so the result is within
        (-k, 0] of the exact value for k such limbs (the exporter adds biases).
        """
        m = (1 << L) - 1
        r = 0
        chk = self.check
        while n > 1:
            p = c * (x & m)
            if chk:
                self._note(acc_id, p)
            if sh > 0:
                p >>= sh
            else:
                p <<= -sh
            r += p
            if chk:
                self._note(acc_id + 1, p)
                self._note(acc_id + 1, r)
            x >>= L
            sh -= L
            n -= 1
        p = c * x
        if chk:
            self._note(acc_id, p)
        if sh > 0:
            p >>= sh
        else:
            p <<= -sh
        r += p
        if chk:
            self._note(acc_id + 1, p)
            self._note(acc_id + 1, r)
        return r

    # -- temperature-dependent part -------------------------------------------
    def set_temperature(self, i, milli_c):
        self.temps[i] = milli_c

    def latch_references(self):
        """Take the current ``temps`` (clamped to the envelope) as the reference temperatures.

        For models fitted on rises from the run start (table.ref_mode == 1) the
        controller latches the temperatures at a cold start; the exporter has
        certified every reference inside the envelope. Raises ValueError for a
        table certified only for its fixed references."""
        t = self.table
        if t.ref_mode != _REF_LATCHED:
            raise ValueError("ref_mode 0: fixed references")
        for i in range(t.n_sensors):
            v = self.temps[i]
            if v < t.env_lo[i]:
                v = t.env_lo[i]
            elif v > t.env_hi[i]:
                v = t.env_hi[i]
            self.ref[i] = v
        self.update()
        if self.kind == _KIND_SCREW_REDUCED:
            self.settle()  # a latch is a cold start: the screw in equilibrium with the air
        elif self.kind == _KIND_DYNAMIC:
            self.rest()  # a latch is a cold start: every filter at rest

    def update(self):
        """Recompute the temperature-dependent terms from ``temps``; flag clamped sensors (``flags``)
        and sensors evaluated outside the training range (``extrap``)."""
        t = self.table
        chk = self.check
        temps = self.temps
        lo = t.env_lo
        hi = t.env_hi
        tlo = t.train_lo
        thi = t.train_hi
        ex = 0
        ref = self.ref
        b = t.b
        shb = t.shb
        Lt = t.Lt
        nt = t.nt
        fl = 0
        s = t.S0
        air = t.air if self.kind == _KIND_SCREW_REDUCED else -1
        dyn = self.kind == _KIND_DYNAMIC
        for i in range(t.n_sensors):
            v = temps[i]
            if v < lo[i]:
                v = lo[i]
                fl |= 1 << i
            elif v > hi[i]:
                v = hi[i]
                fl |= 1 << i
            if v < tlo[i] or v > thi[i]:
                ex |= 1 << i
            d = v - ref[i]
            if chk:
                self._note(_ACC_D, d)
            if i == air:
                self.da = d
            if dyn:
                self.d[i] = d
            s += self._mul(_ACC_SMUL, b[i], d, Lt, nt, shb[i])
            if chk:
                self._note(_ACC_S, s)
        if dyn:
            self.Slin = s
            fl |= self._inputs()
            s = self._dsum(s)
        self.S = s
        self.flags = (self.flags & ~(_SENSOR_BITS | _CLAMP_INPUT)) | fl
        self.extrap = ex

    # -- outputs --------------------------------------------------------------
    def _clamp_pos(self, pos):
        t = self.table
        if pos < t.pos_lo:
            self.flags |= _CLAMP_POSITION
            return t.pos_lo
        if pos > t.pos_hi:
            self.flags |= _CLAMP_POSITION
            return t.pos_hi
        self.flags &= ~_CLAMP_POSITION
        return pos

    def offset_at(self, pos_um):
        """Total model offset (geometric + thermal) at ``pos_um``, in 0.01 um."""
        t = self.table
        chk = self.check
        if self.direct:
            v = (self.S + t.rL) >> t.fo
            if chk:
                self._note(_ACC_SUM, self.S + t.rL)
                self._note(_ACC_OUT, v)
            return v
        p = self._clamp_pos(pos_um)
        if chk:
            self._note(_ACC_P, p)
        G = t.G
        shg = t.shg
        Lg = t.Lg
        ng = t.ng
        h = G[t.degree]
        for j in range(t.degree - 1, -1, -1):
            h = self._mul(_ACC_GEOMUL, p, h, Lg, ng, shg[j]) + G[j]
            if chk:
                self._note(_ACC_GEO, h)
        acc = h + self._mul(_ACC_THMUL, p, self.S, t.Lw, t.nw, t.shw)
        if chk:
            self._note(_ACC_SUM, acc)
        if self.kind == _KIND_SCREW_REDUCED:
            acc += self._seg(p)
            # reversal error (format 4): +Rv moving in +, -Rv moving in -, as the last position change went
            if self.dir > 0:
                acc += t.Rv
            elif self.dir < 0:
                acc -= t.Rv
            if chk:
                self._note(_ACC_SUM, acc)
        acc += t.rO
        if chk:
            self._note(_ACC_SUM, acc)
        v = acc >> t.fo
        if chk:
            self._note(_ACC_OUT, v)
        return v

    def set_reference(self, pos_um):
        """Reference position of the offset/slope pair (clamped to the envelope)."""
        self.pos_ref = self._clamp_pos(pos_um)

    def ref_offset(self):
        """Thermal offset (no geometric part) at the reference position, in 0.01 um.

        With ``slope()`` this is the Siemens/Beckhoff-style pair: thermal(P) is
        ref_offset + slope * (P - P_ref), exact for poly_slope and
        linear_direct; for screw tables the slope is the chord over the envelope.
        """
        t = self.table
        chk = self.check
        if self.direct:
            return self.offset_at(0)
        p = self.pos_ref
        acc = self._mul(_ACC_THMUL, p, self.S, t.Lw, t.nw, t.shw)
        if self.kind == _KIND_SCREW_REDUCED:
            acc += self._seg(p)
        acc += t.rT
        if chk:
            self._note(_ACC_SUM, acc)
        v = acc >> t.fo
        if chk:
            self._note(_ACC_OUT, v)
        return v

    def slope(self):
        """Thermal slope d(offset)/dP in 0.01 um/m (0 for linear_direct)."""
        t = self.table
        chk = self.check
        if self.direct:
            return 0
        acc = self._mul(_ACC_KMUL, t.KS, self.S, t.Lw, t.nw, t.shK)
        if self.kind == _KIND_SCREW_REDUCED:
            de = self._seg(t.pos_hi) - self._seg(t.pos_lo)
            if chk:
                self._note(_ACC_DE, de)
            acc += self._mul(_ACC_CMUL, t.KC, de, t.Lc, t.nc, t.shC)
        acc += t.rK
        if chk:
            self._note(_ACC_SLOPE, acc)
        v = acc >> t.fK
        if chk:
            self._note(_ACC_OUT, v)
        return v

    # -- dynamic ----------------------------------------------------------------
    def set_spindle(self, rpm):
        """Spindle speed as the controller reports it (rpm; the sign, the direction, is dropped). Read at update()."""
        self.spin = rpm if rpm >= 0 else -rpm

    def set_feed_rate(self, feed_mm_min):
        """Axis feed while it moves, 0 when idle (mm/min). Read at update()."""
        self.fin = feed_mm_min if feed_mm_min >= 0 else -feed_mm_min

    def _inputs(self):
        """Each filter's input now into Uc (clamped to the envelope; returns the flag); tau = 0 terms follow it.
        Sources: a sensor's rise (>= 0), spindle speed (-1), its square (-2), feed (-3), a power of a rise (<= -4)."""
        t = self.table
        fl = 0
        r = self.spin
        if r > t.smax:
            r = t.smax
            fl = _CLAMP_INPUT
        f = self.fin
        if f > t.fmax:
            f = t.fmax
            fl = _CLAMP_INPUT
        q = self._mul(_ACC_QMUL, r, r, t.Lq, t.nq, t.shq)  # rpm**2 / 2**shq
        src = t.src
        A = t.A
        fy = t.fy
        Uc = self.Uc
        d = self.d
        for j in range(t.nf):
            k = src[j]
            if k >= -3:
                v = d[k] if k >= 0 else (r if k == -1 else (q if k == -2 else f))
            else:  # -4 - 3*i - (e - 2): sensor i's rise x to the power e (2..4) / 2**(shp2 + shp*(e - 2)), one floored factor at a time
                k = -4 - k
                x = d[k // 3]
                v = self._mul(_ACC_PMUL, x, x, t.Lp, t.np, t.shp2)
                e = k % 3
                while e > 0:
                    v = self._mul(_ACC_PMUL, v, x, t.Lp, t.np, t.shp)
                    e -= 1
            Uc[j] = v
            if A[j] == 0:
                v <<= fy[j]
                if self.check:
                    self._note(_ACC_Y, v)
                self.Y[j] = v
        return fl

    def _dsum(self, s):
        """S plus every coefficient x filter state."""
        t = self.table
        bY = t.bY
        shY = t.shY
        Y = self.Y
        LY = t.LY
        nY = t.nY
        for j in range(t.nf):
            s += self._mul(_ACC_YMUL, bY[j], Y[j], LY, nY, shY[j])
            if self.check:
                self._note(_ACC_S, s)
        return s

    def rest(self):
        """Every filter at rest (state 0) with the present inputs as the last step's: a cold start."""
        t = self.table
        for j in range(t.nf):
            if t.A[j]:
                self.Y[j] = 0
            self.U0[j] = self.Uc[j]
        self.S = self._dsum(self.Slin)

    def observe(self):
        """The observer (issue 21, docs/firmware.md): every lag state estimated from the present inputs,
        Y[j] = (rG[j] + sum_m Go[j*nf + m] x Uc[m] / 2**(shO - gO[j])) >> gO[j] (gO < 0: a coarser row, clamped to the
        box at its scale, then shifted up), clamped to its box (the
        exact state of a filter lies in it, so the clamp only removes error); the present inputs become the
        last step's, as in rest(). A state the controller supplies (table.tauc) keeps its value once supply() set it;
        before, its row estimates it as any other (without gains: its present input, the steady state). A table without
        an observer (obs 0) gets rest(): the cold start."""
        t = self.table
        if not t.obs:
            self.rest()
            return
        chk = self.check
        nf = t.nf
        A = t.A
        Go = t.Go
        shO = t.shO
        gO = t.gO
        rG = t.rG
        Ylo = t.Ylo
        Yhi = t.Yhi
        LO = t.LO
        nO = t.nO
        Y = self.Y
        Uc = self.Uc
        tc = t.tauc
        sup = self.sup_set
        for j in range(nf):
            if A[j] and not (tc[j] and sup):  # a supplied state (tauc) keeps what the controller sent (supply())
                g = gO[j]
                acc = rG[j]
                k = j * nf
                gains = False
                for m in range(nf):
                    c = Go[k + m]
                    if c:
                        gains = True
                        acc += self._mul(_ACC_OMUL, c, Uc[m], LO, nO, shO[k + m] - g)
                        if chk:
                            self._note(_ACC_OSUM, acc)
                if tc[j] and not gains:  # a supplied state without an estimate: its present input until the values come
                    v = Uc[j] << t.fy[j]
                elif g >= 0:
                    v = acc >> g
                else:  # a row coarser than the state (an estimate that can reach far beyond its box): clamp, then scale
                    lo = Ylo[j] >> -g
                    hi = Yhi[j] >> -g
                    if acc < lo:
                        acc = lo
                    elif acc > hi:
                        acc = hi
                    v = acc << -g
                if chk:
                    self._note(_ACC_Y, v)
                if v < Ylo[j]:
                    v = Ylo[j]
                elif v > Yhi[j]:
                    v = Yhi[j]
                Y[j] = v
            self.U0[j] = Uc[j]
        self.S = self._dsum(self.Slin)

    def set_lags(self, Y):
        """Every lag state from ``Y`` (a stored or computed state, already checked against its box: a warm restart,
        firmware/warmstate.py); the present inputs become the last step's, as in rest() and observe(). A term without
        a lag keeps its input (update() sets it), a state the controller supplies (table.tauc) its value once supply() set it."""
        t = self.table
        for j in range(t.nf):
            if t.A[j] and not (t.tauc[j] and self.sup_set):
                self.Y[j] = Y[j]
            self.U0[j] = self.Uc[j]
        self.S = self._dsum(self.Slin)

    def supply_scale(self, j):
        """Filter ``j``'s state units per unit of its input as the controller measures it (rpm, rpm squared, mm/min):
        the state is that lag x 2**supply_scale(j) (the squared speed's input is rpm**2 / 2**shq)."""
        t = self.table
        return t.fy[j] - t.shq if t.src[j] == -2 else t.fy[j]

    def supply(self, vals):
        """The lag states the controller supplies (table.tauc), in filter order, in state units; the caller checked
        each against its box (App.supply_states)."""
        t = self.table
        k = 0
        for j in range(t.nf):
            if t.tauc[j]:
                self.Y[j] = vals[k]
                k += 1
        self.sup_set = True
        self.S = self._dsum(self.Slin)

    def extreme(self, sign):
        """Every filter state at the end of its box that drives S up (sign > 0), down (< 0), or 0 (the firmware's
        cheap certificate check at table acceptance)."""
        t = self.table
        for j in range(t.nf):
            up = (t.bY[j] >= 0) == (sign > 0)
            self.Y[j] = 0 if not sign else (t.Yhi[j] if up else t.Ylo[j])
        self.S = self._dsum(self.Slin)

    def _dstep(self):
        """One step of every lag filter: Y <- Y + a (U0 << fy - Y), the input held over the step (zero-order hold)."""
        t = self.table
        chk = self.check
        A = t.A
        shA = t.shA
        rA = t.rA
        gA = t.gA
        fy = t.fy
        Ylo = t.Ylo
        Yhi = t.Yhi
        Y = self.Y
        U0 = self.U0
        Uc = self.Uc
        LX = t.LX
        nX = t.nX
        for j in range(t.nf):
            if A[j]:
                x = (U0[j] << fy[j]) - Y[j]
                if chk:
                    self._note(_ACC_DX, x)
                # the increment is formed gA[j] guard bits finer and rounded once (rA[j] centres it)
                g = gA[j]
                v = self._mul(_ACC_DMUL, A[j], x, LX, nX, shA[j] - g) + rA[j]
                if chk:
                    self._note(_ACC_DMUL + 1, v)
                v = Y[j] + (v >> g)
                if chk:
                    self._note(_ACC_Y, v)
                if v < Ylo[j]:  # the exact state lies in the box (a convex combination of inputs and 0):
                    v = Ylo[j]  # clamping only removes error
                elif v > Yhi[j]:
                    v = Yhi[j]
                Y[j] = v
            U0[j] = Uc[j]
        self.S = self._dsum(self.Slin)

    # -- screw_reduced ----------------------------------------------------------
    def _seg(self, p):
        """Segment elongation alpha * sum T_i * overlap_i(p), at output scale 2**-fo."""
        t = self.table
        x = p - t.fixed_end
        if x <= 0:
            return 0
        e = t.edges
        m = t.M
        if x >= e[m]:
            return self.cum[m]
        k = 0
        while e[k + 1] <= x:
            k += 1
        xl = x - e[k]
        if self.check:
            self._note(_ACC_XL, xl)
        v = self.cum[k] + self._mul(_ACC_SEGMUL, xl, self.segslope[k], t.Lx, t.nx, t.shX)
        if self.check:
            self._note(_ACC_CUM, v)
        return v

    def advance_position(self, pos_um):
        """Accumulate nut travel per segment from a position report (screw tables)."""
        t = self.table
        p = self._clamp_pos(pos_um)
        x = p - t.fixed_end
        if not self.have_x:
            self.have_x = True
            self.x = x
            return
        a = self.x
        b = x
        self.x = x
        if a == b:
            return
        if a > b:
            a, b = b, a
            self.dir = -1
        else:
            self.dir = 1
        e = t.edges
        u = self.u
        umax = t.umax
        for i in range(t.M):
            lo = e[i] if e[i] > a else a
            hi = e[i + 1] if e[i + 1] < b else b
            if hi > lo:
                v = u[i] + (hi - lo)
                if self.check:
                    self._note(_ACC_TRAVEL, v)
                if v > umax:
                    v = umax
                    self.flags |= _CLAMP_TRAVEL
                u[i] = v

    def set_feed(self, feed_mm_min, lo_um, hi_um):
        """Fallback without position reports: ``feed`` spread over [lo, hi] every step."""
        t = self.table
        f = feed_mm_min if feed_mm_min >= 0 else -feed_mm_min
        if f > t.fmax:
            f = t.fmax
            self.flags |= _CLAMP_TRAVEL
        self.F = (f * t.dt_ms) // 60
        e = t.edges
        m = t.M
        a = self._clamp_pos(lo_um) - t.fixed_end
        b = self._clamp_pos(hi_um) - t.fixed_end
        if a > b:
            a, b = b, a
        if a < 0:
            a = 0
        if b > e[m]:
            b = e[m]
        w = self.w
        r = b - a
        for i in range(m):
            w[i] = 0
            lo = e[i] if e[i] > a else a
            hi = e[i + 1] if e[i + 1] < b else b
            if r <= 0:
                if e[i] <= a < e[i + 1] or (i == m - 1 and a == e[m]):
                    w[i] = 1 << _FEED_W_BITS
            elif hi > lo:
                # floor((hi - lo) * 2**19 / r) by long division: no product beyond 2**23
                q = 0
                rem = hi - lo
                if rem >= r:
                    q = 1
                    rem -= r
                for _ in range(_FEED_W_BITS):
                    rem <<= 1
                    q <<= 1
                    if rem >= r:
                        rem -= r
                        q += 1
                w[i] = q
        self.feed = True
        self.dir = 0  # the feed/range state has no direction

    def clear_feed(self):
        self.feed = False

    def step(self):
        """One time step (every ``table.dt_ms``): the dynamic table's filters, or the screw's segment recurrence
        T <- T + C*T + B*g(U)*u + Bu*U - D*U*(T - a0) + W0*a0 + W1*a1 (then u = 0), U = sum u (the step's total
        travel), g(U) = g0 + Gv*U (speed_dependent_heat; 1 without it), D (moving_convection; 0 without it)."""
        if self.kind == _KIND_DYNAMIC:
            return self._dstep()
        t = self.table
        chk = self.check
        m = t.M
        T = self.T
        Tn = self.Tn
        u = self.u
        umax = t.umax
        U0 = 0
        if self.feed:
            w = self.w
            F = self.F
            for i in range(m):
                U0 += u[i]
                v = u[i] + self._mul(_ACC_FEEDMUL, w[i], F, _FEED_LIMB, 3, _FEED_W_BITS)
                if chk:
                    self._note(_ACC_TRAVEL, v)
                if v > umax:
                    v = umax
                    self.flags |= _CLAMP_TRAVEL
                u[i] = v
        U = 0  # the step's total travel, for the effects' heat per mm of travel (Bu; bearing_heat) and speed terms
        for i in range(m):
            U += u[i]
            if chk:
                self._note(_ACC_TRAVEL, U)
            if U > umax:
                U = umax
                self.flags |= _CLAMP_TRAVEL
        if self.feed:
            # the spread's fractions sum to 1: the total is the feed's travel itself (plus what position reports left in
            # u this step), without the shares' floors
            U = U0 + self.F
            if U > umax:
                U = umax
        fg = t.fg
        g = 0
        if fg:  # speed_dependent_heat (format 5): the friction heat of the step times g(U) = g0 + Gv*U (2**-fg)
            g = t.g0 + self._mul(_ACC_GMUL, t.Gv, U, t.Lu, t.nu, t.shGv)
            if chk:
                self._note(_ACC_GMUL + 1, g)
        a0 = 0  # moving_convection (format 5): the air at the step's start in state units (as settle() sets it)
        if t.fe and t.air >= 0:
            a0 = self._mul(_ACC_AMUL, t.Ka, self.da0, t.Lt, t.nt, t.shKa)
            if a0 < t.Tlo:
                a0 = t.Tlo
            elif a0 > t.Tmax:
                a0 = t.Tmax
        D = t.D
        shD = t.shD
        ns = t.ns
        Ls = t.Ls
        mask = (1 << Ls) - 1
        limbs = self.limbs
        for j in range(m):
            x = T[j]
            for k in range(ns - 1):
                limbs[k * m + j] = x & mask
                x >>= Ls
            limbs[(ns - 1) * m + j] = x
            if chk:
                self._note(_ACC_LIMB, x)
        C = t.C
        B = t.B
        shB = t.shB
        Bu = t.Bu
        shBu = t.shBu
        rS = t.rS
        gs = t.gs
        Tmax = t.Tmax
        fl = 0
        for i in range(m):
            # the row is summed at gs guard bits below the state unit and rounded once
            acc = 0
            sh = t.fc - gs
            base = i * m
            for k in range(ns):
                r = 0
                lb = k * m
                for j in range(m):
                    r += C[base + j] * limbs[lb + j]
                    if chk:
                        self._note(_ACC_ROWMUL, C[base + j] * limbs[lb + j])
                        self._note(_ACC_ROWMUL, r)
                if sh > 0:
                    acc += r >> sh
                else:
                    acc += r << -sh
                if chk:
                    self._note(_ACC_ROW, acc)
                sh -= Ls
            ui = u[i]
            if fg:
                ui = self._mul(_ACC_UGMUL, g, ui, t.Lgu, t.ngu, fg)
            acc += self._mul(_ACC_BMUL, B[i], ui, t.Lu, t.nu, shB[i]) + rS[i]
            if D[i]:
                # the extra loss D_i*U*(T_i - a) of the step, explicit: the weight (2**-fe) then its product
                e = self._mul(_ACC_EMUL, D[i], U, t.Lu, t.nu, shD[i])
                y = T[i] - a0
                if chk:
                    self._note(_ACC_CONVY, y)
                acc -= self._mul(_ACC_LMUL, e, y, t.Ly, t.ny, t.fe - gs)
            if Bu[i]:
                acc += self._mul(_ACC_BMUL, Bu[i], U, t.Lu, t.nu, shBu[i])
            if chk:
                self._note(_ACC_ROW, acc)
            if t.air >= 0:
                acc += self._mul(_ACC_AMUL, t.W0[i], self.da0, t.Lt, t.nt, t.shW0[i])
                acc += self._mul(_ACC_AMUL, t.W1[i], self.da, t.Lt, t.nt, t.shW1[i])
                if chk:
                    self._note(_ACC_ROW, acc)
            v = T[i] + (acc >> gs)
            if chk:
                self._note(_ACC_STATE, v)
            if v < t.Tlo:
                v = t.Tlo  # the exact state is >= the air's lowest value, so this only removes error
            elif v > Tmax:
                v = Tmax
                fl = _CLAMP_STATE
            Tn[i] = v
        for i in range(m):
            T[i] = Tn[i]
            u[i] = 0
        self.da0 = self.da
        self.flags = (self.flags & ~_CLAMP_STATE) | fl
        self._refresh()

    def settle(self):
        """State = the air's temperature over its reference (equilibrium); no heat stored."""
        t = self.table
        v = 0
        if t.air >= 0:
            v = self._mul(_ACC_AMUL, t.Ka, self.da, t.Lt, t.nt, t.shKa)
            if v < t.Tlo:
                v = t.Tlo
            elif v > t.Tmax:
                v = t.Tmax
        if self.check:
            self._note(_ACC_STATE, v)
        for i in range(t.M):
            self.T[i] = v
        self.da0 = self.da
        self._refresh()

    def estimate(self):
        """The screw's segment states from its sensors (the observer, table.obs; issue 21, docs/firmware.md): the air's
        state as settle() sets it plus, per segment, Gn[i] x r + rN[i], r the nut sensor sn's rise over sensor sr
        (milli-K, clamped to +-Rn), then clamped to the state bounds. A table without an observer gets settle(): the
        cold start. Runs once per start, allocation-free."""
        self.settle()
        t = self.table
        if not t.obs:
            return
        chk = self.check
        r = self._rise(t.sn) - self._rise(t.sr)
        if r > t.Rn:
            r = t.Rn
        elif r < -t.Rn:
            r = -t.Rn
        T = self.T
        a = T[0]
        Gn = t.Gn
        shGn = t.shGn
        rN = t.rN
        for i in range(t.M):
            v = a + self._mul(_ACC_NMUL, Gn[i], r, t.Lr, t.nr, shGn[i]) + rN[i]
            if chk:
                self._note(_ACC_NSUM, v)
            if v < t.Tlo:
                v = t.Tlo
            elif v > t.Tmax:
                v = t.Tmax
            T[i] = v
        self._refresh()

    def _rise(self, i):
        """Sensor i's reading clamped to its envelope, over its reference (milli-K), as update() reads it."""
        t = self.table
        v = self.temps[i]
        if v < t.env_lo[i]:
            v = t.env_lo[i]
        elif v > t.env_hi[i]:
            v = t.env_hi[i]
        return v - self.ref[i]

    def settle_restored(self):
        """The state ``T`` was written from a stored one (a warm restart): refresh what depends on it."""
        self.da0 = self.da
        self._refresh()

    def _refresh(self):
        """Per-step precomputation of the piecewise-linear elongation profile."""
        t = self.table
        chk = self.check
        T = self.T
        cum = self.cum
        seg = self.segslope
        G2 = t.G2
        shG2 = t.shG2
        Ls = t.Ls
        ns = t.ns
        c = 0
        for i in range(t.M):
            cum[i] = c
            c += self._mul(_ACC_CUMMUL, G2[i], T[i], Ls, ns, shG2[i])
            if chk:
                self._note(_ACC_CUM, c)
            seg[i] = self._mul(_ACC_HMUL, t.H, T[i], Ls, ns, t.shH)
        cum[t.M] = c


if sys.implementation.name != "micropython":  # CPython: the constants under their public names (see the module docstring)
    _g = globals()
    for _k in [k for k in _g if k[:1] == "_" and k[1:2].isupper() and k == k.upper()]:
        _g[_k[1:]] = _g[_k]
