"""Stream mode of the serial link: $TC frames and commands (docs/protocol.md, version 1).

Frames the device sends (``$TC,<seq>,<status>,<type>,...*CRC``):
H hello, O periodic offsets, Q answer to a query, T temperatures,
A acknowledgement, E error. Commands from the controller (``$TC,<cmd>,...*CRC``):
P position (and spindle speed), M feed/range, Q query, R reference, S temperatures, V hello,
U table upload (B begin, D data, C commit, X abort), L latch reference
temperatures, X reset.
A line that is corrupt, unknown or out of range is answered with an E frame
and changes nothing; E frames are rate-limited (a burst of _E_BURST, then one
per _E_REFILL_MS), so garbage on the line cannot crowd out the offsets. U,B, U,C,
U,X, L and X change what the board outputs: they end with ``<counter>,<tag>``
(firmware/auth.py) and are refused without; each U,D chunk ends with a tag
bound to its U,B. Only a valid P or Q counts as the controller's life for the
link watchdog (LINK_TIMEOUT).

Periodic frames, position reports and queries allocate nothing; the upload and
the hello frame may (they are not part of the steady state).
"""

from micropython import const

from firmware import frame as fr
from firmware.safety import round10
from firmware.slots import UploadError, SLOT_NAMES

# wire contract values (firmware/wire.py), as folded copies (tests/firmware/test_fw_consts.py checks)
_PROTOCOL_VERSION = const(2)
_FIRMWARE_VERSION = const(b"0.1.0")
_REF_LETTERS = const(b"-SLUNCO")
_UPLOAD_STEPS = const(b"BDCX")  # wire.UPLOAD_STEPS (the U sub-commands known, so a malformed one is a syntax error)
_TAG_BYTES = const(16)
_MAX_COUNTER = const(999999999)
_E_BURST = const(8)
_E_REFILL_MS = const(25)
# firmware.auth's (tests/firmware/test_fw_consts.py checks the copies)
_BAD_TAG = const(2)
_AUTH_BUSY = const(5)
_UNSIGNED = const(6)

# firmware.frame's (tests/firmware/test_fw_consts.py checks the copies)
_MAX_LINE = const(200)
_LINE_OK = const(0)
_LINE_CRC = const(2)
_LINE_OVERFLOW = const(3)

# error codes of E frames
_E_CRC = const(1)
_E_SYNTAX = const(2)
_E_UNKNOWN = const(3)
_E_RANGE = const(4)
_E_STATE = const(5)
_E_TABLE = const(6)
_E_OVERFLOW = const(7)
_E_AUTH = const(8)
_E_BUSY = const(9)
ERRORS = {1: b"crc", 2: b"syntax", 3: b"unknown", 4: b"range", 5: b"state", 6: b"table", 7: b"overflow",
          8: b"auth", 9: b"busy"}
_UPLOAD_CODES = {"range": _E_RANGE, "state": _E_STATE, "table": _E_TABLE}
_ONE_POSITION = b"PQR"  # commands with one position argument
_NO_ARGUMENT = b"SV"
_SIGNED = b"XL"  # no argument but the counter and the tag

_POS_LIMIT = const(100000000)  # |position| in um accepted from the controller (100 m)
_FEED_LIMIT = const(1000000)  # mm/min
_SPINDLE_LIMIT = const(1000000)  # |spindle speed| in rpm accepted from the controller
_STATE_LIMIT = const(0x3FFFFFFF)  # |a supplied lag state| parsed (the table's box then decides)
_SUPPLY_LETTERS = const(b"-AS")  # wire.SUPPLY_LETTERS, indexed by App.supply
_MAX_CHUNK = const(64)  # bytes of table data per U,D frame
_RX_CHUNK = const(64)
_MAX_READS = const(8)

# frame kinds, command letters and upload steps as ASCII codes (firmware/wire.py FRAME_KINDS, COMMANDS,
# UPLOAD_STEPS; folded copies, checked by tests/firmware/test_fw_consts.py)
_H = const(72)
_O = const(79)
_Q = const(81)
_T = const(84)
_A = const(65)
_E = const(69)
_P = const(80)
_M = const(77)
_R = const(82)
_S = const(83)
_V = const(86)
_U = const(85)
_X = const(88)
_Y = const(89)
_B = const(66)
_D = const(68)
_C = const(67)
_L = const(76)


