"""The LinuxCNC bridge's logic, without HAL: link to the board, fault rules, offset ramp, counts loop.

``Bridge.step(now_s, inputs)`` is called once per period by the HAL layer
(``host/board/linuxcnc/halcomp.py``) with the controller's pins and returns the
pins to write. Everything here runs on plain Python so that it is
unit-tested without LinuxCNC (tests/board/test_board_linuxcnc_bridge.py); the
whole chain is tested in a real LinuxCNC in hil_tests/test_hil_linuxcnc.py.

What LinuxCNC does with the pins (motion's external axis offsets, checked in
the simulator): motion adds ``(counts - previous counts) * eoffset-scale`` to
``axis.L.eoffset-request`` only while the machine is on and homed, drops
count changes at any other time, and zeroes the external offset when the
machine is switched on again (the offset in force is folded into the axis
position, the axis does not move). So the bridge closes its loop on
``eoffset-request`` (what motion has taken) and writes count changes only
while motion can take them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from typing import TYPE_CHECKING
import math
import time
from dataclasses import dataclass, field

from firmware.wire import (
    E_AUTH, E_BUSY, E_RANGE, E_STATE, E_UNKNOWN, EX_DEVICE_FAILURE, HR_AUTH, HR_LATCH, HR_POSITION, HR_SLEW, HR_SPINDLE, HR_SUPPLY, IR_AUTH_COUNTER,
    IR_NONCE, IR_POSITION, IR_REFERENCE, IR_SEQUENCE, IR_STATUS_HI, IR_STATUS_LO, IR_SUPPLY_STATE, IR_TOTAL, MAX_SUPPLIED, SETTLING,
    SUPPLY_DICT_REGS,
)
from host.board.client import BoardLink
from host.board.link import FALLBACK, command_line
from host.board.supplied import SOURCE_NAMES, SignalRecord, SupplyEntry, SupplyError, modbus_dictionary, parse_dictionary

if TYPE_CHECKING:
    from host.board.linkauth import LinkSigner

COUNT_UM = 0.1  # one eoffset count: the board's offset resolution (docs/protocol.md, 0.1 um)
UM_PER_UNIT = {"mm": 1000.0, "inch": 25400.0}

# fault reasons, bits of the ``fault-code`` pin
LINK = 1       # the port failed, or (Modbus) the board did not answer a request
STALE = 2      # no new frame (sequence number moving) within stale_s
CRC = 4        # a malformed frame (bad CRC, bad syntax) arrived
BOARD = 8      # the board reports FALLBACK: its model cannot be used
FAULT_NAMES = {LINK: "link", STALE: "stale", CRC: "crc", BOARD: "fallback"}

# latch-state pin
LATCH_NONE, LATCH_SENT, LATCH_DONE, LATCH_REFUSED = 0, 1, 2, 3

# the signal record (supplied lag states): saved this often (what a crash of the bridge can lose: the spindle is then
# taken as stopped from the last save), a new event past this change of the speed, the dictionary asked again this
# often while the board says SETTLING
RECORD_SAVE_S = 60.0
RECORD_DEADBAND_RPM = 5
DICTIONARY_POLL_S = 5.0

# the axis feed (--feed, M): a move is what ``tcomp record --linuxcnc`` records as one (halsample.MotionSegmenter), so a
# table sees the feed its model was fitted on. Below IDLE_MM_PER_S the axis stands (a servo's dither is well below it, a
# thermal test's feeds are 1000s of mm/min).
IDLE_MM_PER_S = 0.01
# during a move a new feed is sent when the commanded velocity has settled (changed by at most FEED_STEADY_REL of itself,
# or FEED_RESOLUTION_MM_MIN, since the previous period: a cruise; an acceleration ramp changes it by accel x period,
# 150 mm/min a period at 50 mm/s2 and 50 ms) and differs from the feed last sent by more than FEED_CHANGE_REL (a feed
# override step, a new F word). A table's feed term is linear in the feed: a change below 2 % moves it by under 2 % of
# its value, and the board filters the feed with its lag, so sending every wobble would only load the link.
FEED_STEADY_REL = 0.005
FEED_CHANGE_REL = 0.02
FEED_RESOLUTION_MM_MIN = 1  # the protocol's unit (M takes whole mm/min)
FEED_LIMIT_MM_MIN = 1000000  # M's range (firmware/protocol.py _FEED_LIMIT)
# --feed with the velocity pin not netted reads 0 for ever and the table's feed term is silently 0: said when the
# position moves faster than UNNETTED_MM_PER_S (100 x the idle threshold, far above a servo's dither) for
# UNNETTED_PERIODS periods in a row (half a second at 50 ms) while the pin reads idle
UNNETTED_MM_PER_S = 1.0
UNNETTED_PERIODS = 10


@dataclass
class Reading:
    """One answer of the board: total offset (um) at ``pos_um``, status word, frame/cycle sequence."""
    total_um: float
    pos_um: int
    status: int
    seq: int


@dataclass
class Exchange:
    """What one link exchange brought back."""
    readings: list = field(default_factory=list)
    malformed: list = field(default_factory=list)   # reasons (bad CRC, syntax)
    error: str = ""                                 # the link failed this time (port gone, no answer)
    latch: str = ""                                 # "" no reply, "ok:<refs>" acknowledged, "refused:<why>"
    # the supplied lag states (host/board/supplied.py): "" nothing this time, "none" the table has none, "sent:<values>",
    # "set" the board took them, "kept" it had set them at its table's start already, "refused:<why>"
    supply: str = ""
    # the axis feed (M): "" no answer this time, "ok:<feed>" the board took it, "refused:<why>"
    feed: str = ""


SUPPLY_APPLIED = "%d" % 1  # A,Y,S,<applied>: 1 set now, 0 set at the table's start already (docs/protocol.md)

# a supplier gives the values of the board's dictionary entries now, or the reason it cannot (a SupplyError's text)
Supplier = Callable[[list[SupplyEntry]], "list[int] | str"]


class StreamLink:
    """``$TC`` stream mode: each exchange sends ``P,<pos>`` (``P,<pos>,<rpm>`` with the spindle speed)
    and ``Q,<pos>`` (the board's offset at this position, now) and decodes whatever arrived (Q answers
    and periodic O frames)."""

    def __init__(self, open_port: Callable[[], Any], reopen_s: float = 1.0, clock: Callable[[], float] = time.monotonic, signer: LinkSigner | None = None) -> None:
        """``open_port()`` returns an open pyserial-like port (timeout 0); it is called again, at most
        every ``reopen_s``, after the port failed (a USB board unplugged and back). ``signer``
        (host.board.linkauth.LinkSigner with the board's key) signs ``L``; the board's last counter comes
        from its hello, asked for (``V``) after every (re)open and after a refused ``L``."""
        self.open_port = open_port
        self.signer = signer
        self.want_hello = True
        self.reopen_s = reopen_s
        self.clock = clock
        self.link = None  # host.board.client.BoardLink on the open port
        self.next_open = 0.0
        self.latch_pending = False
        self.latch_wanted = False  # a signed L waits for the hello that carries the session nonce it needs
        self.supplier: Supplier | None = None  # set by the Bridge when it keeps a signal record
        self.want_dictionary = True  # ask the board's supplied-states dictionary (Y) with the next exchange
        self.dictionary_pending = False
        self.supply_pending = False
        # Ms sent whose answers have not come yet: the board answers each in order, and an answer may come a period
        # after the next M went out
        self.feed_pending = 0
        # the board may have lost the feed it was told (it booted: its hello; the port failed): the Bridge sends it again
        self.feed_lost = False

    def exchange(self, pos_um: int, latch: bool = False, spindle_rpm: int | None = None, feed_mm_min: int | None = None) -> Exchange:
        ex = Exchange()
        p = command_line("P", pos_um) if spindle_rpm is None else command_line("P", pos_um, spindle_rpm)
        out = p + command_line("Q", pos_um)
        if feed_mm_min is not None:
            # before P; lo = hi = the position: a dynamic table does not read them, and a screw table takes M as its
            # fallback travel until the P right after clears it, so a cycle between the two lines credits the step's
            # travel where the nut is, not at position 0 (docs/protocol.md)
            out = command_line("M", feed_mm_min, pos_um, pos_um) + out
            self.feed_pending += 1
        if self.supplier is not None and self.want_dictionary:
            # after the speed report: a board that waits for it and for the states then starts with both
            out += command_line("Y")
            self.want_dictionary = False
            self.dictionary_pending = True
        if self.want_hello:
            out = command_line("V") + out
            self.want_hello = False
        if latch and self.signer is not None:
            # the tag needs the board's current session nonce: ask for the hello, sign L when it comes
            self.latch_wanted = True
            if not out.startswith(command_line("V")):
                out = command_line("V") + out
        elif latch:
            out += command_line("L")
            self.latch_pending = True
        link = None
        try:
            if self.link is None:
                if self.clock() < self.next_open:
                    raise OSError("port closed after an error, reopening")
                self.next_open = self.clock() + self.reopen_s
                self.link = BoardLink(self.open_port())
            link = self.link
            link.write(out, flush=False)  # the port's write timeout bounds it; a period must not wait for the UART
            for f in link.receive():
                self._frame(f, ex)
            link.take_frames()  # handled above; the bridge keeps none
        except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
            ex.error = str(exc) or type(exc).__name__
            self.latch_pending = False
            self.latch_wanted = False
            self.dictionary_pending = False
            self.supply_pending = False
            self.feed_pending = 0
            self.close()
        if link is not None:
            while link.decoder.bad:
                ex.malformed.append(link.decoder.bad.pop(0)[1])
        return ex

    def _supply_frame(self, f, ex):
        """An A,Y answer: the dictionary (send the states if the board awaits them) or the answer to the states."""
        if self.supply_pending and len(f.fields) == 3:
            self.supply_pending = False
            ex.supply = "set" if f.fields[2] == SUPPLY_APPLIED else "kept"
            return
        if not self.dictionary_pending:
            return
        self.dictionary_pending = False
        try:
            letter, entries = parse_dictionary(f.fields)
        except SupplyError as exc:
            ex.malformed.append(str(exc))
            return
        if letter != "A":
            ex.supply = "none" if letter == "-" else "kept"
            return
        assert self.supplier is not None and self.link is not None  # asked only with a supplier, on the open link
        vals = self.supplier(entries)
        if isinstance(vals, str):
            ex.supply = "refused:" + vals
            return
        self.link.write(command_line("Y", *vals), flush=False)
        self.supply_pending = True
        ex.supply = "sent:" + ",".join("%d" % v for v in vals)

    def _feed_refusal(self, f):
        """An E frame that answers M: "no screw or dynamic table" names it; a range error without a detail does while
        no Y awaits its answer (the board refuses a feed above its max_speed_mm_min; P's range errors say "implausible
        position"). Anything else is another command's."""
        if not (f.kind == "E" and self.feed_pending):
            return False
        return f.fields[2:3] == ["no screw or dynamic table"] or (f.fields == ["%d" % E_RANGE, "range"] and not self.supply_pending)

    def _frame(self, f, ex):
        if f.kind == "A" and f.fields[:1] == ["Y"]:
            self._supply_frame(f, ex)
        elif f.kind == "A" and f.fields[:1] == ["M"]:
            self.feed_pending = max(self.feed_pending - 1, 0)
            if not ex.feed.startswith("refused:"):  # a refusal in the same exchange is the news
                ex.feed = "ok:" + ",".join(f.fields[1:])
        elif self._feed_refusal(f):
            self.feed_pending -= 1
            ex.feed = "refused:" + ",".join(f.fields[1:])
        elif f.kind == "E" and self.supply_pending and not self.latch_pending:
            self.supply_pending = False
            ex.supply = "refused:" + ",".join(f.fields)
        elif f.kind == "E" and self.dictionary_pending and f.fields[:1] == ["%d" % E_UNKNOWN]:
            self.dictionary_pending = False
            ex.supply = "refused:the board does not know Y (a firmware before table format 7)"
        elif f.kind in ("O", "Q"):
            try:
                ex.readings.append(Reading(float(f.fields[2]), int(f.fields[1]), f.status, f.seq))
            except (IndexError, ValueError):
                ex.malformed.append("bad %s fields: %r" % (f.kind, f.raw[:80]))
        elif f.kind == "A" and f.fields[:1] == ["L"] and self.latch_pending:
            self.latch_pending = False
            ex.latch = "ok:" + (f.fields[1] if len(f.fields) > 1 else "")
        if f.kind == "H":
            self.want_dictionary = True  # a hello: the board booted, or answered V after a reopen
            self.feed_lost = True
        if f.kind == "H" and self.signer is not None and f.fields:
            try:
                self.signer.observe_hello(f.fields)
                line = self.signer.stream_line("L") if self.latch_wanted else None
            except ValueError as exc:  # host.board.linkauth.CounterError: an old firmware's hello, a bad counter
                line = None
                if self.latch_wanted:
                    ex.latch = "refused:" + str(exc)
            if self.latch_wanted:
                self.latch_wanted = False
                if line is not None:
                    assert self.link is not None  # _frame reads the frames the open link has just received
                    self.link.write(line, flush=False)
                    self.latch_pending = True
        elif f.kind == "E" and self.latch_pending and f.fields[:1] in (["%d" % E_STATE], ["%d" % E_AUTH], ["%d" % E_BUSY]):
            # 5 state (no table, fixed references, sensor faulty), 8 auth (unsigned, bad tag,
            # replayed counter...), 9 busy
            self.latch_pending = False
            ex.latch = "refused:" + ",".join(f.fields[1:] if f.fields[0] != "%d" % E_STATE else f.fields[2:])
            if f.fields[0] == "%d" % E_AUTH:
                self.want_hello = True  # the counter may be behind the board's

    def close(self) -> None:
        self.want_hello = True  # a board that comes back is asked for its hello (counter)
        self.want_dictionary = True
        self.feed_lost = True
        if self.link is not None:
            self.link.close()
            self.link = None


def _s16(v):
    return v - 0x10000 if v & 0x8000 else v


class ModbusLink:
    """Modbus RTU mode (pymodbus master): write the position (holding 3-4) and, when given, the
    spindle speed (holding 18-19, int32 written whole), read input 0-9 (firmware/wire.py's register map)."""

    def __init__(self, client: Any, address: int = 1, signer: LinkSigner | None = None) -> None:
        self.client = client
        self.address = address
        self.signer = signer
        self.supplier: Supplier | None = None  # set by the Bridge when it keeps a signal record
        self.want_dictionary = True

    def slew_um_per_s(self) -> int | None:
        """The board's slew limit (holding register HR_SLEW), or None if it cannot be read."""
        try:
            rr = self.client.read_holding_registers(HR_SLEW, count=1, device_id=self.address)
        except Exception:  # pymodbus raises its own exception tree (ModbusException, ConnectionException)
            return None
        return None if rr.isError() else rr.registers[0]

    def exchange(self, pos_um: int, latch: bool = False, spindle_rpm: int | None = None) -> Exchange:
        ex = Exchange()
        p = pos_um & 0xFFFFFFFF
        try:
            w = self.client.write_registers(HR_POSITION, [p >> 16, p & 0xFFFF], device_id=self.address)
            if spindle_rpm is not None and not w.isError():
                r = spindle_rpm & 0xFFFFFFFF
                w = self.client.write_registers(HR_SPINDLE, [r >> 16, r & 0xFFFF], device_id=self.address)
            rr = self.client.read_input_registers(IR_STATUS_LO, count=IR_REFERENCE + 2, device_id=self.address)  # 0..9: status to reference position
            if w.isError() or rr.isError():
                ex.error = "modbus exception %s" % (w if w.isError() else rr)
            else:
                r = rr.registers
                pos = (r[IR_POSITION] << 16) | r[IR_POSITION + 1]
                pos = pos - (1 << 32) if pos & 0x80000000 else pos
                ex.readings.append(Reading(_s16(r[IR_TOTAL]) / 10.0, pos, r[IR_STATUS_LO] | (r[IR_STATUS_HI] << 16), r[IR_SEQUENCE]))
            if self.supplier is not None and self.want_dictionary and not ex.error:
                self.want_dictionary = False
                ex.supply = self._supply()
            if latch:
                if self.signer is not None:  # the auth block (holding 8..17) for this very write
                    # the last counter (48-49) and the session nonce (51-52) the tag must use
                    cr = self.client.read_input_registers(IR_AUTH_COUNTER, count=IR_NONCE + 2 - IR_AUTH_COUNTER,
                                                          device_id=self.address)
                    if not cr.isError():
                        r = cr.registers
                        n = IR_NONCE - IR_AUTH_COUNTER
                        self.signer.observe((r[0] << 16) | r[1], (r[n] << 16) | r[n + 1])
                    self.client.write_registers(HR_AUTH, self.signer.modbus_auth(self.address, HR_LATCH, [1]),
                                                device_id=self.address)
                lr = self.client.write_register(HR_LATCH, 1, device_id=self.address)
                ex.latch = ("refused:exception %s" % getattr(lr, "exception_code", "?")) if lr.isError() else "ok:"
        except Exception as exc:  # no answer, CRC error (pymodbus drops the frame), port gone
            ex.error = str(exc) or type(exc).__name__
        return ex

    def _supply(self) -> str:
        """Read the supplied-states dictionary (input registers 54..) and, if the board awaits them, write the states
        (holding 20.., the table's k int32 in one FC16); what happened, as Exchange.supply."""
        rr = self.client.read_input_registers(IR_SUPPLY_STATE, count=2 + SUPPLY_DICT_REGS * MAX_SUPPLIED, device_id=self.address)
        if rr.isError():
            self.want_dictionary = True
            return "refused:modbus exception %s" % rr
        try:
            letter, entries = modbus_dictionary(rr.registers)
        except SupplyError as exc:
            return "refused:" + str(exc)
        if letter != "A":
            return "none" if letter == "-" else "kept"
        assert self.supplier is not None
        vals = self.supplier(entries)
        if isinstance(vals, str):
            return "refused:" + vals
        regs = []
        for v in vals:
            v &= 0xFFFFFFFF
            regs += [v >> 16, v & 0xFFFF]
        w = self.client.write_registers(HR_SUPPLY, regs, device_id=self.address)
        if w.isError():
            return "refused:exception %s" % getattr(w, "exception_code", "?")
        return "set"

    def close(self) -> None:
        self.client.close()


def _named(entries: list[SupplyEntry]) -> str:
    """The supplied states as a log names them: source and time constant."""
    return ", ".join("%s, tau %g s" % (SOURCE_NAMES[e.source], e.tau_ms / 1000.0) for e in entries)


class OffsetRamp:
    """The offset the bridge commands (um).

    While the link is healthy and the ramp has caught the board's value it
    follows the board exactly (the board limits its own slew; position moves
    change the total continuously). Otherwise it moves towards its target
    (zero on a fault, the board's value on recovery or at start) by at most
    the slew limit times the elapsed time: never a step.
    """

    def __init__(self, slew_um_per_s: float) -> None:
        if not slew_um_per_s > 0:
            raise ValueError("slew limit must be > 0 um/s, got %r" % (slew_um_per_s,))
        self.slew = float(slew_um_per_s)
        self.out_um = 0.0
        self.tracking = False

    def step(self, target_um: float, dt_s: float, healthy: bool) -> float:
        if healthy and self.tracking:
            self.out_um = target_um
            return self.out_um
        room = self.slew * max(dt_s, 0.0)
        d = target_um - self.out_um
        if abs(d) <= room:
            self.out_um = target_um
            self.tracking = healthy
        else:
            self.out_um += math.copysign(room, d)
            self.tracking = False
        return self.out_um

    def restart(self) -> None:
        """Motion zeroes its external offset when the machine is switched on: start again from zero."""
        self.out_um = 0.0
        self.tracking = False


class FeedReport:
    """The axis feed a dynamic table filters (M), from the commanded axis velocity sampled once a period.

    ``update(velocity_mm_per_s)`` returns the feed to send now (mm/min, 0 when a move ends) or None: nothing changed
    that matters. A move starts at the first period the axis moves (|v| > IDLE_MM_PER_S) and ends at the first it
    stands; it sends its |v| at once (the board must know the axis moves, even if the velocity is still ramping), then
    the cruise feed once the velocity has settled (FEED_STEADY_REL) and differs from the feed sent (FEED_CHANGE_REL).
    At most one feed per call: one per bridge period."""

    def __init__(self) -> None:
        self.sent: int | None = None  # the feed last sent (mm/min); None: nothing yet (the board's feed is 0)
        self.last_mm_min: float | None = None  # |v| of the previous period, mm/min

    def update(self, velocity_mm_per_s: float) -> int | None:
        if not math.isfinite(velocity_mm_per_s):
            return None  # a NaN/inf pin: the board keeps the last feed it was told
        now = abs(velocity_mm_per_s) * 60.0
        prev, self.last_mm_min = self.last_mm_min, now
        if now <= IDLE_MM_PER_S * 60.0:
            return self._send(0) if self.sent else None
        feed = min(max(int(round(now)), FEED_RESOLUTION_MM_MIN), FEED_LIMIT_MM_MIN)
        if not self.sent:
            return self._send(feed)
        steady = prev is not None and abs(now - prev) <= max(FEED_STEADY_REL * now, FEED_RESOLUTION_MM_MIN)
        if steady and abs(feed - self.sent) > max(FEED_CHANGE_REL * self.sent, FEED_RESOLUTION_MM_MIN):
            return self._send(feed)
        return None

    def _send(self, feed: int) -> int:
        self.sent = feed
        return feed

    def again(self) -> int | None:
        """The feed last sent, to send again (the board booted or the link failed: its feed may be 0 now)."""
        return self.sent


@dataclass
class Inputs:
    position: float = 0.0          # axis.L.pos-cmd, machine units (without the external offset)
    machine_on: bool = False       # motion.motion-enabled
    homed: bool = False            # motion.is-all-homed
    eoffset_request: float = 0.0   # axis.L.eoffset-request, machine units: what motion has taken
    cold_start: bool = False       # the controller says: this start is a cold start
    latch: bool = False            # rising edge: declare a cold start now
    spindle_rpm: float = 0.0       # spindle speed (e.g. spindle.0.speed-out-abs); sent with send_spindle
    velocity: float = 0.0          # commanded axis velocity, machine units/s (e.g. joint.0.vel-cmd); its feed sent with send_feed


@dataclass
class BridgeOutputs:
    eoffset_counts: int = 0
    eoffset_scale: float = 0.0
    eoffset_enable: bool = True
    offset_um: float = 0.0          # what the bridge commands now
    board_offset_um: float = 0.0    # the board's last total
    board_status: int = 0
    link_ok: bool = False
    fault: bool = True
    fault_code: int = LINK
    tracking: bool = False
    latch_state: int = LATCH_NONE


class Bridge:
    """One axis: board link -> offset ramp -> eoffset counts; position -> board.

    ``stale_s``: no new frame for this long is a fault (the stream answers
    every period, a Modbus board's cycle counter moves every ``cycle_ms``).
    ``recover_s``: a fault ends only after this long without any fault
    reason, then the ramp goes back to the board's value at the slew limit.
    ``max_dt_s``: a ramp step covers at most this much time (two periods), so
    a bridge descheduled by a loaded host ramps more slowly, never in a step.
    """

    def __init__(self, link: StreamLink | ModbusLink, slew_um_per_s: float, units: str = "mm", stale_s: float = 1.0, recover_s: float = 1.0, cold_start: bool = False,
                 log: Callable[[str], None] | None = None, latch_retry_s: float = 1.0, latch_tries: int = 10, max_dt_s: float = 0.1, send_spindle: bool = False,
                 record: SignalRecord | None = None, record_path: str | None = None, wall: Callable[[], float] = time.time,
                 send_feed: bool = False) -> None:
        if units not in UM_PER_UNIT:
            raise ValueError("units must be one of %s, got %r" % (", ".join(UM_PER_UNIT), units))
        if send_feed and not isinstance(link, StreamLink):
            raise ValueError("the axis feed (M) has no Modbus register (docs/protocol.md): send_feed needs the stream link")
        if record is not None and not send_spindle:
            raise ValueError("a signal record (the supplied lag states) needs send_spindle: the board's own filters read the speed")
        self.link = link
        self.send_spindle = send_spindle  # off: exactly the position-only exchange of older boards
        # off: no M at all (a table reading the feed gets 0, as before); on: the velocity pin's feed, M on change
        self.feed = FeedReport() if send_feed else None
        self.noted_feed = 0.0  # the feed the signal record is given (mm/min): what the board was last sent
        self.unnetted = 0  # periods in a row the position moved while the velocity pin read idle (-1: said once)
        self.last_pos_um: float | None = None
        # the controller's record of the spindle speed, for the lag states a table asks it to supply (host/board/supplied.py):
        # noted every period, saved to record_path every RECORD_SAVE_S, and read by the link when the board asks
        self.record = record
        self.record_path = record_path
        self.wall = wall
        self.noted_rpm: float | None = None
        self.saved_at: float | None = None
        self.next_dictionary_s = 0.0
        self.last_supply = ""
        self.last_feed_answer = ""
        if record is not None:
            link.supplier = self._supply_values
        elif send_spindle:
            # no record: the dictionary is still read once per hello, so a table that asks for the states is said, not
            # left to a SETTLING that lasts the table's settle_nr (a dynamic fit's default since stop 35)
            link.supplier = self._no_record
        self.ramp = OffsetRamp(slew_um_per_s)
        self.um_per_unit = UM_PER_UNIT[units]
        self.scale = COUNT_UM / self.um_per_unit
        self.stale_s = stale_s
        self.recover_s = recover_s
        self.max_dt_s = max_dt_s
        self.force_cold = cold_start
        self.log = log or (lambda msg: None)
        self.latch_retry_s = latch_retry_s
        self.latch_tries = latch_tries
        self.out = BridgeOutputs(eoffset_scale=self.scale)
        self.counts = 0
        self.last_now = None
        self.last_new_s = None     # when the last new reading arrived
        self.last_seq = None
        self.reading = None
        self.fault_since = None
        self.clear_since = None
        self.link_error = ""
        self.was_on = False
        self.cold_decided = False
        self.latch_tries_left = 0
        self.latch_next_s = 0.0
        self.last_latch_pin = False
        self.fault_code = LINK

    # --- cold start ------------------------------------------------------------------------
    def _want_latch(self, now, inp):
        """The rule: the first time the machine is on after the bridge started, the ``cold-start`` pin
        (or --cold-start) decides; a rising edge of the ``latch`` pin latches at any time. A refusal
        because a sensor is not reading good yet is retried every latch_retry_s, latch_tries times."""
        if inp.machine_on and not self.cold_decided:
            self.cold_decided = True
            if inp.cold_start or self.force_cold:
                self.log("cold start: sending L (re-latch the reference temperatures)")
                self.latch_tries_left = self.latch_tries
                self.latch_next_s = now
        if inp.latch and not self.last_latch_pin:
            self.log("latch pin: sending L")
            self.latch_tries_left = self.latch_tries
            self.latch_next_s = now
        self.last_latch_pin = inp.latch
        if self.latch_tries_left and now >= self.latch_next_s and self.out.latch_state != LATCH_SENT:
            self.latch_tries_left -= 1
            self.latch_next_s = now + self.latch_retry_s
            self.out.latch_state = LATCH_SENT
            return True
        return False

    def _latch_reply(self, now, reply):
        if reply.startswith("ok:"):
            self.out.latch_state = LATCH_DONE
            self.latch_tries_left = 0
            self.log("L acknowledged (refs %s)" % (reply[3:] or "latched"))
        else:
            why = reply.split(":", 1)[1]
            retry = any(w in why for w in ("sensor faulty", "exception %d" % EX_DEVICE_FAILURE, "busy", "replayed"))
            if not (retry and self.latch_tries_left):
                self.latch_tries_left = 0
            self.out.latch_state = LATCH_REFUSED
            self.log("L refused: %s%s" % (why, ", retrying" if self.latch_tries_left else ""))

    # --- the supplied lag states --------------------------------------------------------------
    def _supply_values(self, entries: list[SupplyEntry]) -> list[int] | str:
        assert self.record is not None
        try:
            vals = self.record.values(entries, self.wall())
        except SupplyError as exc:
            return str(exc)
        self.log("supplied lag states: sending %s for %s" % (vals, _named(entries)))
        return vals

    def _no_record(self, entries: list[SupplyEntry]) -> str:
        """The supplier of a bridge without a signal record: sends nothing, says what the board asks for."""
        return ("the board's table asks the controller for %d lag state(s) (%s) and this bridge has no --signal-record: the "
                "board starts them at its estimate and keeps SETTLING for its table's settle_nr (docs/linuxcnc.md)"
                % (len(entries), _named(entries)))

    def _note_signals(self, now: float, inp: Inputs) -> None:
        assert self.record is not None
        w = self.wall()
        rpm = int(round(inp.spindle_rpm)) if math.isfinite(inp.spindle_rpm) else self.noted_rpm
        # a new event only past the dead band: a measured speed's jitter would otherwise fill the record (the state's
        # error from it is at most RECORD_DEADBAND_RPM)
        if rpm is not None and (self.noted_rpm is None or abs(rpm - self.noted_rpm) > RECORD_DEADBAND_RPM or (rpm == 0) != (self.noted_rpm == 0)):
            self.noted_rpm = rpm
        try:
            self.record.note(w, float(self.noted_rpm or 0), self.noted_feed)
        except SupplyError as exc:  # the wall clock stepped back (NTP): the record keeps its times, notes resume after
            self.log("signal record: %s" % exc)
        if self.record_path is not None and (self.saved_at is None or w - self.saved_at >= RECORD_SAVE_S or w < self.saved_at):
            try:
                self.record.save(self.record_path)
            except OSError as exc:
                self.log("signal record: cannot save %s: %s" % (self.record_path, exc))
            self.saved_at = w

    def _check_velocity_pin(self, v_mm_s: float, pos_um: float, dt_s: float) -> None:
        """Say once when the axis moves while the velocity pin reads idle (not netted: the board's feed stays 0)."""
        last, self.last_pos_um = self.last_pos_um, pos_um
        if self.unnetted < 0 or last is None or dt_s <= 0:
            return
        moving_mm_s = abs(pos_um - last) / 1000.0 / dt_s
        if moving_mm_s > UNNETTED_MM_PER_S and not abs(v_mm_s) > IDLE_MM_PER_S:
            self.unnetted += 1
            if self.unnetted >= UNNETTED_PERIODS:
                self.log("--feed: the velocity pin reads %g mm/s while the axis position moves at %.3g mm/s: is tcomp.velocity "
                         "netted (e.g. to joint.0.vel-cmd, examples/linuxcnc/tcomp.hal)? Until it is, the board's feed is 0"
                         % (v_mm_s, moving_mm_s))
                self.unnetted = -1
        else:
            self.unnetted = 0

    def _feed_now(self, inp: Inputs, dt_s: float) -> int | None:
        """The feed (mm/min) to send with this period's exchange, or None (send_feed off, or nothing changed)."""
        if self.feed is None:
            return None
        v_mm_s = inp.velocity * self.um_per_unit / 1000.0
        self._check_velocity_pin(v_mm_s, inp.position * self.um_per_unit, dt_s)
        feed = self.feed.update(v_mm_s)
        assert isinstance(self.link, StreamLink)  # send_feed: the constructor checked
        if self.link.feed_lost:
            # the board booted or the port reopened: its feed may be 0, whatever it was told
            self.link.feed_lost = False
            if feed is None:
                feed = self.feed.again()
        if feed is not None:
            self.noted_feed = float(feed)
        return feed

    def save_record(self) -> None:
        """Save the signal record now (at the bridge's exit)."""
        if self.record is not None and self.record_path is not None:
            self.record.save(self.record_path)

    # --- one period ---------------------------------------------------------------------------
    def step(self, now: float, inp: Inputs) -> BridgeOutputs:
        dt = 0.0 if self.last_now is None else min(now - self.last_now, self.max_dt_s)
        self.last_now = now
        if self.last_new_s is None:
            self.last_new_s = now
        pos_um = int(round(inp.position * self.um_per_unit))
        send_latch = self._want_latch(now, inp)
        feed = self._feed_now(inp, dt)
        if self.record is not None:
            self._note_signals(now, inp)
            if self.reading is not None and self.reading.status & SETTLING and now >= self.next_dictionary_s:
                # SETTLING: the board may wait for the states (a new table, a reset the link did not see): ask again
                self.link.want_dictionary = True
                self.next_dictionary_s = now + DICTIONARY_POLL_S
        extra: dict[str, int] = {}
        if self.send_spindle and math.isfinite(inp.spindle_rpm):
            # an input of dynamic tables (docs/protocol.md); the board checks its range. A NaN/inf pin
            # is not sent: the board keeps the last speed it was given
            extra["spindle_rpm"] = int(round(inp.spindle_rpm))
        if feed is not None:
            extra["feed_mm_min"] = feed
        ex = self.link.exchange(pos_um, latch=send_latch, **extra)
        if ex.feed.startswith("refused:") and ex.feed != self.last_feed_answer:  # said once per reason
            self.log("feed (M) refused: %s" % ex.feed[8:])
        if ex.feed:
            self.last_feed_answer = ex.feed
        if ex.supply and ex.supply != self.last_supply:  # said once per outcome (the SETTLING poll repeats it)
            self.last_supply = ex.supply
            if ex.supply != "none" and not ex.supply.startswith("sent:"):  # the values sent: _supply_values said them
                self.log("supplied lag states: %s" % {"set": "the board took them",
                                                      "kept": "the board set them at its table's start already"}.get(ex.supply, ex.supply))
        if ex.latch:
            self._latch_reply(now, ex.latch)
        elif send_latch and ex.error:
            self.out.latch_state = LATCH_NONE  # never reached the board: sent again at the next retry
        code = 0
        if ex.error:
            code |= LINK
            if ex.error != self.link_error:
                self.log("link: %s" % ex.error)
        self.link_error = ex.error
        if ex.malformed:
            code |= CRC
            for why in ex.malformed:
                self.log("malformed frame: %s" % why)
        for r in ex.readings:
            if r.seq != self.last_seq:
                self.last_seq = r.seq
                self.last_new_s = now
                self.reading = r
        if now - self.last_new_s > self.stale_s:
            code |= STALE
        if self.reading is not None and self.reading.status & FALLBACK:
            code |= BOARD
        if self.reading is None:
            code |= STALE
        self._track_fault(now, code)
        healthy = self.fault_code == 0
        target = self.reading.total_um if healthy and self.reading is not None else 0.0  # healthy: a reading
        ready = inp.machine_on and inp.homed
        if not inp.machine_on or (ready and not self.was_on):
            self.ramp.restart()
        self.was_on = ready
        if ready:
            self.ramp.step(target, dt, healthy)
            want = int(round(self.ramp.out_um / COUNT_UM))
            taken = int(round(inp.eoffset_request / self.scale))
            self.counts = (self.counts + want - taken + 2 ** 31) % 2 ** 32 - 2 ** 31
        o = self.out
        o.eoffset_counts = self.counts
        o.offset_um = self.ramp.out_um
        o.tracking = self.ramp.tracking and ready
        o.link_ok = not (code & (LINK | STALE))
        o.fault = not healthy
        o.fault_code = self.fault_code
        if self.reading is not None:
            o.board_offset_um = self.reading.total_um
            o.board_status = self.reading.status
        return o

    def _track_fault(self, now, code):
        if code:
            if not self.fault_code or code & ~self.fault_code:
                names = "+".join(n for b, n in FAULT_NAMES.items() if code & b)
                self.log("fault (%s): offset ramps to zero at %.4g um/s" % (names, self.ramp.slew))
            self.fault_code |= code
            self.clear_since = None
        elif self.fault_code:
            if self.clear_since is None:
                self.clear_since = now
            if now - self.clear_since >= self.recover_s:
                self.log("link healthy for %.3g s: offset ramps back to the board's value" % self.recover_s)
                self.fault_code = 0
                self.clear_since = None


def run_loop(bridge: Bridge, read_inputs: Callable[[], Inputs], write_outputs: Callable[[BridgeOutputs], None], period_s: float = 0.05, clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
             running: Callable[[], bool] = lambda: True) -> None:
    """Call ``bridge.step`` every ``period_s`` with the inputs read, write the outputs."""
    next_t = clock()
    while running():
        now = clock()
        write_outputs(bridge.step(now, read_inputs()))
        next_t += period_s
        delay = next_t - clock()
        if delay > 0:
            sleep(delay)
        else:
            next_t = clock()
