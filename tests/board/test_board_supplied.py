"""The controller's side of the supplied lag states (issue 21, table format 7): host/board/supplied.py's signal record
against the closed form of a first-order lag, across the controller's restarts, and the LinuxCNC bridge handing the
states to the real firmware (CPython, on the register-level fakes), including after the board's reset."""
import json
import math
import os
import sys

import pytest

from host.board.supplied import (SOURCE_FEED, SOURCE_SPINDLE, SOURCE_SPINDLE_SQUARED, SignalRecord, SupplyEntry, SupplyError,
                                 parse_dictionary)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "firmware"))
from fwfakes import BoardPort  # tests/firmware, on the path above

TAU = 1800.0
SPIN = SupplyEntry(SOURCE_SPINDLE, int(TAU * 1000), 0)
SQUARE = SupplyEntry(SOURCE_SPINDLE_SQUARED, int(TAU * 1000), -4)
FEED = SupplyEntry(SOURCE_FEED, 600000, 3)


def test_lag_of_steps_is_the_closed_form():
    rec = SignalRecord()
    rec.note(0.0, 0.0)  # at rest: the lag starts in equilibrium with 0
    rec.note(100.0, 6000.0, 2000.0)
    rec.note(100.0 + TAU, 6000.0, 2000.0)
    rec.note(100.0 + 2 * TAU, -3000.0, 0.0)  # M4: the heat follows the magnitude
    t = 100.0 + 2 * TAU + 600.0
    # 6000 from 100 s for 2 tau, then 3000 for 600 s: y = 3000 + (6000 (1 - e^-2) - 3000) e^(-600/tau)
    want = 3000.0 + (6000.0 * (1 - math.exp(-2.0)) - 3000.0) * math.exp(-600.0 / TAU)
    assert rec.lag(SPIN, t) == pytest.approx(want, rel=1e-12)
    want_sq = 3000.0 ** 2 + (6000.0 ** 2 * (1 - math.exp(-2.0)) - 3000.0 ** 2) * math.exp(-600.0 / TAU)
    assert rec.lag(SQUARE, t) == pytest.approx(want_sq, rel=1e-12)
    want_feed = 2000.0 * (1 - math.exp(-2 * TAU / 600.0)) * math.exp(-600.0 / 600.0)
    assert rec.lag(FEED, t) == pytest.approx(want_feed, rel=1e-12)
    # the board's state units: round(lag x 2**scale)
    assert rec.values([SPIN, SQUARE, FEED], t) == [round(want), round(want_sq / 16), round(want_feed * 8)]


def test_record_starts_in_equilibrium_and_forgets_beyond_its_horizon():
    rec = SignalRecord(horizon_s=3600.0)
    rec.note(0.0, 5000.0)
    assert rec.lag(SPIN, 10.0) == 5000.0  # a record that starts running: in equilibrium with its first input
    rec.note(1000.0, 0.0)
    rec.note(10000.0, 0.0)
    assert [e[0] for e in rec.events] == [1000.0]  # the 5000 rpm event is older than the horizon's start
    assert rec.lag(SPIN, 10000.0) == 0.0  # what the horizon forgets: 5000 x e^(-9000/1800), here 34 rpm


def test_bad_notes_and_asks_are_refused():
    rec = SignalRecord()
    with pytest.raises(SupplyError, match="empty"):
        rec.lag(SPIN, 0.0)
    rec.note(10.0, 100.0)
    with pytest.raises(SupplyError, match="before the record's last"):
        rec.note(5.0, 100.0)
    with pytest.raises(SupplyError, match="not finite"):
        rec.note(11.0, float("nan"))
    with pytest.raises(SupplyError, match="horizon"):
        SignalRecord(horizon_s=0)


def test_record_survives_the_controllers_restart_with_the_spindle_stopped(tmp_path):
    path = str(tmp_path / "signals.json")
    rec = SignalRecord()
    rec.note(0.0, 8000.0)
    rec.note(3 * TAU, 8000.0)
    rec.save(path)
    assert not [p for p in os.listdir(tmp_path) if p != "signals.json"]  # the temporary file was renamed
    back = SignalRecord.load(path, now=3 * TAU + 900.0)
    # 8000 rpm until the save, then stopped while the controller was off
    assert back.lag(SPIN, 3 * TAU + 900.0) == pytest.approx(8000.0 * math.exp(-900.0 / TAU), rel=1e-12)
    assert SignalRecord.load(str(tmp_path / "none.json"), now=5.0).events == []  # a first start
    with pytest.raises(SupplyError, match="after now"):
        SignalRecord.load(path, now=10.0)
    (tmp_path / "bad.json").write_text(json.dumps({"format": "x"}))
    with pytest.raises(SupplyError, match="bad.json: not a tcomp signal record"):
        SignalRecord.load(str(tmp_path / "bad.json"), now=1e9)
    (tmp_path / "nan.json").write_text('{"format": "tcomp-signal-record-1", "events": [[1, NaN, 0]], "last_t": 5}')
    with pytest.raises(SupplyError, match="nan.json: the signal record holds a value that is not finite"):
        SignalRecord.load(str(tmp_path / "nan.json"), now=1e9)
    (tmp_path / "other.json").write_text("[1, 2]")
    with pytest.raises(SupplyError, match="other.json: not a tcomp signal record"):
        SignalRecord.load(str(tmp_path / "other.json"), now=1e9)
    (tmp_path / "torn.json").write_text('{"format": "tcomp-signal-record-1", "ev')
    with pytest.raises(SupplyError, match="torn.json: unreadable signal record"):
        SignalRecord.load(str(tmp_path / "torn.json"), now=1e9)


