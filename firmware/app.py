"""The compensator: read sensors, evaluate the table, limit, report. ``main(board)`` runs it.

One cycle (``App.cycle``) reads every channel, converts and checks it
(firmware.channels), writes the good temperatures into the evaluator
(firmware.evaluate, a sensor that went bad keeps its last good value: the
output is held), advances the screw state on the table's fixed time step,
evaluates the three outputs at the last reported position, passes them
through the limiter (firmware.safety), services the serial link (stream or
Modbus) and feeds the watchdog last. Once started, a cycle allocates nothing
(tests/firmware/test_fw_heaplock.py runs it under ``micropython.heap_lock()``).

Units inside: temperatures milli-degC, positions um, offsets 0.01 um,
slopes 0.01 um/m (the evaluator's); the links convert for the wire.
"""

from micropython import const

from firmware.auth import Auth
from firmware.channels import Channels
from firmware.evaluate import Evaluator
from firmware.safety import Limiter
from firmware.slots import TableStore
from firmware.table import TableError, REASON_SENSORS, REASON_CERT

# status word bits (firmware/wire.py; tests/firmware/test_fw_consts.py checks the copies)
_CLAMPED = const(0x10000)
_EXTRAPOLATING = const(0x10000000)
_DISABLED = const(0x1000000)
_FALLBACK = const(0x100000)
_HELD = const(0x80000)
_LINK_TIMEOUT = const(0x400000)
_NO_POSITION = const(0x800000)
_NO_TABLE = const(0x200000)
_UPLOADING = const(0x2000000)
_REF_PENDING = const(0x8000000)
_SETTLING = const(0x20000000)

_MAX_CATCHUP = const(50)  # screw steps per cycle after a stall; beyond, time is dropped
_POLL_MS = const(5)  # serial polling period while waiting for the next cycle
_CAP = const(0x20000000)  # elapsed-time counters saturate at 2**29 ms
_KIND_SCREW_REDUCED = const(3)  # firmware.table's (tests/firmware/test_fw_consts.py checks)
_KIND_DYNAMIC = const(4)
# ref_state: where the reference temperatures come from (docs/firmware.md); the hello
# frame sends firmware.wire.REF_LETTERS[ref_state]. From 4 on the latch is pending: 4..6 are
# firmware.slots' REFS_MISSING/CORRUPT/FOREIGN (why the stored ones were not used).
_REFS_STORED = const(1)
_REFS_LATCHED = const(2)
_REFS_UNSAVED = const(3)
# Flash wear (docs/protocol.md, "Flash wear"): every file replacement a command causes (latch,
# table upload, counter mark) spends a token; _WEAR_CAP tokens, one more every _WEAR_REFILL_MS.
_WEAR_CAP = const(4)
_WEAR_REFILL_MS = const(60000)
BUSY = b"busy"  # relatch()'s answer when the flash budget is used up
_UPLOAD_IDLE_MS = const(60000)  # an upload without a chunk for this long is abandoned
# Position plausibility (docs/protocol.md, "Position and feed"): a report may be at most as far from the last
# accepted one as the axis can travel at max_speed_mm_min in the time between them plus this allowance (reports
# queued in the controller's or the UART's buffers arrive closer together than they were sent)
_POS_JITTER_MS = const(200)
_NEED_CAP = const(8000000)  # d // v beyond this: the time needed exceeds _CAP (the sums below stay small ints)
# the lag states the controller supplies (wire.SUPPLY_*; tests/firmware/test_fw_consts.py checks the copies)
_SUPPLY_NONE = const(0)
_SUPPLY_AWAITED = const(1)
_SUPPLY_SET = const(2)
_MAX_SUPPLIED = const(4)
# how long a table's start waits for them before it starts without them (at the observer's estimate, or without gains
# at the steady state of the present input; SETTLING stays raised until they come): the bridge sends them in its first
# exchange after it hears the board, so 10 s covers a bridge started with the board; one started later corrects the
# states when it comes (docs/firmware.md "Supplied lag states")
_SUPPLY_WAIT_MS = const(10000)
# A dynamic table's stored lag states (lags.bin) are trusted at a restart only if the machine is where it was at the
# write (docs/firmware.md, "Warm restarts of the lag states", where the two limits were measured on FL_THERMAL): every
# sensor the table reads within _LAG_DRIFT_MK of its reading then, and (with an observer) the observer's estimate from
# the temperatures now within _LAG_AGREE (0.01 um of output) of its estimate from those then.
_LAG_DRIFT_MK = const(1000)
_LAG_AGREE = const(1000)
# lag_verdict: what became of lags.bin at this table's start (App._restore_lags; docs/firmware.md)
LAGS_NONE = 0  # no record (none, damaged, another table's or references', or not a dynamic table)
LAGS_RESTORED = 1
LAGS_MOVED = 2  # a sensor moved more than _LAG_DRIFT_MK since the write
LAGS_DISAGREE = 3  # the observer's estimate moved more than _LAG_AGREE since the write


