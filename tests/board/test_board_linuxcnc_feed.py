"""The LinuxCNC bridge's axis feed (--feed, M): the rules that decide when it is sent (host/board/linuxcnc/bridge.py
FeedReport), the stream line, and a dynamic table with a feed term on the real firmware (CPython, on the register-level
fakes) whose offset follows the host model's prediction of the same moves only when the bridge sends the feed."""
import os
import random
import sys

import numpy as np
import pytest

from host.board.link import command_line
from host.board.linuxcnc.bridge import (CRC, FEED_CHANGE_REL, IDLE_MM_PER_S, Bridge, FeedReport, Inputs, ModbusLink,
                                        StreamLink)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "firmware"))
from fwfakes import BoardPort  # tests/firmware, on the path above

PERIOD_S = 0.1  # one bridge period = one board cycle of the fakes (run_cycles' 100 ms)


# --- the rules ---------------------------------------------------------------------------------------------------------
def _feeds(velocities_mm_s):
    rep = FeedReport()
    return [rep.update(v) for v in velocities_mm_s]


def test_a_move_sends_its_feed_at_the_start_and_0_at_its_end():
    # 50 mm/s = 3000 mm/min, after one ramp sample at 20 mm/s
    assert _feeds([0.0, 20.0, 50.0, 50.0, 50.0, 0.0, 0.0]) == [None, 1200, None, 3000, None, 0, None]
    # either direction: the board filters the magnitude
    assert _feeds([0.0, -50.0, -50.0, 0.0]) == [None, 3000, None, 0]


def test_standing_is_at_most_the_recordings_idle_velocity():
    assert _feeds([IDLE_MM_PER_S, -IDLE_MM_PER_S, 0.0]) == [None, None, None]  # a servo's dither: no move
    assert _feeds([2 * IDLE_MM_PER_S, 0.0]) == [1, 0]  # 1.2 mm/min: a move, at least the protocol's 1 mm/min


def test_an_acceleration_ramp_sends_nothing_until_the_velocity_settles():
    ramp = [10.0 * k for k in range(1, 11)]  # 10 mm/s more every period (100 mm/s2 at 100 ms): never steady
    assert _feeds(ramp + [100.0, 100.0]) == [600] + [None] * 9 + [6000, None]


def test_a_feed_change_during_a_move_is_sent_when_it_exceeds_the_change_threshold():
    v = 50.0
    small = v * (1 + FEED_CHANGE_REL * 0.9)  # a 1.8 % change: under the threshold, kept
    big = v * (1 + FEED_CHANGE_REL * 1.5)    # a 3 % change (a feed override step): sent once it holds for a period
    assert _feeds([v, v, small, small, small]) == [3000, None, None, None, None]
    assert _feeds([v, v, big, big, big]) == [3000, None, None, 3090, None]


def test_a_nan_velocity_keeps_the_last_feed():
    assert _feeds([50.0, float("nan"), 50.0, 0.0]) == [3000, None, None, 0]


# --- the bridge and its link ---------------------------------------------------------------------------------------------
class FakePort:
    def __init__(self):
        self.tx = bytearray()
        self.fail = False

    in_waiting = 0

    def write(self, b):
        if self.fail:
            raise OSError("device disconnected")
        self.tx += b

    def read(self, n):
        return b""

    def close(self):
        pass


def _bridge(port, **kw):
    return Bridge(StreamLink(lambda: port, reopen_s=0.0), 1000.0, **kw)


def test_without_feed_no_m_is_sent_whatever_the_velocity_pin_says():
    port = FakePort()
    b = _bridge(port)
    for k, v in enumerate([0.0, 50.0, 50.0, 0.0]):
        b.step(k * PERIOD_S, Inputs(position=1.0, machine_on=True, homed=True, velocity=v))
    assert b"$TC,M," not in bytes(port.tx)


def test_the_feed_goes_before_p_in_mm_per_min_of_the_machine_units():
    port = FakePort()
    b = _bridge(port, send_feed=True, units="inch")
    b.step(0.0, Inputs(position=1.0, machine_on=True, homed=True, velocity=2.0))  # 2 in/s = 3048 mm/min
    want = command_line("M", 3048, 25400, 25400) + command_line("P", 25400)  # lo = hi = the position
    assert want in bytes(port.tx)
    port.tx.clear()
    b.step(PERIOD_S, Inputs(position=1.0, machine_on=True, homed=True, velocity=2.0))
    assert b"$TC,M," not in bytes(port.tx)  # only on change


def test_a_feed_the_link_lost_is_sent_again():
    port = FakePort()
    b = _bridge(port, send_feed=True)
    inp = Inputs(position=1.0, machine_on=True, homed=True, velocity=50.0)
    b.step(0.0, inp)
    b.link.feed_lost = False  # the hello the first exchange asked for: not the point here
    port.fail = True
    b.step(PERIOD_S, inp)  # the port fails: the board may have lost the feed (a reset)
    port.fail = False
    port.tx.clear()
    b.step(2 * PERIOD_S, inp)
    assert command_line("M", 3000, 1000, 1000) in bytes(port.tx)