def test_dictionary_answers_are_parsed_or_refused():
    assert parse_dictionary(["Y", "A", "2", "-1", "600000", "14", "-2", "1800000", "0"]) == (
        "A", [SupplyEntry(-1, 600000, 14), SupplyEntry(-2, 1800000, 0)])
    assert parse_dictionary(["Y", "-", "0"]) == ("-", [])
    for bad, msg in ((["Y", "A", "2", "-1", "600000", "14"], "2 states need 6 fields"), (["Y", "Q", "0"], "not a supplied"),
                     (["Y", "A", "1", "-7", "600000", "0"], "source -7"), (["Y", "A", "1", "-1", "x", "0"], "not an integer")):
        with pytest.raises(SupplyError, match=msg):
            parse_dictionary(bad)


# --- the bridge and the real firmware ---------------------------------------------------------------------------------


def _period(app, board, bridge, inp, now, cycles=1):
    out = bridge.step(now, inp)
    from fwhelpers import run_cycles
    app.link.poll(board.clock.t)
    run_cycles(app, board, cycles)
    return out


def test_bridge_supplies_the_states_at_the_boards_start_and_after_its_reset(tmp_path):
    from fwhelpers import rig_app
    from firmware.app import App
    from firmware.wire import SUPPLY_SET
    from host.board.linuxcnc.bridge import Bridge, Inputs, StreamLink
    app, board = rig_app(tmp_path, kind="dynamic_supplied", extra={"frame_ms": 0})
    wall = [1.0e6]
    rec = SignalRecord()
    rec.note(wall[0] - 7200.0, 0.0)
    rec.note(wall[0] - 5400.0, 9000.0)  # 90 min at 9000 rpm before the bridge starts
    logs = []
    port = BoardPort(board)
    bridge = Bridge(StreamLink(lambda: port), 1000.0, send_spindle=True, record=rec, record_path=str(tmp_path / "signals.json"),
                    wall=lambda: wall[0], log=logs.append)
    inp = Inputs(position=0.0, machine_on=True, homed=True, spindle_rpm=9000.0)
    t = app.table
    entries = [SupplyEntry(t.src[j], t.tauc[j], app.ev.supply_scale(j)) for j in range(t.nf) if t.tauc[j]]
    sent = None
    for k in range(6):
        _period(app, board, bridge, inp, float(k), cycles=5)
        if sent is None and any("sending" in m for m in logs):
            sent = rec.values(entries, wall[0])
        wall[0] += 0.5
    assert app.supply == SUPPLY_SET, logs
    assert [app.ev.Y[j] for j in range(t.nf) if t.tauc[j]][:2] == pytest.approx(sent[:2], rel=1e-3)
    assert sent[0] > 0.9 * 9000 * 2 ** entries[0].scale * (1 - math.exp(-5400.0 / (entries[0].tau_ms / 1000.0)))
    assert any("the board took them" in m for m in logs)
    assert (tmp_path / "signals.json").exists()  # saved at the first period
    # the board resets (same flash): it boots awaiting the states; the bridge hears its hello and sends them again
    logs.clear()
    app = App(board)
    for k in range(6, 12):
        _period(app, board, bridge, inp, float(k), cycles=5)
        wall[0] += 0.5
    assert app.supply == SUPPLY_SET and any("the board took them" in m for m in logs), logs
    bridge.save_record()
    back = SignalRecord.load(str(tmp_path / "signals.json"), now=wall[0])
    # the record up to its last note, then the spindle stopped for the 0.5 s to the reload
    tau = entries[0].tau_ms / 1000.0
    want = rec.lag(entries[0], rec.last_t) * math.exp(-(wall[0] - rec.last_t) / tau)
    assert back.lag(entries[0], wall[0]) == pytest.approx(want, rel=1e-12)


