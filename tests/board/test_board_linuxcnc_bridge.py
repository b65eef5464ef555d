"""The LinuxCNC bridge's logic without HAL (host/board/linuxcnc/bridge.py): link decoding, fault rules, ramp,
counts loop against a motion model, cold-start rule. The same bridge in a real LinuxCNC:
hil_tests/test_hil_linuxcnc.py."""
import pytest

from host.board.link import FALLBACK, command_line, crc16
from host.cli import main
from host.board.linuxcnc.bridge import (BOARD, CRC, LATCH_DONE, LATCH_NONE, LATCH_REFUSED, LINK, STALE, Bridge, Exchange,
                                  Inputs, OffsetRamp, Reading, StreamLink)

SLEW = 10.0
PERIOD = 0.05


class Motion:
    """LinuxCNC motion's external offset as the bridge sees it: count deltas times scale are taken only
    while on and homed (dropped otherwise); switching the machine on zeroes the request."""

    def __init__(self, scale):
        self.scale = scale
        self.old = 0
        self.request = 0.0
        self.on = True

    def servo(self, counts, homed=True):
        delta, self.old = counts - self.old, counts
        if self.on and homed:
            self.request += delta * self.scale

    def switch(self, on):
        if on and not self.on:
            self.request = 0.0
        self.on = on


class ScriptLink:
    """Answers with ``total`` (um) and a moving sequence number; ``mode`` breaks it."""

    def __init__(self, total=25.0):
        self.total = total
        self.status = 0
        self.mode = "ok"
        self.seq = 0
        self.positions = []
        self.latches = 0
        self.latch_reply = "ok:L"

    def exchange(self, pos_um, latch=False):
        self.positions.append(pos_um)
        ex = Exchange()
        if self.mode == "down":
            ex.error = "no answer"
            return ex
        if latch:
            self.latches += 1
            ex.latch = self.latch_reply
        if self.mode != "stale":
            self.seq = (self.seq + 1) % 65536
        if self.mode == "crc":
            ex.malformed.append("CRC mismatch")
        else:
            ex.readings.append(Reading(self.total, pos_um, self.status, self.seq))
        return ex


class Run:
    def __init__(self, link=None, **kw):
        self.link = link or ScriptLink()
        self.bridge = Bridge(self.link, SLEW, **kw)
        self.motion = Motion(self.bridge.scale)
        self.t = 0.0
        self.inp = Inputs(position=250.0, machine_on=True, homed=True)

    def step(self, n=1):
        out = []
        for _ in range(n):
            self.inp.eoffset_request = self.motion.request
            self.inp.machine_on = self.motion.on
            o = self.bridge.step(self.t, self.inp)
            self.motion.servo(o.eoffset_counts)
            out.append((self.t, self.motion.request * 1000.0, o.fault_code))
            self.t += PERIOD
        return out


def _max_rate(rows):
    return max(abs(b[1] - a[1]) / (b[0] - a[0]) for a, b in zip(rows, rows[1:]))


def test_ramp_tracks_when_healthy_and_moves_at_the_slew_limit_otherwise():
    r = OffsetRamp(SLEW)
    assert r.step(30.0, 0.1, True) == pytest.approx(1.0) and not r.tracking
    for _ in range(40):
        r.step(30.0, 0.1, True)
    assert r.out_um == 30.0 and r.tracking
    assert r.step(31.7, 0.1, True) == 31.7  # tracking: the board's own value (its slew, position moves)
    assert r.step(0.0, 0.1, False) == pytest.approx(30.7) and not r.tracking
    r.restart()
    assert r.out_um == 0.0 and not r.tracking
    with pytest.raises(ValueError):
        OffsetRamp(0)