def test_feed_is_refused_with_modbus_and_on_the_command_line(capsys):
    with pytest.raises(ValueError, match="no Modbus register"):
        Bridge(ModbusLink(object()), 1000.0, send_feed=True)
    from host.cli import main
    assert main(["linuxcnc", "--port", "/dev/x", "--mode", "modbus", "--feed"]) == 2
    err = capsys.readouterr().err
    assert "--feed needs --mode stream" in err and "no register for the axis feed" in err


def test_the_signal_record_gets_the_feed_sent():
    from host.board.supplied import SignalRecord
    port = FakePort()
    rec = SignalRecord()
    wall = [1000.0]
    b = _bridge(port, send_feed=True, send_spindle=True, record=rec, wall=lambda: wall[0])
    for v in (0.0, 50.0, 50.0, 0.0):
        b.step(wall[0], Inputs(position=1.0, machine_on=True, homed=True, spindle_rpm=6000.0, velocity=v))
        wall[0] += 1.0
    assert [e[2] for e in rec.events] == [0.0, 3000.0, 0.0]


# --- the real firmware --------------------------------------------------------------------------------------------------
FEED_UM_PER_M_MIN = 10.0  # the feed term: 10 um per m/min, through a 60 s lag
FEED_TAU_S = 60.0


def _feed_table():
    """An exported dynamic table whose thermal output is (almost) only a lag of the feed: T1's term is there because a
    table reads a sensor, with a gain no fake sensor's noise shows through."""
    from hil_tests.fixtures.samples import dynamic_doc, restamp
    from host.learning.documents import load_model
    from models_export import export_model
    names = ["T%d" % i for i in range(1, 12)]  # rig_app's channels
    doc = dynamic_doc(random.Random(1), "direct", dt_s=1.0, signals=["T:T1", "feed_m_min"], names=names)
    doc["thermal"]["intercept"] = 0.0
    doc["thermal"]["terms"] = [{"signal": "T:T1", "tau_s": 0.0, "coefficient": 0.001},
                               {"signal": "feed_m_min", "tau_s": FEED_TAU_S, "coefficient": FEED_UM_PER_M_MIN}]
    doc["envelope"]["feed_mm_min"] = [0, 20000]
    doc["envelope"]["position_mm"] = [0.0, 800.0]
    doc = restamp(doc)
    ex = export_model(doc)
    return ex.table, ex.report["max_error_um"], load_model(doc)


def _velocity(t):
    """mm/s: standing 5 s; +25 mm/s for 30 s (one ramp period); standing 10 s; -25 mm/s for 10 s then -40 mm/s (a
    feed override) for 10 s; standing to the end."""
    if 5.0 <= t < 35.0:
        return 12.5 if t < 5.0 + PERIOD_S else 25.0
    if 45.0 <= t < 55.0:
        return -25.0
    if 55.0 <= t < 65.0:
        return -40.0
    return 0.0


def _board_run(tmp_path, table, send_feed, seconds=100.0):
    """The bridge and the board for ``seconds``; returns [(t, board offset um)] once a second and the bridge's
    (t, position, velocity) samples."""
    from fwhelpers import rig_app, run_cycles
    tmp_path.mkdir()
    (tmp_path / "table_a.bin").write_bytes(table)
    app, board = rig_app(tmp_path, table=False, extra={"frame_ms": 0})
    port = BoardPort(board)
    bridge = Bridge(StreamLink(lambda: port), 1000.0, send_feed=send_feed)
    pos_mm = 20.0
    offsets, samples = [], []
    for k in range(int(round(seconds / PERIOD_S)) + 1):
        t = k * PERIOD_S
        v = _velocity(t)
        out = bridge.step(t, Inputs(position=pos_mm, machine_on=True, homed=True, velocity=v))
        samples.append((t, pos_mm, v))
        app.link.poll(board.clock.t)
        run_cycles(app, board, 1)
        if k % 10 == 0:
            offsets.append((t, out.board_offset_um))
        pos_mm += v * PERIOD_S
    return offsets, samples




def _host_prediction(model, times):
    """The host model's offsets at ``times`` for _velocity's moves (motion.csv intervals, one per commanded feed; the
    first move's one ramp period left out: 0.1 s at half the feed), constant temperatures."""
    from host.data.runs import Errors, Motion, Run, Temperatures
    moves = [(5.0, 35.0, 20.0, 770.0, 1500.0), (45.0, 55.0, 770.0, 520.0, 1500.0), (55.0, 65.0, 520.0, 120.0, 2400.0)]
    motion = Motion(*(np.asarray(c, dtype=float) for c in zip(*moves)))
    t_temp = np.arange(0.0, max(times) + 1.0, 1.0)
    names = list(model.sensors)
    temps = Temperatures(t_temp, names, np.full((t_temp.size, len(names)), 20.0))
    n = len(times)
    run = Run({}, temps, Errors(np.asarray(times, dtype=float), np.zeros(n), np.zeros(n)), motion)
    return np.asarray(model.predict(run))


