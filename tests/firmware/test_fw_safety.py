"""Output limiter and the app's hold / fallback / recovery behaviour."""
import pytest

from fwhelpers import rig_app, run_cycles, frames
from firmware import wire as st
from firmware.safety import Limiter


def test_slew_limit_is_exact_over_time():
    lim = Limiter(5, 300, 500000)
    outs = []
    for _ in range(100):  # 10 s in 100 ms steps towards +100 um
        fl = lim.update(10000, 0, 10000, 10000, True, 100)
        outs.append(lim.ref)
        assert fl & st.RATE_LIMITED
    assert outs[9] == 500 and outs[-1] == 5000  # 5 um/s in 0.01 um
    assert all(b - a == 50 for a, b in zip([0] + outs, outs))
    # odd dt: the remainder carries, the long-run rate stays exact
    lim = Limiter(3, 300, 500000)
    for _ in range(1000):
        lim.update(-100000, 0, -100000, -100000, True, 7)
    assert lim.ref == -2100


def test_magnitude_limit_and_flag():
    lim = Limiter(1000, 50, 500000)
    for _ in range(20):
        fl = lim.update(9000, 0, 9000, 9000, True, 100)
    assert lim.ref == 5000 and lim.total == 5000
    assert fl & st.MAG_LIMITED and not fl & st.RATE_LIMITED


def test_slope_limits_scale_with_span():
    lim = Limiter(5, 300, 500000)  # 500 mm span: 5 um/s over 0.5 m = 10 um/m per s
    for _ in range(10):
        lim.update(0, 10 ** 6, 0, 0, True, 100)
    assert lim.slope == 1000  # 10.00 um/m after 1 s
    for _ in range(1000):
        fl = lim.update(0, 10 ** 6, 0, 0, True, 100)
    assert lim.slope == lim.max_s == 60000  # 300 um over 0.5 m = 600 um/m
    assert fl & st.MAG_LIMITED


def test_position_changes_pass_through_temperature_steps_ramp():
    lim = Limiter(5, 300, 500000)
    lim.total = 1000
    # the axis moves: the model is 1000 at the old position and 7777 at the new one
    lim.update(0, 0, 7777, 1000, True, 100)
    assert lim.total == 7777
    # standing axis, the model jumps by +20 um: the output ramps at 0.5 um per 100 ms
    lim.update(0, 0, 9777, 9777, True, 100)
    assert lim.total == 7827
    # both at once: the ramp at the old position, then the model's change with position
    lim.update(0, 0, 12000, 9777, True, 100)
    assert lim.total == 7877 + (12000 - 9777)


def test_total_never_faster_than_slew_at_a_standing_axis():
    import random
    rnd = random.Random(5)
    lim = Limiter(5, 300, 500000)
    prev = lim.total
    for _ in range(3000):
        raw = rnd.choice([0, 29000, -31000, rnd.randint(-40000, 40000)])
        lim.update(rnd.randint(-40000, 40000), rnd.randint(-99999, 99999), raw, raw,
                   rnd.random() < 0.8, 100)
        assert abs(lim.total - prev) <= 50 and abs(lim.total) <= 30000
        prev = lim.total


def test_pair_moves_as_one_affine_function():
    lim = Limiter(5, 300, 500000)  # span 500 mm
    for _ in range(400):
        r0, s0 = lim.ref, lim.slope
        lim.update(8000, -9000, 0, 0, True, 100)
        # change of ref + slope * (P - P_ref) at the envelope's edge
        edge = abs(lim.ref - r0) + abs(lim.slope - s0) * 500 // 1000
        assert edge <= 50
    assert (lim.ref, lim.slope) == (8000, -9000)


def test_fallback_ramps_to_zero_and_recovers_ramped():
    lim = Limiter(5, 300, 500000)
    lim.ref = lim.total = 2000
    seq = []
    for _ in range(50):
        lim.update(2000, 0, 2000, 2000, False, 100)
        seq.append(lim.total)
    assert seq[0] == 1950 and seq[-1] == 0 and min(seq) == 0 and lim.ref == 0
    assert all(a - b <= 50 for a, b in zip([2000] + seq, seq))
    fl = lim.update(2000, 0, 2000, 2000, True, 100)
    assert fl & st.RECOVERING and lim.total == 50
    for _ in range(60):
        fl = lim.update(2000, 0, 2000, 2000, True, 100)
    assert lim.total == 2000 and not fl & (st.RECOVERING | st.RATE_LIMITED)


def _setup(tmp_path, **kw):
    extra = {"hold_ms": 2000, "slew_um_per_s": 5, "max_offset_um": 300, "frame_ms": 100}
    extra.update(kw)
    app, board = rig_app(tmp_path, kind="linear_direct", extra=extra,
                         table_kw={"b": [1] * 11, "shb": 4})
    run_cycles(app, board, 300)  # ramp up from zero at boot
    assert app.status & (st.RATE_LIMITED | st.SENSOR_MASK | st.FALLBACK) == 0
    return app, board