def test_motion_request_equals_board_offset_after_the_start_ramp():
    run = Run()
    rows = run.step(80)
    assert rows[-1][1] == pytest.approx(25.0, abs=1e-9)
    assert _max_rate(rows) <= SLEW + 1e-9  # from zero at start: a ramp, not a step
    assert run.link.positions[-1] == 250000
    run.link.total = -12.3
    run.step(1)
    run.step(1)
    assert run.motion.request * 1000 == pytest.approx(-12.3)  # tracking: follows at once


@pytest.mark.parametrize("mode,code", [("crc", CRC), ("stale", STALE), ("down", LINK)])
def test_link_faults_ramp_to_zero_at_slew_then_back(mode, code):
    run = Run()
    run.step(80)
    run.link.mode = mode
    rows = run.step(70)
    assert rows[-1][1] == pytest.approx(0.0, abs=1e-9) and rows[-1][2] & code
    assert _max_rate(rows) <= SLEW + 1e-9
    if mode == "stale":  # detected after stale_s (1 s): held until then
        assert rows[int(0.9 / PERIOD)][1] == pytest.approx(25.0)
    run.link.mode = "ok"
    rows = run.step(20)
    assert rows[-1][1] == pytest.approx(0.0, abs=1e-9)  # recover_s of good answers first
    rows = run.step(60)
    assert rows[-1][1] == pytest.approx(25.0) and rows[-1][2] == 0 and _max_rate(rows) <= SLEW + 1e-9


def test_board_fallback_ramps_to_zero():
    run = Run()
    run.step(80)
    run.link.status = FALLBACK
    rows = run.step(60)
    assert rows[-1][1] == pytest.approx(0.0, abs=1e-9) and rows[-1][2] & BOARD and _max_rate(rows) <= SLEW + 1e-9


def test_machine_off_zeroes_the_bridge_and_motion_restarts_from_zero():
    run = Run()
    run.step(80)
    run.motion.switch(False)
    run.link.mode = "down"
    run.step(1)
    assert run.bridge.out.offset_um == 0.0
    counts = run.bridge.out.eoffset_counts
    run.step(40)
    assert run.bridge.out.eoffset_counts == counts  # nothing written while motion drops it
    run.link.mode = "ok"
    run.motion.switch(True)
    rows = run.step(80)
    assert rows[0][1] == 0.0 and rows[-1][1] == pytest.approx(25.0) and _max_rate(rows) <= SLEW + 1e-9


def test_dropped_counts_are_written_again():
    run = Run()
    run.step(2)
    run.motion.old += 7  # as if motion saw a change while it could not take it
    run.step(80)
    assert run.motion.request * 1000 == pytest.approx(25.0)


def test_a_stalled_bridge_ramps_slower_never_in_a_step():
    run = Run()
    run.step(80)
    run.link.mode = "down"
    run.step(30)
    before = run.motion.request
    run.t += 2.0  # descheduled for 2 s
    run.step(1)
    assert abs(run.motion.request - before) * 1000 <= SLEW * 0.1 + 1e-9


def test_cold_start_rule():
    run = Run(cold_start=False)
    run.motion.on = False
    run.step(5)
    run.motion.switch(True)
    run.step(5)
    assert run.link.latches == 0 and run.bridge.out.latch_state == LATCH_NONE
    run.inp.latch = True  # rising edge of the latch pin: L now
    run.step(3)
    assert run.link.latches == 1 and run.bridge.out.latch_state == LATCH_DONE

    cold = Run()
    cold.inp.cold_start = True
    cold.motion.on = False
    cold.step(5)
    assert cold.link.latches == 0  # decided at the first machine-on, when the nets are up
    cold.motion.switch(True)
    cold.step(5)
    assert cold.link.latches == 1

    faulty = Run()
    faulty.inp.cold_start = True
    faulty.link.latch_reply = "refused:sensor faulty"
    faulty.step(int(3.5 / PERIOD))
    assert faulty.link.latches == 4 and faulty.bridge.out.latch_state == LATCH_REFUSED  # retried every 1 s
    fixed = Run()
    fixed.inp.cold_start = True
    fixed.link.latch_reply = "refused:fixed references"
    fixed.step(int(3.5 / PERIOD))
    assert fixed.link.latches == 1