def _load_config(d):
    # the board's terse check (firmware/bootcfg.py; the friendly one runs on the host)
    # is needed once per boot: unload it again to give the RAM back
    # (every reference is dropped explicitly: the GC scans the stack conservatively)
    import sys
    import firmware
    from firmware import bootcfg
    try:
        cfg = bootcfg.load_config(d)
    finally:
        bootcfg = None
        sys.modules.pop("firmware.bootcfg", None)
        if hasattr(firmware, "bootcfg"):
            delattr(firmware, "bootcfg")
    return cfg


def _nothing():
    pass


class Restart(Exception):
    """Raised by a reset command when the board has no hardware reset."""


class App:
    def __init__(self, board):
        import gc
        # CPython's heap needs no help, and a full collection there is slow
        collect = gc.collect if hasattr(gc, "mem_free") else _nothing
        self.board = board
        cfg = self.cfg = _load_config(board.config)
        # Code first, and a collection between boot steps: the heap never moves
        # objects, so long-lived ones placed between boot garbage fragment it
        # until a later import finds no contiguous block.
        if cfg.serial_mode == "modbus":
            from firmware.modbus import ModbusLink as Link
        else:
            from firmware.protocol import StreamLink as Link
        for ch in cfg.channels:
            __import__("firmware." + ch.driver)
        collect()
        clock = self.clock = board.clock
        now = clock.ticks_ms()
        self.channels = Channels(cfg, board, now)
        self.channels.set_thresholds()
        self.enabled = True
        self.slew = cfg.slew_um_per_s
        self.link_timeout_ms = cfg.link_timeout_ms
        self.pos = 0  # last reported position
        self.pos_used = 0  # position the last cycle's total was evaluated at
        self.have_pos = False
        self.pos_t = now  # tick of the last accepted position report
        self.spindle = 0  # last reported spindle speed (rpm) and feed (mm/min): the dynamic table's inputs
        self.feed = 0
        self.dyn = False  # the table in use is a dynamic one
        self.obs_link = False  # its observer reads the spindle speed or feed: it waits for the controller (use_table)
        self.heard_spin = False  # the controller has reported the spindle speed since boot
        self.unobserved = False  # a dynamic table's lag states wait for the first all-good cycle (observer, or rest)
        # the lag states the controller supplies (table.tauc; docs/firmware.md "Supplied lag states"): the table's
        # start waits for them (AWAITED) as for the first speed report; set once per table start
        self.supply = _SUPPLY_NONE
        self.sup_k = 0
        self.sup_vals = [0] * _MAX_SUPPLIED  # the values as received (a `Y` or the Modbus registers), no allocation
        self.sup_wait_ms = 0  # how long the table's start has waited for them
        self.settle_s = 0  # seconds since the observer's estimate (saturating at settle_cap) and the ms
        self.settle_ms = 0  # toward the next second
        # the table's settle_s, or its settle_nr when larger: SETTLING of a start without the supplied states lasts
        # settle_nr (table format 8; docs/firmware.md "Supplied lag states")
        self.settle_cap = 0
        # elapsed-time counters (ms, saturating) rather than timestamps: ticks wrap
        self.rx_ms = 0  # since the last valid controller traffic
        self.fault_active = False
        self.fault_ms = 0  # since a sensor the model needs went bad
        self.last_t = now
        self.step_ms = 0  # time not yet consumed by screw-model steps
        self.cycles = 0
        self.status = 0
        self.total = 0  # limited outputs, 0.01 um / 0.01 um/m
        self.ref_out = 0
        self.slope_out = 0
        self.usable = False
        self.dev = 0  # limited total minus the model at the current position
        self.ev = None
        self.table = None
        self.slot = None
        self.map = []
        self.unlatched = False
        self.unsettled = False  # screw state not yet set in equilibrium with a good air reading
        self.ref_state = 0
        self.heat = None  # firmware.warmstate.HeatStore of a screw table with latched references
        self.warm = False  # the screw state was restored from heat.bin (not settled at the first good cycle)
        # a screw table's observer (table.obs) starts the segments at the first all-good cycle, and SETTLING counts
        # settle_s from there; cleared by a restored state, a latch (a cold start) or a faulty nut sensor then
        self.sobs = False
        self.nut = -1  # a screw observer table's index of its nut sensor: read by the start only, never needed by the model
        self.lags = None  # firmware.warmstate.LagStore of a dynamic table
        self.lag_rec = None  # its stored record, until the first all-good cycle decides whether to trust it
        self.lag_verdict = LAGS_NONE
        self.limiter = Limiter(cfg.slew_um_per_s, cfg.max_offset_um, 1000)
        self.store = TableStore(cfg.table_dir, self._accept)
        self.wear = _WEAR_CAP  # flash-write tokens (spend_flash)
        self.wear_ms = 0
        self.auth = Auth(self.store, self.spend_flash, getattr(board, "entropy", None))
        t, slot = self.store.load()
        collect()
        if t is not None:
            self.use_table(t, slot)
        self.link = Link(self)
        collect()
        # what the hello frame reports before the first cycle: nothing read yet
        self.status = (self.channels.faulty_mask() | _NO_POSITION | _FALLBACK
                       | (0 if t is not None else _NO_TABLE)
                       | (_REF_PENDING if self.unlatched else 0))
        self.link.boot()

    # --- table ---------------------------------------------------------------
    def _accept(self, table):
        names = self.channels.names
        for s in table.sensors:
            if s not in names:
                raise TableError(REASON_SENSORS, "table sensor %s has no channel on this board" % s)
        # The certificate must hold where it is cheap to check: the temperature part at its
        # largest, its smallest (each sensor at the envelope end its coefficient favours) and at
        # the references, at both ends of the position envelope and at the reference position.
        # A table whose coefficients were changed without its certificate fails here.
        ev = Evaluator(table)
        for sign in (1, -1, 0):
            for j in range(table.n_sensors):
                up = (table.b[j] >= 0) == (sign > 0)
                ev.temps[j] = table.ref[j] if not sign else (table.env_hi[j] if up else table.env_lo[j])
            ev.update()
            if table.kind_code == _KIND_DYNAMIC:
                ev.extreme(sign)  # the filter states at the ends of their boxes
            for p in (table.pos_lo, table.pos_hi, table.pos_ref):
                ev.set_reference(p)
                for v, bound in ((ev.offset_at(p), table.cert_out), (ev.ref_offset(), table.cert_ref),
                                 (ev.slope(), table.cert_slope)):
                    if v > bound or v < -bound:
                        raise TableError(REASON_CERT, "output %d at %d um beyond the certified %d" % (v, p, bound))

    def use_table(self, table, slot):
        """Switch to ``table`` (already verified); the limiter ramps from the current output."""
        ev = Evaluator(table)
        names = self.channels.names
        self.map = [names.index(s) for s in table.sensors]
        for j in range(len(self.map)):
            i = self.map[j]
            if self.channels.have_good[i]:
                ev.temps[j] = self.channels.temp[i]
        ref = self.cfg.reference_um
        if ref is not None:
            ev.set_reference(ref)
        self.dyn = table.kind_code == _KIND_DYNAMIC
        if self.dyn:
            ev.set_spindle(self.spindle)
            ev.set_feed_rate(self.feed)
        ev.update()
        if self.dyn:
            ev.rest()
        # a dynamic table's lag states are set at the first cycle every sensor it needs reads good: estimated from the
        # inputs (its observer), or at rest without one; then the filters step at dt_ms from that cycle
        self.unobserved = self.dyn
        # an observer that reads the spindle speed waits for the controller's first report of it (P,<pos>,<rpm>, or
        # Modbus holding registers 18-19), one that reads the feed for its first position report: estimated before,
        # those states would start from 0 rpm whatever the spindle does (docs/firmware.md, "Observer")
        self.obs_link = 0  # 0: the sensors suffice; 1: wait for a position report; 2: for the spindle speed
        if self.dyn and table.obs:
            for k in table.src:
                if k == -3 and not self.obs_link:
                    self.obs_link = 1
                elif -2 <= k <= -1:
                    self.obs_link = 2
        self.sup_k = 0
        if self.dyn:
            for c in table.tauc:
                if c:
                    self.sup_k += 1
        self.supply = _SUPPLY_AWAITED if self.sup_k else _SUPPLY_NONE
        self.sup_wait_ms = 0
        self.settle_s = 0
        self.settle_ms = 0
        self.settle_cap = max(table.settle_s, table.settle_nr) if self.dyn else getattr(table, "settle_s", 0)
        self.table = table
        self.slot = slot
        self.ev = ev
        self.screw = table.kind_code == _KIND_SCREW_REDUCED
        # A model fitted on rises from the run start takes its reference temperatures at the
        # first cycle in which every sensor it needs reads good (a cold start), unless they
        # were stored for this very table before a restart (docs/firmware.md).
        st = 0
        if table.ref_mode == 1:
            st = self.store.load_refs(table)
            if not isinstance(st, int):
                for i in range(len(st)):
                    ev.ref[i] = st[i]
                ev.update()
                st = _REFS_STORED
        self.ref_state = st
        self.unlatched = st > _REFS_UNSAVED
        # the screw state starts in equilibrium with the air at the first cycle every needed sensor reads good,
        # unless this is a warm restart: the stored references are in use and heat.bin holds a state for them
        self.unsettled = self.screw
        self.warm = False
        self.step_ms = 0
        self._open_heat(table, ev, st == _REFS_STORED)
        self.sobs = self.screw and table.obs and not self.warm and not self.unlatched  # unlatched: the latch, a cold start
        self.nut = table.sn if self.screw and table.obs else -1
        self._open_lags(table, ev, st == _REFS_STORED or table.ref_mode != 1)
        self._span()

    def _settle(self, ev, nut_bad):
        # the first cycle in which every sensor the table needs reads good
        self.unsettled = False
        if self.warm:
            ev.da0 = ev.da  # the restored state keeps its heat; the air steps on from now
        elif self.sobs and not nut_bad:
            ev.estimate()  # the observer (allocation-free, tests/firmware/test_fw_heaplock.py)
            self.settle_s = 0
            self.settle_ms = 0
        else:  # no observer, or its nut sensor reads no good value: the cold start, no SETTLING (docs/firmware.md)
            self.sobs = False
            ev.settle()

    def _open_heat(self, table, ev, restore):
        if self.heat is not None:
            self.heat.close()
            self.heat = None
        if not self.screw or table.ref_mode != 1:
            return
        from firmware.warmstate import HeatStore, ref_tag
        h = HeatStore(self.store.dir, table, ref_tag(ev.ref))
        T = h.load()  # read even when not restored: the writes' sequence numbers go on above the file's
        if not restore:
            T = None
        if T is not None:
            ev.T[:] = T
            ev.settle_restored()
            self.warm = True
        if h.open():
            self.heat = h

    def _open_lags(self, table, ev, restore):
        # a dynamic table's lag states: the stored record is read now and judged at the first all-good cycle
        if self.lags is not None:
            self.lags.close()
            self.lags = None
        self.lag_rec = None
        self.lag_verdict = LAGS_NONE
        if not self.dyn:
            return
        from firmware.warmstate import LagStore, ref_tag
        h = LagStore(self.store.dir, table, ref_tag(ev.ref))
        w = h.load()  # read even when not restored: the writes' sequence numbers go on above the file's
        if restore:
            self.lag_rec = w
        if h.open():
            self.lags = h

    def _restore_lags(self, ev, t):
        # once, at the first cycle every sensor reads good (allocates: not the steady state). The record is used only
        # if the machine is where it was at the write (docs/firmware.md, "Warm restarts of the lag states").
        w = self.lag_rec
        self.lag_rec = None
        if w is None:
            return
        nf = t.nf
        n = t.n_sensors
        temps = ev.temps
        for i in range(n):
            d = temps[i] - w[nf + i]
            if d > _LAG_DRIFT_MK or d < -_LAG_DRIFT_MK:
                self.lag_verdict = LAGS_MOVED
                return
        if t.obs:
            # the observer's estimate from the readings at the write and from the temperatures now (the spindle speed
            # and feed of the write in both: the speed now says nothing about the heat the spindle left), each
            # applied to the model at the present inputs: how far the observer sees the machine moved, in output
            now = list(temps)
            before = list(ev.Y)
            spin = ev.spin
            fin = ev.fin
            ev.set_spindle(w[nf + n])
            ev.set_feed_rate(w[nf + n + 1])
            est = []
            for k in range(2):
                for i in range(n):
                    temps[i] = w[nf + i] if k == 0 else now[i]
                ev.update()
                ev.observe()
                est.append(list(ev.Y))
            ev.set_spindle(spin)
            ev.set_feed_rate(fin)
            ev.update()
            fl = ev.flags
            for p in (t.pos_lo, t.pos_hi):
                ev.set_lags(est[0])
                a = ev.offset_at(p)
                ev.set_lags(est[1])
                d = ev.offset_at(p) - a
                if d > _LAG_AGREE or d < -_LAG_AGREE:
                    self.lag_verdict = LAGS_DISAGREE
                    ev.flags = fl
                    ev.set_lags(before)  # as before the decision: the observer sets the states below
                    return
            ev.flags = fl
        ev.set_lags(w)
        self.lag_verdict = LAGS_RESTORED
        self.unobserved = False
        self.step_ms = 0
        self.settle_s = w[nf + n + 2]  # SETTLING goes on where it was (docs/firmware.md)
        self.settle_ms = 0

    def _span(self):
        t = self.table
        ev = self.ev
        if t is None or ev is None:
            return
        r = ev.pos_ref
        span = t.pos_hi - r if t.pos_hi - r > r - t.pos_lo else r - t.pos_lo
        self.limiter.configure(self.slew, self.cfg.max_offset_um, span, t)

    def _latch(self, ev, t):
        # once per latch, never in the steady state: the flash write allocates
        ev.latch_references()
        if self.dyn:
            self.step_ms = 0  # the filters step at dt_ms from the cold start, as the host's from the run's first sample
        self.unlatched = False
        self.sobs = False  # a latch is a cold start by definition: the screw in equilibrium with the air, no estimate
        self.ref_state = _REFS_LATCHED if self.store.save_refs(t, ev.ref) else _REFS_UNSAVED
        h = self.lags
        if h is not None:  # a latch is a cold start: the filters at rest, stored under the new references
            from firmware.warmstate import ref_tag
            self.lag_rec = None
            h.retag(ref_tag(ev.ref))
            h.save(ev, self.settle_s)
        h = self.heat
        if h is not None:  # a latch is a cold start: the settled state, stored under the new references
            from firmware.warmstate import ref_tag
            self.warm = False
            self.unsettled = False
            h.retag(ref_tag(ev.ref))
            h.save(ev.T)

    def relatch(self, check_only=False):
        """Latch the reference temperatures now (the controller's cold start) and store them.

        Returns None, or why not (bytes; nothing changed): no table, a table with fixed
        references, or a sensor the table needs not reading good this cycle."""
        t = self.table
        ev = self.ev
        if ev is None or t is None:
            return b"no table"
        if t.ref_mode != 1:
            return b"fixed references"
        for i in self.map:
            if not self.channels.good[i]:
                return b"sensor faulty"
        if self.wear <= 0:
            return BUSY
        if not check_only:
            self.wear -= 1
            self._latch(ev, t)
        return None

    def spend_flash(self):
        """Take one flash-write token; False (nothing written) when the budget is used up."""
        if self.wear <= 0:
            return False
        self.wear -= 1
        return True

    def set_reference(self, pos_um):
        if self.ev is None:
            return None
        self.ev.set_reference(pos_um)
        self._span()
        return self.ev.pos_ref

    def set_slew(self, um_per_s):
        self.slew = um_per_s
        if self.ev is not None:
            self._span()
        else:
            self.limiter.configure(um_per_s, self.cfg.max_offset_um, 1000)

    # --- inputs from the controller -------------------------------------------
    def position_plausible(self, pos_um, now):
        """Whether the axis can have moved from the last accepted report to ``pos_um`` since it came,
        at the config's max_speed_mm_min (0: no check); the first report is always plausible."""
        v = self.cfg.max_speed_mm_min
        if not v or not self.have_pos:
            return True
        d = pos_um - self.pos
        if d < 0:
            d = -d
        q = d // v
        # ms the move needs at v mm/min (v mm/min = v/60 um/ms), rounded up, without forming values beyond 2**30
        need = _CAP if q >= _NEED_CAP else q * 60 + ((d - q * v) * 60 + v - 1) // v
        e = self.clock.ticks_diff(now, self.pos_t)
        if e < 0 or e > _CAP:
            e = _CAP
        return need <= e + _POS_JITTER_MS

    def feed_plausible(self, feed_mm_min):
        v = self.cfg.max_speed_mm_min
        return not v or feed_mm_min <= v

    def report_position(self, pos_um, now):
        """A position report; False (nothing changed) when it is not plausible (position_plausible)."""
        if not self.position_plausible(pos_um, now):
            return False
        self.pos = pos_um
        self.pos_t = now
        self.have_pos = True
        if self.ev is not None and self.screw:
            if self.ev.feed:
                self.ev.clear_feed()
            self.ev.advance_position(pos_um)
        return True

    def report_spindle(self, rpm):
        """Spindle speed from the controller (rpm, either sign): an input of dynamic tables, like the position."""
        self.spindle = rpm
        self.heard_spin = True
        if self.ev is not None and self.dyn:
            self.ev.set_spindle(rpm)

    def supply_states(self, vals, k):
        """The lag states the controller supplies (docs/protocol.md "Supplied lag states"): ``vals[0:k]`` in the table's
        filter order and state units. Returns 1: set now (the table's start was waiting for them, or started without
        them after _SUPPLY_WAIT_MS: these replace that start's estimate); 0: they were set at this table's start, so
        nothing is applied (the board's filters carry them on); or a refusal, nothing changed:
        -1 the table supplies no state (or no table), -2 not the table's count, -3 - i: value i outside its state's
        box (the certified range)."""
        t = self.table
        if self.ev is None or t is None or not self.sup_k:
            return -1
        if k != self.sup_k:
            return -2
        i = 0
        for j in range(t.nf):
            if t.tauc[j]:
                if not t.Ylo[j] <= vals[i] <= t.Yhi[j]:
                    return -3 - i
                i += 1
        if self.supply == _SUPPLY_SET:
            return 0
        self.ev.supply(vals)
        self.supply = _SUPPLY_SET
        return 1

    def set_feed(self, feed_mm_min, lo_um, hi_um):
        self.feed = feed_mm_min
        if self.ev is not None and self.dyn:
            self.ev.set_feed_rate(feed_mm_min)
            return True
        if self.ev is None or not self.screw:
            return False
        if feed_mm_min == 0:
            self.ev.clear_feed()
        else:
            self.ev.set_feed(feed_mm_min, lo_um, hi_um)
        return True

    def link_alive(self, now):
        """Valid traffic from the controller (a valid P or Q; on Modbus a request to this slave it
        answers normally): only this feeds the link watchdog (LINK_TIMEOUT)."""
        self.rx_ms = 0

    # --- outputs ---------------------------------------------------------------
    def total_at(self, pos):
        """The output the last cycle would have given at ``pos`` (queries; state untouched).

        The model at ``pos`` plus the limiter's present deviation from the model,
        which is what the output becomes if the axis moves there now.
        """
        ev = self.ev
        lim = self.limiter
        if ev is None or not self.usable:
            return lim.total
        fl = ev.flags
        v = ev.offset_at(pos) + self.dev
        ev.flags = fl
        m = lim.max
        return m if v > m else (-m if v < -m else v)

    # --- the cycle ---------------------------------------------------------------
    def cycle(self):
        clock = self.clock
        now = clock.ticks_ms()
        dt = clock.ticks_diff(now, self.last_t)
        self.last_t = now
        if dt < 0:
            dt = 0
        elif dt > _CAP:
            dt = _CAP
        v = self.rx_ms + dt
        self.rx_ms = v if v < _CAP else _CAP
        self.auth.tick(dt)
        if self.wear < _WEAR_CAP:
            v = self.wear_ms + dt
            if v >= _WEAR_REFILL_MS:
                v -= _WEAR_REFILL_MS
                self.wear += 1
            self.wear_ms = v
        st = self.store
        if st.uploading:
            st.idle_ms += dt
            if st.idle_ms >= _UPLOAD_IDLE_MS:
                st.abort()
        self.link.poll(now)
        ch = self.channels
        s = ch.read_all(now, clock)
        usable = self.enabled
        ev = self.ev
        t = self.table
        raw_total = 0
        raw_prev = 0
        raw_ref = 0
        raw_slope = 0
        if ev is None or t is None:
            s |= _NO_TABLE
            usable = False
        else:
            needed = 0
            never = False
            nut_bad = False
            temps = ev.temps
            m = self.map
            for j in range(len(m)):
                i = m[j]
                if ch.good[i]:
                    temps[j] = ch.temp[i]
                elif j == self.nut and not self.unlatched:  # read by the start only (a cold start without it); a latch needs it
                    nut_bad = True
                else:
                    needed = 1
                    if not ch.have_good[i]:
                        never = True
            if needed:
                if not self.fault_active:
                    self.fault_active = True
                    self.fault_ms = 0
                else:
                    v = self.fault_ms + dt
                    self.fault_ms = v if v < _CAP else _CAP
                if never or self.fault_ms >= self.cfg.hold_ms:
                    usable = False
                else:
                    s |= _HELD
            else:
                self.fault_active = False
                if self.unlatched:
                    self._latch(ev, t)
            ev.update()
            if self.unsettled and not needed:
                self._settle(ev, nut_bad)
            # the table's start waits for the controller's supplied states, at most _SUPPLY_WAIT_MS
            waiting = self.supply == _SUPPLY_AWAITED and self.sup_wait_ms < _SUPPLY_WAIT_MS
            if waiting:
                self.sup_wait_ms += dt
            if self.lag_rec is not None and not needed and not waiting:
                # once per table start: a stored state, if it is trusted (the supplied ones too while the controller's
                # values have not come: they replace them when they do)
                self._restore_lags(ev, t)
            link = self.obs_link
            if self.unobserved and not needed and not waiting and (
                    link == 0 or (link == 1 and self.have_pos) or (link == 2 and self.heard_spin)):
                ev.observe()  # allocation-free (tests/firmware/test_fw_heaplock.py); without the controller's values
                self.unobserved = False  # the supplied states start at their estimate (they replace it when they come)
                self.step_ms = 0
                self.settle_s = 0
                self.settle_ms = 0
            elif (self.dyn or (self.sobs and not self.unsettled)) and self.settle_s < self.settle_cap:
                v = self.settle_ms + dt  # dt <= _CAP: small ints throughout
                k = v // 1000
                self.settle_ms = v - k * 1000
                cap = self.settle_cap
                self.settle_s = cap if k >= cap - self.settle_s else self.settle_s + k
            if self.screw or self.dyn:
                dtm = t.dt_ms
                self.step_ms += dt
                k = 0
                while self.step_ms >= dtm:
                    ev.step()
                    self.step_ms -= dtm
                    k += 1
                    if k >= _MAX_CATCHUP:  # after a stall: drop the time rather than burst
                        self.step_ms = 0
                        break
                if self.heat is not None and not self.unsettled:
                    self.heat.tick(dt, ev.T)  # allocation-free (firmware/warmstate.py)
                if self.lags is not None and not self.unobserved:
                    self.lags.tick(dt, ev, self.settle_s)  # allocation-free (firmware/warmstate.py)
            pos = self.pos if self.have_pos else ev.pos_ref
            # the model at last cycle's position too: the limiter tells motion from drift
            raw_prev = ev.offset_at(self.pos_used)
            self.pos_used = pos
            raw_total = ev.offset_at(pos)
            raw_ref = ev.ref_offset()
            raw_slope = ev.slope()
            if ev.flags:
                s |= _CLAMPED
            if ev.extrap:
                s |= _EXTRAPOLATING
            # without the controller's values (still awaited after the start) the supplied states are at their rows'
            # estimate, whose start error settles by settle_nr (a format 7 table: never, until the values come)
            if (self.dyn and t.obs and (self.unobserved or self.settle_s < t.settle_s or (
                    self.supply == _SUPPLY_AWAITED and self.settle_s < t.settle_nr))) or (self.sobs and self.settle_s < t.settle_s):
                s |= _SETTLING
        lim = self.limiter
        s |= lim.update(raw_ref, raw_slope, raw_total, raw_prev, usable, dt)
        self.usable = usable
        self.dev = lim.total - raw_total
        self.total = lim.total
        self.ref_out = lim.ref
        self.slope_out = lim.slope
        if not usable:
            s |= _FALLBACK
        if not self.enabled:
            s |= _DISABLED
        if not self.have_pos:
            s |= _NO_POSITION
        if self.link_timeout_ms and self.rx_ms >= self.link_timeout_ms:
            s |= _LINK_TIMEOUT
        if self.store.uploading:
            s |= _UPLOADING
        if self.unlatched:
            s |= _REF_PENDING
        self.status = s
        self.cycles += 1
        self.link.after_cycle(now)
        wdt = self.board.watchdog
        if wdt is not None:
            wdt.feed()

    def wait(self, start):
        """Service the link until ``cycle_ms`` after ``start``."""
        clock = self.clock
        period = self.cfg.cycle_ms
        while True:
            now = clock.ticks_ms()
            left = period - clock.ticks_diff(now, start)
            if left <= 0:
                return
            self.link.poll(now)
            clock.sleep_ms(_POLL_MS if left > _POLL_MS else left)

    def run(self, max_cycles=None):
        clock = self.clock
        while max_cycles is None or self.cycles < max_cycles:
            start = clock.ticks_ms()
            self.cycle()
            self.wait(start)

    def reset(self):
        h = self.heat
        ev = self.ev
        if h is not None and ev is not None and not self.unsettled and self.spend_flash():
            h.save(ev.T)  # the restart resumes from the state of this very moment
        h = self.lags
        if h is not None and ev is not None and not self.unobserved and self.spend_flash():
            h.save(ev, self.settle_s)
        self.store.abort()
        r = self.board.reset
        if r is not None:
            r()
        raise Restart()


def main(board, max_cycles=None):
    """Run the compensator on ``board`` (firmware.board) until reset or ``max_cycles``."""
    while True:
        try:
            App(board).run(max_cycles)
            return
        except Restart:
            continue
