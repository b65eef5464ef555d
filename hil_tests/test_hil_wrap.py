"""The tick counter wraps: MicroPython's ticks_ms() wraps at 2**30 ms (12.4 days of uptime). The rig
starts the board's clock 10 simulated minutes before the wrap and runs through it: frames keep
their one-second period (modulo the wrap), the output does not jump, no sensor is flagged.
"""
import pytest

from hil_tests.rig.boards import export, poly_slope_for_run, rig_config

pytestmark = pytest.mark.rig
PERIOD = 1 << 30


def test_ticks_wrap_is_seamless(make_rig, demo_run):
    sensors = ["T1", "T2", "T4"]
    table = export(poly_slope_for_run(demo_run, sensors, seed=17)).table
    rig = make_rig(rig_config(sensors), table, temps={"T1": 23.0, "T2": 24.0, "T4": 22.0},
                   start_ms=PERIOD - 600000, noise_uohm=20000)
    rig.send("P", 400000)
    rig.run(300000)  # settled, 5 minutes before the wrap
    rig.take_frames()
    rig.run(1500000, temps={"T1": 25.0, "T2": 25.0, "T4": 23.0})  # 20 minutes across the wrap
    o = [f for f in rig.take_frames() if f.kind == "O"]
    assert len(o) >= 1199
    steps = [(b.t_ms - a.t_ms) % PERIOD for a, b in zip(o, o[1:])]
    assert any(b.t_ms < a.t_ms for a, b in zip(o, o[1:]))  # the wrap happened in the window
    assert min(steps) >= 900 and max(steps) <= 1100, (min(steps), max(steps))
    assert all(f.status & 0xFFFF == 0 for f in o), [f.raw for f in o if f.status & 0xFFFF][:3]
    jumps = [abs(b.total_um - a.total_um) for a, b in zip(o, o[1:])]
    assert max(jumps) <= 5 * 1.0 + 0.1  # never faster than the 5 um/s slew limit