class FakePort:
    def __init__(self, data=b""):
        self.rx = bytearray(data)
        self.tx = bytearray()
        self.fail = False

    @property
    def in_waiting(self):
        return len(self.rx)

    def write(self, b):
        if self.fail:
            raise OSError("device disconnected")
        self.tx += b

    def read(self, n):
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def close(self):
        pass


def test_stream_link_sends_p_and_q_and_decodes_answers():
    body = b"TC,7,00100000,Q,1000,250000,-12.3,1.0,2.00"
    good = b"$" + body + b"*%04X\r\n" % crc16(body)
    bad = b"$" + body + b"*%04X\r\n" % (crc16(body) ^ 1)
    ack = b"$TC,8,00000000,A,L,L"
    ack = ack + b"*%04X\r\n" % crc16(ack[1:])
    ports = [FakePort(good + bad + ack)]
    link = StreamLink(lambda: ports[-1], reopen_s=0.0)
    ex = link.exchange(250000, latch=True)
    assert bytes(ports[0].tx) == command_line("V") + command_line("P", 250000) + command_line("Q", 250000) + command_line("L")
    assert ex.readings == [Reading(-12.3, 250000, FALLBACK, 7)]
    assert len(ex.malformed) == 1 and "CRC" in ex.malformed[0]
    assert ex.latch == "ok:L"
    ports[0].fail = True
    ex = link.exchange(250000)
    assert ex.error == "device disconnected"
    ports.append(FakePort())
    ex = link.exchange(250000)  # reopened, and the hello asked for again
    assert not ex.error and bytes(ports[1].tx).startswith(command_line("V"))
    ex = link.exchange(250000)
    assert not bytes(ports[1].tx).count(command_line("V")) > 1


def test_stream_link_signs_l_with_the_board_counter():
    from host.board.linkauth import LinkSigner
    hello = b"TC,0,00000000,H,2,0.1.0,A,0ABCAE5F,0001020304050607,poly_slope,X,3,S,41,0A0B0C0D"
    port = FakePort(b"$" + hello + b"*%04X\r\n" % crc16(hello))
    signer = LinkSigner(b"k" * 32)
    link = StreamLink(lambda: port, signer=signer)
    link.exchange(0)
    assert signer.counter == 41 and signer.nonce == bytes.fromhex("0A0B0C0D")
    # L waits for a fresh hello (the session nonce moves on): V goes out, L is signed when the hello comes
    port.tx.clear()
    link.exchange(0, latch=True)
    assert bytes(port.tx).startswith(b"$TC,V*") and b"$TC,L," not in bytes(port.tx)
    hello = b"TC,1,00000000,H,2,0.1.0,A,0ABCAE5F,0001020304050607,poly_slope,X,3,S,41,0A0B0C0E"
    refused = b"TC,3,00000000,E,8,auth,replayed counter"
    port.rx += b"$" + hello + b"*%04X\r\n" % crc16(hello) + b"$" + refused + b"*%04X\r\n" % crc16(refused)
    ex = link.exchange(0)
    want = LinkSigner(b"k" * 32, 41, bytes.fromhex("0A0B0C0E")).stream_line("L")
    assert want in bytes(port.tx) and ex.latch == "refused:auth,replayed counter"
    assert link.want_hello


