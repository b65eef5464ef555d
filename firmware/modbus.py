"""Modbus RTU slave mode of the serial link (register map in docs/protocol.md).

Function codes 03 (read holding), 04 (read input), 06 (write single holding)
and 16 (write multiple holding). Anything else gets exception 01 (illegal
function), a register range outside the map 02 (illegal data address), a bad
quantity, byte count or register value 03 (illegal data value); a multi-register
write is validated completely before any register changes. Frames with a bad
CRC-16/MODBUS, or for another slave address, are ignored, as the Modbus
specification requires (the master times out). Broadcast (address 0) requests
change nothing and get no reply.

Writes to the registers that change the output (enable, slew, link timeout,
latch) need authorisation (firmware/auth.py): the master first writes the
auth block, holding registers 8..17 (counter, then the 16-byte tag over this
slave's address, the write's start, count, values and the counter), and the
next such write is checked against it (exception 04 when refused, the reason
in input register 50). Position, reference and spindle speed are written as whole int32s; the
spindle speed (holding registers 18-19, rpm, an input of dynamic tables like the position) needs no
authorisation, as the position does not.

A request is complete when its function code's length has arrived, or after a
silence of 3.5 character times (at least 2 ms) for anything else. Allocation-free.
"""

from micropython import const

from firmware.crc16 import crc16_modbus
from firmware.safety import round10

# input registers
_IR_STATUS_LO = const(0)
_IR_STATUS_HI = const(1)
_IR_SEQUENCE = const(2)
_IR_TOTAL = const(3)  # 0.1 um, int16, at the reported position
_IR_REF_OFFSET = const(4)  # 0.1 um, int16, at the reference position
_IR_SLOPE = const(5)  # 0.01 um/m, int16
_IR_POSITION = const(6)  # int32 um, high word first
_IR_REFERENCE = const(8)  # int32 um
_IR_TABLE_CRC = const(10)  # uint32
_IR_SLOT = const(12)  # 0 none, 1 A, 2 B
_IR_CHANNELS = const(13)
_IR_REF_STATE = const(14)  # firmware.app's ref_state: where the reference temperatures come from
_IR_UNMAPPED = const(15)  # the one hole in the map: exception 02
_IR_TEMPS = const(16)  # 16 x int16 0.01 degC, 0x8000 when faulty
_IR_FAULTS = const(32)  # 16 x channel fault bits (firmware.channels F_*)
_IR_AUTH_COUNTER = const(48)  # uint32: the last counter used (firmware.auth)
_IR_AUTH_WHY = const(50)  # the last refusal (firmware.auth reason code)
_IR_NONCE = const(51)  # the session nonce (firmware.auth), high word first: every auth block's tag starts with it
_IR_ERROR_REF = const(53)  # the table's error reference (header byte 58): 0 start (or no table: IR 12 = 0), 1 + i sensor i
# the lag states the controller supplies (firmware.app supply, table.tauc; docs/protocol.md "Supplied lag states")
_IR_SUPPLY_STATE = const(54)  # wire.SUPPLY_*: 0 none, 1 awaited, 2 set at this table's start
_IR_SUPPLY_COUNT = const(55)  # k
_IR_SUPPLY_DICT = const(56)  # per supplied state: source (int16), tau_ms (uint32, high word first), scale (int16)
_SUPPLY_DICT_REGS = const(4)
_N_INPUT = const(72)
# holding registers
_HR_ENABLE = const(0)  # 0/1
_HR_SLEW = const(1)  # um/s, 1..10000
_HR_LINK_TIMEOUT = const(2)  # ms, 0 = off
_HR_POSITION = const(3)  # int32 um, high word first: writing it is a position report
_HR_REFERENCE = const(5)  # int32 um
_HR_LATCH = const(7)  # write 1: latch the reference temperatures now (reads 0)
_N_VALUES = const(8)  # registers 0..7 hold values; the auth block reads 0
_HR_AUTH = const(8)  # 10 registers: counter (uint32), tag (16 bytes); written whole with FC16
_N_AUTH = const(10)
_HR_SPINDLE = const(18)  # int32 rpm, high word first, written whole with FC16: a spindle speed report
_HR_SUPPLY = const(20)  # MAX_SUPPLIED x int32, high word first: the supplied lag states, the table's k written whole (reads 0)
_N_HOLDING = const(28)
_PROTECTED = const(0x87)  # bit r: holding register r needs authorisation (0 enable, 1 slew, 2 timeout, 7 latch)