class BoardModbus:
    """The three pymodbus client calls the bridge's ModbusLink makes, as RTU requests to the firmware's Modbus slave
    on the fake board (the firmware answers them; this only frames and unframes)."""

    class Reply:
        def __init__(self, raw):
            self.raw = raw
            self.exception_code = raw[2] if raw[1] & 0x80 else None
            self.registers = [int.from_bytes(raw[3 + 2 * i:5 + 2 * i], "big") for i in range(raw[2] // 2)] if not raw[1] & 0x80 else []

        def isError(self):
            return self.exception_code is not None

    def __init__(self, app, board):
        self.app, self.board = app, board

    def _ask(self, body):
        from firmware.crc16 import crc16_modbus
        c = crc16_modbus(body)
        self.board.serial.feed(body + bytes([c & 0xFF, c >> 8]))
        self.board.clock.t += 10
        self.app.link.poll(self.board.clock.t)
        return self.Reply(self.board.serial.take())

    def read_input_registers(self, start, count, device_id):
        return self._ask(bytes([device_id, 4, start >> 8, start & 0xFF, 0, count]))

    def read_holding_registers(self, start, count, device_id):
        return self._ask(bytes([device_id, 3, start >> 8, start & 0xFF, 0, count]))

    def write_registers(self, start, values, device_id):
        body = b"".join(v.to_bytes(2, "big") for v in values)
        return self._ask(bytes([device_id, 16, start >> 8, start & 0xFF, 0, len(values), 2 * len(values)]) + body)

    def write_register(self, r, v, device_id):
        return self._ask(bytes([device_id, 6, r >> 8, r & 0xFF, v >> 8, v & 0xFF]))


def test_bridge_supplies_the_states_over_modbus(tmp_path):
    from fwhelpers import rig_app, run_cycles
    from firmware.wire import SUPPLY_SET
    from host.board.linuxcnc.bridge import Bridge, Inputs, ModbusLink
    app, board = rig_app(tmp_path, kind="dynamic_supplied", serial_mode="modbus")
    wall = [5.0e5]
    rec = SignalRecord()
    rec.note(wall[0] - 3600.0, 4000.0)
    logs = []
    bridge = Bridge(ModbusLink(BoardModbus(app, board)), 1000.0, send_spindle=True, record=rec, wall=lambda: wall[0],
                    log=logs.append)
    inp = Inputs(position=0.0, machine_on=True, homed=True, spindle_rpm=4000.0)
    for k in range(3):
        bridge.step(float(k), inp)
        run_cycles(app, board, 5)
        wall[0] += 0.5
    t = app.table
    assert app.supply == SUPPLY_SET and any("the board took them" in m for m in logs), logs
    # the record: 4000 rpm for an hour, a lag in equilibrium with it; the board's states hold that (and stay there: its
    # own filters see 4000 rpm too): 4000 rpm, 4000**2 rpm**2 in state units
    got = [app.ev.Y[j] / 2.0 ** app.ev.supply_scale(j) for j in range(t.nf) if t.tauc[j]]
    assert got[:2] == pytest.approx([4000.0, 4000.0 ** 2], rel=1e-4)


@pytest.mark.parametrize("mode", ["stream", "modbus"])
def test_a_bridge_without_a_record_says_what_the_board_awaits_and_sends_nothing(tmp_path, mode):
    """--spindle without --signal-record on a table whose spindle lag states the controller supplies (a dynamic fit's
    default since stop 35): the bridge reads the board's dictionary once, says in one line which states the board asks
    for and what happens without them, and writes no states (the board keeps awaiting them, then starts them at its
    estimate). A bridge without --spindle does not ask at all (its exchanges stay those of older boards)."""
    from fwhelpers import rig_app, run_cycles
    from firmware.wire import SUPPLY_AWAITED
    from host.board.linuxcnc.bridge import Bridge, Inputs, ModbusLink, StreamLink
    for spindle in (True, False):
        folder = tmp_path / ("%s%d" % (mode, spindle))
        folder.mkdir()
        app, board = rig_app(folder, kind="dynamic_supplied",
                             **({"serial_mode": "modbus"} if mode == "modbus" else {"extra": {"frame_ms": 0}}))
        logs = []
        if mode == "stream":
            port = BoardPort(board)
            link = StreamLink(lambda: port)
        else:
            link = ModbusLink(BoardModbus(app, board))
        bridge = Bridge(link, 1000.0, send_spindle=spindle, log=logs.append)
        inp = Inputs(position=0.0, machine_on=True, homed=True, spindle_rpm=3000.0)
        for k in range(6):
            if mode == "stream":
                _period(app, board, bridge, inp, float(k), cycles=5)
            else:
                bridge.step(float(k), inp)
                run_cycles(app, board, 5)
        said = [m for m in logs if "no --signal-record" in m]
        assert app.supply == SUPPLY_AWAITED, logs  # nothing was written
        if not spindle:
            assert said == [], logs
            continue
        assert len(said) == 1, logs  # once, though the exchange goes on
        t = app.table
        named = ["%s, tau %g s" % ({-1: "spindle rpm", -2: "spindle rpm squared", -3: "feed mm/min"}[t.src[j]], t.tauc[j] / 1000.0)
                 for j in range(t.nf) if t.tauc[j]]
        assert "asks the controller for %d lag state(s) (%s)" % (len(named), ", ".join(named)) in said[0], said
        assert "keeps SETTLING for its table's settle_nr" in said[0]