def test_cli_errors_are_one_line(capsys):
    assert main(["linuxcnc", "--port", "/dev/x", "--period-ms", "0"]) == 2
    assert main(["linuxcnc", "--port", "/dev/x", "--slew-um-per-s", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["tcomp linuxcnc: error: --period-ms 0: must be 1..1000",
                   "tcomp linuxcnc: error: --slew-um-per-s 0: must be in (0, 10000] (the firmware's range)"]


def test_extrapolating_and_clamped_are_not_faults():
    """EXTRAPOLATING (a temperature outside the training range, inside the certified envelope) and
    CLAMPED are informational: the bridge keeps applying the board's offset; only FALLBACK ramps to zero."""
    from firmware.wire import CLAMPED, EXTRAPOLATING
    run = Run()
    run.step(80)
    run.link.status = EXTRAPOLATING | CLAMPED
    rows = run.step(60)
    assert rows[-1][1] == pytest.approx(25.0) and rows[-1][2] == 0
    run.link.status = EXTRAPOLATING | FALLBACK
    rows = run.step(60)
    assert rows[-1][1] == pytest.approx(0.0, abs=1e-9) and rows[-1][2] & BOARD


class FakeModbus:
    """pymodbus client's calls the bridge makes, recorded; answers like a healthy board."""

    class _Ok:
        def __init__(self, registers=()):
            self.registers = list(registers)

        def isError(self):
            return False

    def __init__(self):
        self.writes = []

    def write_registers(self, start, values, device_id):
        self.writes.append((start, list(values)))
        return self._Ok()

    def read_input_registers(self, start, count, device_id):
        return self._Ok([0, 0, 1, 123, 0, 0, 0, 250, 0, 0][:count])


def test_spindle_speed_is_sent_only_when_asked_and_only_when_finite():
    # off (the default): the position-only exchange, whatever the pin says
    port = FakePort()
    off = Run(StreamLink(lambda: port, reopen_s=0.0))
    off.inp.spindle_rpm = 8000.0
    off.step()
    assert command_line("P", 250000) in bytes(port.tx) and b"$TC,P,250000," not in bytes(port.tx)
    # on: P,<pos>,<rpm> in stream mode ...
    port = FakePort()
    on = Run(StreamLink(lambda: port, reopen_s=0.0), send_spindle=True)
    on.inp.spindle_rpm = 7999.6
    on.step()
    assert command_line("P", 250000, 8000) in bytes(port.tx)
    # ... a NaN pin is not sent (the board keeps the last speed), and the bridge keeps running
    port.tx.clear()
    on.inp.spindle_rpm = float("nan")
    on.step()
    assert command_line("P", 250000) in bytes(port.tx) and b"$TC,P,250000," not in bytes(port.tx)
    # ... and holding registers 18-19 (int32, high word first, written whole) in Modbus mode
    from host.board.linuxcnc.bridge import ModbusLink
    client = FakeModbus()
    mb = Run(ModbusLink(client), send_spindle=True)
    mb.inp.spindle_rpm = 70000.0
    mb.step()
    assert (3, [0x0003, 0xD090]) in client.writes and (18, [0x0001, 0x1170]) in client.writes
    client = FakeModbus()
    Run(ModbusLink(client)).step()
    assert [w for w in client.writes if w[0] == 18] == []


def test_linuxcnc_cli_has_the_spindle_option():
    from host.cli.verbs import linuxcnc
    import argparse
    p = argparse.ArgumentParser()
    linuxcnc.add_arguments(p)
    assert p.parse_args(["--port", "x", "--spindle"]).spindle and not p.parse_args(["--port", "x"]).spindle


def test_settling_is_not_a_fault_and_reaches_the_board_status_pin():
    """SETTLING (a dynamic table's observer estimated its states less than settle_s ago, issue 21) informs: the bridge
    keeps applying the board's offset and passes the bit on in board-status; `tcomp monitor` names it."""
    from firmware.wire import SETTLING
    from host.board.link import STATUS_BITS
    run = Run()
    run.step(80)
    run.link.status = SETTLING
    rows = run.step(60)
    assert rows[-1][1] == pytest.approx(25.0) and rows[-1][2] == 0
    assert run.bridge.step(run.t, run.inp).board_status & SETTLING
    assert STATUS_BITS[SETTLING] == "SETTLING"