def test_a_feed_table_on_the_real_firmware_follows_the_host_model_only_with_feed(tmp_path):
    table, export_error_um, model = _feed_table()
    with_feed, samples = _board_run(tmp_path / "feed", table, send_feed=True)
    without, _ = _board_run(tmp_path / "nofeed", table, send_feed=False)
    times = [t for t, _ in with_feed if t >= 2.0]  # after the board's start
    host = _host_prediction(model, times)
    assert samples[-1][1] == pytest.approx(120.0 - 1.25)  # the bridge's positions are those moves' (less the ramp's 1.25 mm)
    board = np.asarray([o for t, o in with_feed if t >= 2.0])
    board0 = np.asarray([o for t, o in without if t >= 2.0])
    # the board's filter steps on its own 1 s clock, the host's on the record's: up to one step of the lag apart,
    # at most (feed x gain) x (1 - e^(-1 s / tau)) = 24 um x 1.7 % plus the exporter's error and the 0.1 um offset
    # resolution
    tol = 2.4 * FEED_UM_PER_M_MIN * (1 - np.exp(-1.0 / FEED_TAU_S)) + export_error_um + 0.1
    worst = float(np.max(np.abs(board - host)))
    assert worst <= tol, (worst, tol, list(zip(times, board, host)))
    # the feed moved the model far beyond that tolerance: without the feed the board is that far off
    assert float(np.max(host)) > 10 * tol
    assert float(np.max(np.abs(board0 - host))) > 10 * tol
    assert float(np.max(np.abs(board0))) <= 0.1 + export_error_um  # feed 0 for ever: the feed term never moves
    print("feed table on the firmware: max host %.2f um, worst board - host %.3f um (tolerance %.3f um), worst without the "
          "feed %.2f um" % (np.max(host), worst, tol, np.max(np.abs(board0 - host))))


def test_a_table_without_a_feed_input_refuses_m_and_the_bridge_says_so_once(tmp_path):
    """A static table (neither screw nor dynamic) answers M with E,5: the bridge logs it once, as M's answer."""
    from fwhelpers import rig_app, run_cycles
    app, board = rig_app(tmp_path, extra={"frame_ms": 0})
    logs = []
    bridge = Bridge(StreamLink(lambda: BoardPort(board)), 1000.0, send_feed=True, log=logs.append)
    for k, v in enumerate([0.0, 25.0, 25.0, 0.0, 0.0, 25.0, 25.0, 0.0]):
        out = bridge.step(k * PERIOD_S, Inputs(position=20.0 + k * 2.5, machine_on=True, homed=True, velocity=v))
        app.link.poll(board.clock.t)
        run_cycles(app, board, 1)
    refused = [m for m in logs if m.startswith("feed (M) refused")]
    assert refused == ["feed (M) refused: state,no screw or dynamic table"], logs
    assert not out.fault_code & CRC  # an answer, not a malformed frame


def test_a_feed_above_the_boards_max_speed_is_refused_and_said(tmp_path):
    """The board refuses a feed above its max_speed_mm_min (E,4,range): the bridge logs it as M's answer, once."""
    from fwhelpers import rig_app, run_cycles
    table, _, _ = _feed_table()
    tmp_path.joinpath("table_a.bin").write_bytes(table)
    app, board = rig_app(tmp_path, table=False, extra={"frame_ms": 0, "max_speed_mm_min": 2000})
    logs = []
    bridge = Bridge(StreamLink(lambda: BoardPort(board)), 1000.0, send_feed=True, log=logs.append)
    for k, v in enumerate([0.0, 25.0, 50.0, 50.0, 50.0, 50.0]):  # 1500 mm/min taken, 3000 refused
        bridge.step(k * PERIOD_S, Inputs(position=20.0, machine_on=True, homed=True, velocity=v))
        app.link.poll(board.clock.t)
        run_cycles(app, board, 1)
    assert app.feed == 1500
    assert [m for m in logs if m.startswith("feed (M) refused")] == ["feed (M) refused: range"], logs



def test_a_velocity_pin_not_netted_is_said_once():
    """--feed with tcomp.velocity left unconnected reads 0 while the axis moves: the board's feed would stay 0 silently.
    The bridge says so once, after the position has moved faster than 1 mm/s for 10 periods with the pin idle; a netted
    pin, or a standing axis, says nothing."""
    def run(velocity, speed_mm_s, periods=30):
        logs = []
        b = _bridge(FakePort(), send_feed=True, log=logs.append)
        for k in range(periods):
            b.step(k * PERIOD_S, Inputs(position=1.0 + speed_mm_s * k * PERIOD_S, machine_on=True, homed=True,
                                        velocity=velocity))
        return [m for m in logs if "velocity pin" in m]

    said = run(0.0, 50.0)
    assert len(said) == 1 and "tcomp.velocity" in said[0] and "50 mm/s" in said[0], said
    assert run(0.0, 50.0, periods=10) == []  # nine moving periods after the first: not yet
    assert run(50.0, 50.0) == []  # netted
    assert run(0.0, 0.0) == []  # standing
    assert run(0.0, 0.5) == []  # slower than the threshold (a creep, a servo's dither)