_EX_ILLEGAL_FUNCTION = const(1)
_EX_ILLEGAL_ADDRESS = const(2)
_EX_ILLEGAL_VALUE = const(3)
_EX_DEVICE_FAILURE = const(4)
_UNSIGNED = const(6)  # firmware.auth's (tests/firmware/test_fw_consts.py checks the copies)

_POS_LIMIT = const(100000000)  # |position| in um, as the stream's (100 m)
_SPINDLE_LIMIT = const(1000000)  # |spindle speed| in rpm, as the stream's
_NO_VALUE = const(-32768)


def _s16(v):
    if v > 32767:
        return 32767
    if v < -32768:
        return -32768
    return v


class ModbusLink:
    def __init__(self, app):
        self.app = app
        self.serial = app.board.serial
        self.addr = app.cfg.modbus_address
        self.buf = bytearray(256)
        self.n = 0
        self.tx = bytearray(256)
        self.rx = bytearray(64)
        self.last_byte = app.clock.ticks_ms()
        baud = app.cfg.baud
        self.silence_ms = 2 if baud >= 19200 else (38500 + baud - 1) // baud + 1
        # values 0..7, the auth block 8..17 (reads 0, not stored here), the spindle speed 18..19
        self.hold = [1, app.cfg.slew_um_per_s, app.cfg.link_timeout_ms, 0, 0, 0, 0, 0] + [0] * (_N_HOLDING - _N_VALUES)
        self.vals = [0] * 123  # values of a write, validated before use
        self.armed = False  # an auth block waits for the next protected write
        self.auth = bytearray(4 + 16)  # its counter (big-endian) and tag
        # [value, high half, low half] of the table CRC and of the auth counter: 32-bit values, long
        # ints on a 32-bit port (small ints stop at 2**30), where every shift or mask allocates
        self.split = [[-1, 0, 0], [-1, 0, 0]]
        self.now = self.last_byte  # the tick of the request being handled
        self.alive = False  # whether its normal answer counts as the controller's life

    def boot(self):
        pass

    def after_cycle(self, now):
        # split the 32-bit registers here, when they changed (a table switch or an authorised command,
        # cycles that allocate anyway), so that reading them never does
        a = self.app
        self._half(0, a.table.crc if a.table is not None else 0, 0)
        self._half(1, a.auth.last, 0)

    # --- receive --------------------------------------------------------------
    def poll(self, now):
        clock = self.app.clock
        rx = self.rx
        got = False
        for _ in range(8):
            k = self.serial.readinto(rx)
            if not k:
                break
            got = True
            for j in range(k):
                if self.n < 256:
                    self.buf[self.n] = rx[j]
                    self.n += 1
            if k < 64:
                break
        if got:
            self.last_byte = now
        while self.n:
            need = self._length()
            if need > 0 and self.n >= need:
                self._frame(need, now)
                self._drop(need)
            elif clock.ticks_diff(now, self.last_byte) >= self.silence_ms or self.n >= 256:
                self._frame(self.n, now)
                self.n = 0
            else:
                return

    def _drop(self, k):
        b = self.buf
        for i in range(k, self.n):
            b[i - k] = b[i]
        self.n -= k

    def _length(self):
        """Length of the request in buf from its function code, 0 if unknown yet."""
        if self.n < 2:
            return 0
        fc = self.buf[1]
        if fc in (3, 4, 6):
            return 8
        if fc == 16:
            if self.n < 7:
                return 0
            return 9 + self.buf[6]
        return 0

    def _frame(self, n, now):
        b = self.buf
        if n < 4:
            return
        crc = crc16_modbus(b, 0, n - 2)
        if b[n - 2] != crc & 0xFF or b[n - 1] != crc >> 8:
            return
        addr = b[0]
        if addr != self.addr and addr != 0:
            return
        fc = b[1]
        if addr == 0 and (fc == 6 or fc == 16):
            return  # a broadcast write would change every slave at once, unanswered: refused
        self.now = now
        self.alive = True
        if fc == 3 or fc == 4:
            self._read(fc, n, addr)
        elif fc == 6:
            self._write_single(n, addr)
        elif fc == 16:
            self._write_multiple(n, addr)
        else:
            self._exception(fc, _EX_ILLEGAL_FUNCTION, addr)

    # --- replies ------------------------------------------------------------------
    def _send(self, n, addr):
        if addr == 0:
            return  # a broadcast read is anybody's: it does not feed the link watchdog either
        if self.alive and not self.tx[1] & 0x80:
            # a request to this slave that it answers normally: the controller's life (an exception
            # answers a refused one, which does not count)
            self.app.link_alive(self.now)
        t = self.tx
        crc = crc16_modbus(t, 0, n)
        t[n] = crc & 0xFF
        t[n + 1] = crc >> 8
        self.serial.write(t, n + 2)

    def _exception(self, fc, code, addr):
        t = self.tx
        t[0] = self.addr
        t[1] = (fc | 0x80) & 0xFF
        t[2] = code
        self._send(3, addr)

    def _read(self, fc, n, addr):
        b = self.buf
        if n != 8:
            return self._exception(fc, _EX_ILLEGAL_VALUE, addr)
        start = (b[2] << 8) | b[3]
        qty = (b[4] << 8) | b[5]
        if qty < 1 or qty > 125:
            return self._exception(fc, _EX_ILLEGAL_VALUE, addr)
        limit = _N_INPUT if fc == 4 else _N_HOLDING
        if start + qty > limit or (fc == 4 and start <= _IR_UNMAPPED < start + qty):
            return self._exception(fc, _EX_ILLEGAL_ADDRESS, addr)
        if addr == 0:
            return
        t = self.tx
        t[0] = self.addr
        t[1] = fc
        t[2] = 2 * qty
        k = 3
        for r in range(start, start + qty):
            v = self.input_register(r) if fc == 4 else (self.hold[r] if r < _N_VALUES or _HR_SPINDLE <= r < _HR_SUPPLY else 0)
            v &= 0xFFFF
            t[k] = v >> 8
            t[k + 1] = v & 0xFF
            k += 2
        self._send(k, addr)

    def input_register(self, r):
        a = self.app
        if r == _IR_STATUS_LO:
            return a.status & 0xFFFF
        if r == _IR_STATUS_HI:
            return (a.status >> 16) & 0xFFFF
        if r == _IR_SEQUENCE:
            return a.cycles & 0xFFFF
        if r == _IR_TOTAL:
            return _s16(round10(a.total))
        if r == _IR_REF_OFFSET:
            return _s16(round10(a.ref_out))
        if r == _IR_SLOPE:
            return _s16(a.slope_out)
        if r == _IR_POSITION or r == _IR_POSITION + 1:
            return self._word(a.pos_used, r - _IR_POSITION)
        if r == _IR_REFERENCE or r == _IR_REFERENCE + 1:
            return self._word(a.ev.pos_ref if a.ev is not None else 0, r - _IR_REFERENCE)
        if r == _IR_TABLE_CRC or r == _IR_TABLE_CRC + 1:
            return self._half(0, a.table.crc if a.table is not None else 0, r - _IR_TABLE_CRC)
        if r == _IR_SLOT:
            return 0 if a.slot is None else a.slot + 1
        if r == _IR_CHANNELS:
            return a.channels.n
        if r == _IR_REF_STATE:
            return a.ref_state
        if r == _IR_AUTH_COUNTER or r == _IR_AUTH_COUNTER + 1:
            return self._half(1, a.auth.last, r - _IR_AUTH_COUNTER)
        if r == _IR_AUTH_WHY:
            return a.auth.why
        if r == _IR_NONCE:
            return a.auth.nonce_hi
        if r == _IR_NONCE + 1:
            return a.auth.nonce_lo
        if r == _IR_ERROR_REF:
            return a.table.error_ref if a.table is not None else 0
        if r == _IR_SUPPLY_STATE:
            return a.supply
        if r == _IR_SUPPLY_COUNT:
            return a.sup_k
        if r >= _IR_SUPPLY_DICT:
            return self._supply_entry(r - _IR_SUPPLY_DICT)
        ch = a.channels
        if _IR_TEMPS <= r < _IR_TEMPS + 16:
            i = r - _IR_TEMPS
            if i >= ch.n or not ch.good[i]:
                return _NO_VALUE
            t = ch.temp[i]
            return _s16((t + 5) // 10 if t >= 0 else -((5 - t) // 10))
        if _IR_FAULTS <= r < _IR_FAULTS + 16:
            i = r - _IR_FAULTS
            return ch.fault[i] if i < ch.n else 0
        return 0

    def _half(self, k, v, low):
        # a 32-bit value split once per new value: comparing a long int allocates nothing, so
        # reading the registers again does not either (after_cycle splits new values)
        s = self.split[k]
        if s[0] != v:
            s[1] = v >> 16
            s[2] = v & 0xFFFF
            s[0] = v
        return s[2] if low else s[1]

    def _word(self, v, low):
        # int32 as two registers without forming values beyond 2**30
        if low:
            return v & 0xFFFF
        return (v >> 16) & 0xFFFF

    # --- writes --------------------------------------------------------------------
    def _write_single(self, n, addr):
        b = self.buf
        if n != 8:
            return self._exception(6, _EX_ILLEGAL_VALUE, addr)
        r = (b[2] << 8) | b[3]
        v = (b[4] << 8) | b[5]
        if r >= _N_HOLDING:
            return self._exception(6, _EX_ILLEGAL_ADDRESS, addr)
        if _HR_POSITION <= r < _N_VALUES - 1 or r >= _N_VALUES:
            # half an int32 (it would combine with a stale other half) or part of the auth block
            return self._exception(6, _EX_ILLEGAL_VALUE, addr)
        self.vals[0] = v
        code = self._apply(r, 1)
        if code:
            return self._exception(6, code, addr)
        t = self.tx
        for i in range(6):
            t[i] = b[i]
        t[0] = self.addr
        self._send(6, addr)

    def _write_multiple(self, n, addr):
        b = self.buf
        start = (b[2] << 8) | b[3]
        qty = (b[4] << 8) | b[5]
        if qty < 1 or qty > 123 or b[6] != 2 * qty or n != 9 + 2 * qty:
            return self._exception(16, _EX_ILLEGAL_VALUE, addr)
        if start + qty > _N_HOLDING:
            return self._exception(16, _EX_ILLEGAL_ADDRESS, addr)
        for i in range(qty):
            self.vals[i] = (b[7 + 2 * i] << 8) | b[8 + 2 * i]
        if start == _HR_SPINDLE and qty == 2:
            code = self._spindle()
        elif start == _HR_SUPPLY:
            code = self._supply(qty)
        elif start + qty > _N_VALUES:
            if start != _HR_AUTH or qty != _N_AUTH:
                return self._exception(16, _EX_ILLEGAL_VALUE, addr)  # the auth block and the speed are written whole
            au = self.auth
            for i in range(_N_AUTH):
                au[2 * i] = b[7 + 2 * i]
                au[2 * i + 1] = b[8 + 2 * i]
            self.armed = True
            self.alive = False  # anyone can write an auth block: only what it authorises counts
            code = 0
        else:
            code = self._apply(start, qty)
        if code:
            return self._exception(16, code, addr)
        t = self.tx
        t[0] = self.addr
        for i in range(1, 6):
            t[i] = b[i]
        self._send(6, addr)

    def _apply(self, start, qty):
        """Validate ``vals[:qty]`` for registers start.., then store and act; exception code or 0."""
        h = self.hold
        vals = self.vals
        end = start + qty
        protect = False
        for i in range(qty):
            r = start + i
            v = vals[i]
            if (_PROTECTED >> r) & 1:
                protect = True
            if r == _HR_ENABLE and v > 1:
                return _EX_ILLEGAL_VALUE
            if r == _HR_SLEW and (v < 1 or v > 10000):
                return _EX_ILLEGAL_VALUE
            if r == _HR_POSITION or r == _HR_REFERENCE:
                if r + 1 >= end:
                    return _EX_ILLEGAL_VALUE  # half an int32
                hi = v - 65536 if v > 32767 else v
                if hi > 1526 or hi < -1527:  # far outside: the value below stays a small int
                    return _EX_ILLEGAL_VALUE
                p = hi * 65536 + vals[i + 1]
                if p > _POS_LIMIT or p < -_POS_LIMIT:
                    return _EX_ILLEGAL_VALUE
                if r == _HR_POSITION and not self.app.position_plausible(p, self.now):
                    return _EX_ILLEGAL_VALUE
            if (r == _HR_POSITION + 1 or r == _HR_REFERENCE + 1) and r == start:
                return _EX_ILLEGAL_VALUE  # the low half alone
            if r == _HR_LATCH and v:
                if v > 1:
                    return _EX_ILLEGAL_VALUE
                if self.app.relatch(True) is not None:
                    return _EX_DEVICE_FAILURE
        if protect:
            armed = self.armed
            self.armed = False  # an auth block authorises one write
            if not armed:
                self.app.auth.why = _UNSIGNED
                return _EX_DEVICE_FAILURE
            if self._authorise(start, qty):
                return _EX_DEVICE_FAILURE
        pos = False
        ref = False
        for i in range(qty):
            r = start + i
            h[r] = vals[i]
            if r == _HR_POSITION or r == _HR_POSITION + 1:
                pos = True
            elif r == _HR_REFERENCE or r == _HR_REFERENCE + 1:
                ref = True
        a = self.app
        a.enabled = h[_HR_ENABLE] == 1
        if start <= _HR_SLEW < start + qty:
            a.set_slew(h[_HR_SLEW])
        a.link_timeout_ms = h[_HR_LINK_TIMEOUT]
        if pos:
            a.report_position(self._int32(_HR_POSITION), self.now)
        if ref:
            a.set_reference(self._int32(_HR_REFERENCE))
        if h[_HR_LATCH]:
            h[_HR_LATCH] = 0
            a.relatch()
        return 0

    def _spindle(self):
        """The spindle speed pair in ``vals[:2]``: validate, store, report; exception code or 0."""
        vals = self.vals
        hi = vals[0] - 65536 if vals[0] > 32767 else vals[0]
        if hi > 16 or hi < -17:  # far outside: the value below stays a small int
            return _EX_ILLEGAL_VALUE
        v = hi * 65536 + vals[1]
        if v > _SPINDLE_LIMIT or v < -_SPINDLE_LIMIT:
            return _EX_ILLEGAL_VALUE
        self.hold[_HR_SPINDLE] = vals[0]
        self.hold[_HR_SPINDLE + 1] = vals[1]
        self.app.report_spindle(v)
        return 0

    def _supply_entry(self, r):
        """Input register IR_SUPPLY_DICT + r: word r % 4 of the (r // 4)-th supplied state's dictionary entry."""
        a = self.app
        k = r // _SUPPLY_DICT_REGS
        if k >= a.sup_k:
            return 0
        t = a.table
        j = 0
        while True:  # the k-th filter with a tauc (at most nf steps)
            if t.tauc[j]:
                if k == 0:
                    break
                k -= 1
            j += 1
        w = r % _SUPPLY_DICT_REGS
        if w == 0:
            return t.src[j]
        if w == 1:
            return t.tauc[j] >> 16
        if w == 2:
            return t.tauc[j] & 0xFFFF
        return a.ev.supply_scale(j)

    def _supply(self, qty):
        """The supplied lag states, ``qty // 2`` int32 in ``vals[:qty]``: validate, hand to the app; exception code or 0.
        Set at this table's start already: answered normally, not applied (IR_SUPPLY_STATE says so)."""
        vals = self.vals
        a = self.app
        if qty % 2 or qty // 2 > len(a.sup_vals):
            return _EX_ILLEGAL_VALUE
        k = qty // 2
        for i in range(k):
            hi = vals[2 * i] - 65536 if vals[2 * i] > 32767 else vals[2 * i]
            if hi > 16383 or hi < -16384:  # beyond a small int: outside every state box
                return _EX_ILLEGAL_VALUE
            a.sup_vals[i] = hi * 65536 + vals[2 * i + 1]
        got = a.supply_states(a.sup_vals, k)
        if got == -1:
            return _EX_DEVICE_FAILURE
        if got < 0:
            return _EX_ILLEGAL_VALUE
        return 0

    def _authorise(self, start, qty):
        """The auth block's verdict on this write (firmware.auth reason, 0 = authorised)."""
        au = self.auth
        msg = bytearray(11 + 2 * qty)
        msg[0] = 77  # M
        msg[1] = 66  # B
        msg[2] = self.addr
        msg[3] = start >> 8
        msg[4] = start & 0xFF
        msg[5] = qty >> 8
        msg[6] = qty & 0xFF
        for i in range(qty):
            msg[7 + 2 * i] = self.vals[i] >> 8
            msg[8 + 2 * i] = self.vals[i] & 0xFF
        for i in range(4):
            msg[7 + 2 * qty + i] = au[i]
        ctr = (((au[0] << 8) | au[1]) << 16) | (au[2] << 8) | au[3]
        return self.app.auth.check(ctr, au[4:], msg)

    def _int32(self, r):
        hi = self.hold[r]
        if hi > 32767:
            hi -= 65536
        return hi * 65536 + self.hold[r + 1]