class StreamLink:
    def __init__(self, app):
        self.app = app
        self.serial = app.board.serial
        self.w = fr.FrameWriter(self.serial)
        self.r = fr.LineReader()
        self.rx = bytearray(_RX_CHUNK)
        self.chunk = bytearray(_MAX_CHUNK)
        self.last = app.clock.ticks_ms()
        self.due_ms = 0  # time towards the next periodic frame (a counter: ticks wrap)
        self.frame_ms = app.cfg.frame_ms
        self.e_tokens = _E_BURST  # E frames that may go out now (error)
        self.e_ms = 0
        self.e_dropped = 0  # E frames not sent for want of a token since boot (a count, not on the wire)
        self.upload_id = b""  # what binds the open upload's chunks and commit to its U,B (firmware.auth)

    # --- frames out ----------------------------------------------------------
    def boot(self):
        self.hello()
        for slot, reason in self.app.store.refusals:
            self.error(_E_TABLE, slot.encode() + b" " + reason.encode())

    def hello(self):
        """H,<protocol>,<firmware>,<slot>,<table crc32>,<provenance[:8] hex>,<kind>,<axis>,<channels>,<refs>,<counter>,<error reference>."""
        a = self.app
        w = self.w
        w.begin(a.status, _H)
        w.int(_PROTOCOL_VERSION)
        w.text(_FIRMWARE_VERSION)
        t = a.table
        if t is None:
            w.text(b"-,-,-,-,-")
        else:
            w.text(SLOT_NAMES[a.slot].encode())
            w.hex(t.crc, 8)
            w.hexbytes(t.provenance, 0, 8)
            w.text(t.kind.encode())
            w.text(t.axis.encode())
        w.int(a.channels.n)
        w.sep()
        w.buf[w.n] = _REF_LETTERS[a.ref_state]
        w.n += 1
        au = a.auth
        if au.keyed:  # the last counter used: an authorised command needs a larger one
            w.int(au.last)
        else:
            w.text(b"-")
        w.hex(au.nonce_hi, 4)  # the session nonce every authorised command's tag starts with
        w._hex(au.nonce_lo, 4)
        # appended after the nonce (firmware/wire.py HELLO_ERROR_REFERENCE): what the offsets compensate (table header byte 58)
        if t is None:
            w.text(b"-")
        elif t.error_ref == 0:
            w.text(b"start")
        else:
            w.text(t.sensors[t.error_ref - 1].encode())
        w.end()

    def offsets(self, kind, pos):
        """O or Q frame: <t_ms>,<pos_um>,<total um>,<offset at ref um>,<slope um/m>."""
        a = self.app
        w = self.w
        w.begin(a.status, kind)
        w.int(a.last_t)
        w.int(pos)
        w.fixed(round10(a.total if kind == _O else a.total_at(pos)), 1)
        w.fixed(round10(a.ref_out), 1)
        w.fixed(a.slope_out, 2)
        w.end()

    def temperatures(self):
        """T,<t_ms>,<per channel: milli-degC as degC.mmm, or !<fault bits hex>>."""
        a = self.app
        ch = a.channels
        w = self.w
        w.begin(a.status, _T)
        w.int(a.last_t)
        for i in range(ch.n):
            if ch.good[i]:
                w.fixed(ch.temp[i], 3)
            else:
                w.sep()
                w.raw(b"!")
                w._hex(ch.fault[i], 2)
        w.end()

    def ack(self, cmd, sub=0, value=None, text=None):
        """A,<cmd>[,<sub>][,<value>][,<text>]."""
        w = self.w
        w.begin(self.app.status, _A)
        w.sep()
        w.buf[w.n] = cmd
        w.n += 1
        if sub:
            w.sep()
            w.buf[w.n] = sub
            w.n += 1
        if value is not None:
            w.int(value)
        if text is not None:
            w.text(text)
        w.end()

    def error(self, code, detail=None):
        """E,<code>,<word>[,<detail>] (the word is ERRORS[code]); dropped without a token (rate limit)."""
        if self.e_tokens <= 0:
            self.e_dropped += 1
            return
        self.e_tokens -= 1
        w = self.w
        w.begin(self.app.status, _E)
        w.int(code)
        w.text(ERRORS[code])
        if detail is not None:
            w.sep()
            for c in detail:  # keep the frame parseable whatever the detail says
                w.buf[w.n] = c if 32 <= c <= 126 and c not in (44, 42, 36) else 32
                w.n += 1
                if w.n > _MAX_LINE - 8:
                    break
        w.end()

    # --- link service ---------------------------------------------------------
    def poll(self, now):
        rx = self.rx
        r = self.r
        for _ in range(_MAX_READS):
            n = self.serial.readinto(rx)
            if not n:
                return
            for k in range(n):
                if r.feed(rx[k]):
                    self._line(now)
            if n < _RX_CHUNK:
                return

    def after_cycle(self, now):
        dt = self.app.clock.ticks_diff(now, self.last)
        self.last = now
        if self.e_tokens < _E_BURST and dt > 0:
            v = self.e_ms + dt
            k = v // _E_REFILL_MS
            self.e_ms = v - k * _E_REFILL_MS
            k += self.e_tokens
            self.e_tokens = k if k < _E_BURST else _E_BURST
        if not self.frame_ms:
            return
        if dt > 0:
            self.due_ms += dt
        if self.due_ms >= 0:
            self.offsets(_O, self.app.pos_used)
            self.due_ms -= self.frame_ms
            if self.due_ms >= 0:  # fell behind: no burst of frames
                self.due_ms = -self.frame_ms

    def _line(self, now):
        r = self.r
        if r.status == _LINE_CRC:
            self.error(_E_CRC)
            return
        if r.status == _LINE_OVERFLOW:
            self.error(_E_OVERFLOW)
            return
        if r.status != _LINE_OK:
            self.error(_E_SYNTAX)
            return
        self._command(r.letter(0), r.nf, now)

    def _command(self, c, nf, now):
        a = self.app
        r = self.r
        if c == _U:
            return self._upload(nf)
        if c in _ONE_POSITION:
            # P,<pos> or P,<pos>,<spindle rpm>: the speed is an input like the position (unsigned, as P is)
            if nf != 2 and not (nf == 3 and c == _P):
                return self.error(_E_SYNTAX)
            v = r.int(1, -_POS_LIMIT, _POS_LIMIT)
            rpm = r.int(2, -_SPINDLE_LIMIT, _SPINDLE_LIMIT) if nf == 3 else 0
            if v is None or rpm is None:
                return self.error(_E_RANGE)
            if c == _P:
                if not a.report_position(v, now):
                    return self.error(_E_RANGE, b"implausible position")
                a.link_alive(now)  # a valid P or Q is the controller's life, nothing else
                if nf == 3:
                    a.report_spindle(rpm)
            elif c == _Q:
                a.link_alive(now)
                self.offsets(_Q, v)
            else:
                ref = a.set_reference(v)
                if ref is None:
                    return self.error(_E_STATE, b"no table")
                self.ack(_R, 0, ref)
        elif c == _M:
            if nf != 4:
                return self.error(_E_SYNTAX)
            f = r.int(1, 0, _FEED_LIMIT)
            lo = r.int(2, -_POS_LIMIT, _POS_LIMIT)
            hi = r.int(3, -_POS_LIMIT, _POS_LIMIT)
            if f is None or lo is None or hi is None or not a.feed_plausible(f):
                return self.error(_E_RANGE)
            if not a.set_feed(f, lo, hi):
                return self.error(_E_STATE, b"no screw or dynamic table")
            self.ack(_M, 0, f)
        elif c == _Y:
            self._supply(nf)
        elif c in _NO_ARGUMENT:
            if nf != 1:
                return self.error(_E_SYNTAX)
            if c == _S:
                self.temperatures()
            else:
                self.hello()
        elif c in _SIGNED:
            if not self._authorised(nf, 3):
                return
            if c == _L:
                why = a.relatch()
                if why is not None:
                    return self.error(_E_BUSY) if why == b"busy" else self.error(_E_STATE, why)
                self.ack(_L, _REF_LETTERS[a.ref_state])
            else:
                self.ack(_X)
                a.reset()
        else:
            self.error(_E_UNKNOWN)

    def _supply(self, nf):
        """``Y``: the board's dictionary of the lag states the controller supplies, ``A,Y,<state>,<k>`` then per state
        ``<source>,<tau_ms>,<scale>``; ``Y,<v1>,...,<vk>``: the states (docs/protocol.md "Supplied lag states"),
        answered ``A,Y,S,1`` (set now) or ``A,Y,S,0`` (set at this table's start already: not applied)."""
        a = self.app
        if nf == 1:
            w = self.w
            w.begin(a.status, _A)
            w.sep()
            w.buf[w.n] = _Y
            w.n += 1
            w.sep()
            w.buf[w.n] = _SUPPLY_LETTERS[a.supply]
            w.n += 1
            w.int(a.sup_k)
            if a.sup_k:
                t = a.table
                for j in range(t.nf):
                    if t.tauc[j]:
                        w.int(t.src[j])
                        w.int(t.tauc[j])
                        w.int(a.ev.supply_scale(j))
            w.end()
            return
        r = self.r
        vals = a.sup_vals
        k = nf - 1
        if k > len(vals):
            return self.error(_E_SYNTAX)
        for i in range(k):
            v = r.int(i + 1, -_STATE_LIMIT, _STATE_LIMIT)
            if v is None:
                return self.error(_E_RANGE)
            vals[i] = v
        got = a.supply_states(vals, k)
        if got == -1:
            return self.error(_E_STATE, b"no supplied states")
        if got == -2:
            return self.error(_E_SYNTAX, b"supplied states: wrong count")
        if got < 0:
            return self.error(_E_RANGE, b"supplied state " + bytes((49 - 3 - got,)) + b" outside its box")
        self.ack(_Y, _SUPPLY_LETTERS[a.supply], got)

    def _tag(self, k):
        """Field ``k`` as _TAG_BYTES bytes (2 * _TAG_BYTES hex digits), or None (the E frame is sent)."""
        r = self.r
        s = r.fs[k]
        if r.fe[k] - s != 2 * _TAG_BYTES:
            self.error(_E_RANGE)
            return None
        tag = bytearray(_TAG_BYTES)
        for i in range(_TAG_BYTES):
            hi = fr._hexval(r.buf[s + 2 * i])
            lo = fr._hexval(r.buf[s + 2 * i + 1])
            if hi < 0 or lo < 0:
                self.error(_E_SYNTAX)
                return None
            tag[i] = (hi << 4) | lo
        return tag

    def _refuse(self, why):
        from firmware.auth import REASONS
        self.app.auth.why = why
        self.error(_E_AUTH, REASONS[why])

    def _authorised(self, nf, want, extra=b"", bound=None):
        """Whether the line (``want`` fields, the last two ``<counter>,<tag>``) is authorised;
        if not, the E frame is sent. The tag covers the session nonce (or ``bound``), the line up
        to the counter, then ``extra``."""
        from firmware.auth import REASONS
        if nf == want - 2:
            self._refuse(_UNSIGNED)
            return False
        if nf != want:
            self.error(_E_SYNTAX)
            return False
        r = self.r
        k = nf - 1
        ctr = r.int(k - 1, 1, _MAX_COUNTER)
        if ctr is None:
            self.error(_E_RANGE)
            return False
        tag = self._tag(k)
        if tag is None:
            return False
        self.ctr = ctr
        why = self.app.auth.check(ctr, tag, memoryview(r.buf)[0:r.fe[k - 1]], extra, bound)
        if why:
            if why == _AUTH_BUSY:
                self.error(_E_BUSY)
            else:
                self.error(_E_AUTH, REASONS[why])
            return False
        return True

    def _upload(self, nf):
        a = self.app
        r = self.r
        sub = r.letter(1) if nf >= 2 else 0
        try:
            if sub == _B and nf in (4, 6):
                size = r.int(2, 0, 1 << 24)
                crc = r.hexint(3, 8)
                if size is None or crc < 0:
                    return self.error(_E_RANGE)
                if not self._authorised(nf, 6):
                    return
                if a.store.uploading:  # someone's upload: they finish or abort it, or it times out
                    return self.error(_E_STATE, b"upload open")
                if not a.spend_flash():
                    return self.error(_E_BUSY)
                slot = a.store.begin(size, crc)
                self.upload_id = a.auth.upload_id(self.ctr)
                self.ack(_U, _B, None, SLOT_NAMES[slot].encode())
            elif sub == _D and nf in (4, 5):
                off = r.int(2, 0, 1 << 24)
                s = r.fs[3]
                e = r.fe[3]
                if off is None or (e - s) & 1 or e == s or e - s > 2 * _MAX_CHUNK:
                    return self.error(_E_RANGE)
                # the chunk's tag binds it to the open upload's U,B: checked before anything is written
                if nf == 4:
                    return self._refuse(_UNSIGNED)
                tag = self._tag(4)
                if tag is None:
                    return
                if not a.store.uploading:
                    return self.error(_E_STATE, b"no upload open")
                if not a.auth.chunk_ok(tag, memoryview(r.buf)[0:e], self.upload_id):
                    return self._refuse(_BAD_TAG)
                n = (e - s) >> 1
                buf = self.chunk
                for k in range(n):
                    hi = fr._hexval(r.buf[s + 2 * k])
                    lo = fr._hexval(r.buf[s + 2 * k + 1])
                    if hi < 0 or lo < 0:
                        return self.error(_E_SYNTAX)
                    buf[k] = (hi << 4) | lo
                got = a.store.write(off, bytes(buf[:n]))
                self.ack(_U, _D, got)
            elif sub == _C and nf in (2, 4):
                # the tag covers the table received (its sha256): a refusal leaves the upload open
                if not self._authorised(nf, 4, a.store.digest(), self.upload_id):
                    return
                t, slot = a.store.commit()
                a.use_table(t, slot)
                self.ack(_U, _C, None, SLOT_NAMES[slot].encode())
                self.hello()
            elif sub == _X and nf in (2, 4):
                if not self._authorised(nf, 4):
                    return
                a.store.abort()
                self.ack(_U, _X)
            else:
                self.error(_E_SYNTAX if sub in _UPLOAD_STEPS else _E_UNKNOWN)
        except UploadError as e:
            self.error(_UPLOAD_CODES.get(e.code, _E_STATE), e.detail.encode())
        except OSError as e:
            a.store.abort()
            self.error(_E_STATE, ("flash: %s" % e).encode())