def test_sensor_fault_flags_next_frame_holds_then_ramps_to_zero_then_recovers(tmp_path):
    app, board = _setup(tmp_path)
    good = app.total
    assert good > 1000
    board.chips[0].open_circuit = True
    board.serial.take()
    run_cycles(app, board, 1)
    f = frames(board.serial.take())[-1]
    s = int(f[2], 16)
    assert s & 1 and s & st.HELD and not s & st.FALLBACK  # flagged in the very next frame
    assert app.total == good  # held
    run_cycles(app, board, 19)
    assert app.total == good and app.status & st.HELD
    totals = []
    for _ in range(200):
        run_cycles(app, board, 1)
        totals.append(app.total)
    assert app.status & st.FALLBACK
    steps = [abs(b - a) for a, b in zip([good] + totals, totals)]
    assert max(steps) <= 50  # 5 um/s at 100 ms
    assert totals[-1] == 0
    board.chips[0].open_circuit = False
    board.chips[0].regs[7] = 0
    totals = []
    for _ in range(400):
        run_cycles(app, board, 1)
        totals.append(app.total)
    assert max(abs(b - a) for a, b in zip([0] + totals, totals)) <= 50
    assert totals[-1] == good
    assert app.status & (st.SENSOR_MASK | st.FALLBACK | st.RECOVERING | st.HELD) == 0


def test_fault_of_unused_sensor_is_flagged_but_output_unaffected(tmp_path):
    app, board = rig_app(tmp_path, kind="linear_direct", extra={"hold_ms": 1000},
                         table_kw={"sensors": ["T1", "T2"], "b": [40, 40]})
    run_cycles(app, board, 300)
    good = app.total
    board.chips[6].open_circuit = True
    run_cycles(app, board, 50)
    assert app.status & (1 << 6)
    assert not app.status & (st.HELD | st.FALLBACK)
    assert app.total == good


def test_step_in_model_output_is_ramped(tmp_path):
    app, board = _setup(tmp_path)
    before = app.total
    for i, c in enumerate(board.chips):  # every sensor +1 K: the model output steps by ~6.9 um
        c.set_temperature(21.0 + i)
    prev = app.total
    seen_rate = False
    for _ in range(100):
        run_cycles(app, board, 1)
        assert abs(app.total - prev) <= 50
        seen_rate |= bool(app.status & st.RATE_LIMITED)
        prev = app.total
    assert seen_rate and app.total == before + 11 * 1000 // 16


def test_disabled_output_ramps_to_zero(tmp_path):
    app, board = _setup(tmp_path)
    app.enabled = False
    run_cycles(app, board, 300)
    assert app.total == 0 and app.status & st.DISABLED and app.status & st.FALLBACK


def test_watchdog_fed_once_per_completed_cycle(tmp_path):
    app, board = rig_app(tmp_path)
    n = board.watchdog.fed
    run_cycles(app, board, 7)
    assert board.watchdog.fed == n + 7
    board.buses["spi0"].write_readinto = None  # a cycle that dies half way
    with pytest.raises(TypeError):
        app.cycle()
    assert board.watchdog.fed == n + 7


class WrapClock:
    """MicroPython tick semantics: ticks_ms wraps at 2**30, ticks_diff is modular."""

    def __init__(self, t):
        self.t = t

    def ticks_ms(self):
        return self.t & 0x3FFFFFFF

    def ticks_diff(self, a, b):
        return ((a - b + 0x20000000) & 0x3FFFFFFF) - 0x20000000

    def sleep_ms(self, ms):
        self.t += ms


def test_tick_wrap_and_week_long_fault(tmp_path):
    from fwfakes import make_rig
    from firmware.app import App
    names = ["T%d" % i for i in range(1, 12)]
    from fwhelpers import make_table
    (tmp_path / "table_a.bin").write_bytes(make_table(kind="linear_direct", sensors=names,
                                                      b=[1] * 11, shb=4))
    board = make_rig(table_dir=str(tmp_path), extra={"hold_ms": 60000, "frame_ms": 1000})
    board.clock = WrapClock((1 << 30) - 50000)  # wraps 50 s after boot
    app = App(board)
    data = b""
    for _ in range(1500):
        app.cycle()
        board.clock.t += 100
        data += board.serial.take()
    good = app.total
    assert good > 1000 and app.status & (st.SENSOR_MASK | st.FALLBACK | st.RATE_LIMITED) == 0
    out = frames(data)
    seqs = [int(f[1]) for f in out if f[3] == "O"]
    assert len(seqs) >= 149 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # across the wrap
    board.chips[0].open_circuit = True
    for _ in range(200):  # 200 h in 1 h steps: longer than ticks_diff's 6.2-day range
        app.cycle()
        board.clock.t += 3600 * 1000
        board.serial.take()
    assert app.status & st.FALLBACK and app.total == 0
    assert app.channels.fault[0]
