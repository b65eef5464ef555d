"""Sensor plausibility: chip faults, range, rate, stuck, bus errors, a chip that goes and comes back."""
import pytest

from fwhelpers import rig_app, run_cycles
from firmware import channels as chm


def setup(tmp_path, **extra):
    app, board = rig_app(tmp_path, extra=extra or None)
    run_cycles(app, board, 5)
    assert app.channels.faulty_mask() == 0
    return app, board, app.channels


def test_good_readings_after_start(tmp_path):
    app, board, ch = setup(tmp_path)
    for i in range(11):
        assert abs(ch.temp[i] - (20000 + 1000 * i)) <= 40  # MAX31865 LSB ~34 mdegC
    assert ch.fault == [0] * 11


def test_never_good_before_three_reads(tmp_path):
    app, board = rig_app(tmp_path)
    run_cycles(app, board, 2)
    assert app.channels.faulty_mask() == (1 << 11) - 1
    assert all(f & chm._F_NEVER for f in app.channels.fault)
    run_cycles(app, board, 1)
    assert app.channels.faulty_mask() == 0


def test_open_rtd_chip_fault(tmp_path):
    app, board, ch = setup(tmp_path)
    board.chips[2].open_circuit = True
    run_cycles(app, board, 1)
    assert ch.faulty_mask() == 1 << 2
    assert ch.fault[2] == chm._F_CHIP and ch.chip_status[2] & 0x80


def test_out_of_plausible_range(tmp_path):
    app, board, ch = setup(tmp_path, plausible_mC=[0, 60000], max_rate_mC_per_s=1000000)
    board.chips[9].set_temperature(65.0)  # the ADS122C04 has no threshold register: software check
    run_cycles(app, board, 1)
    assert ch.fault[9] & chm._F_RANGE
    board.chips[3].set_temperature(-5.0)  # MAX31865: its low threshold trips as well
    run_cycles(app, board, 1)
    assert ch.fault[3] & (chm._F_CHIP | chm._F_RANGE)


def test_jump_faster_than_physics_then_accepted_when_possible(tmp_path):
    app, board, ch = setup(tmp_path, max_rate_mC_per_s=1000)
    board.chips[1].set_temperature(21.0 + 5.0)  # +5 K in one 100 ms cycle
    run_cycles(app, board, 1)
    assert ch.fault[1] == chm._F_RATE and not ch.good[1]
    held = ch.temp[1]
    run_cycles(app, board, 30)  # 3 s: 1 K/s allows 3.2 K, still not 5 K
    assert not ch.good[1] and ch.temp[1] == held
    run_cycles(app, board, 30)  # 6 s: now physically possible
    assert ch.good[1] and abs(ch.temp[1] - 26000) <= 40


def test_short_spike_excluded(tmp_path):
    app, board, ch = setup(tmp_path, max_rate_mC_per_s=1000)
    board.chips[4].set_temperature(80.0)
    run_cycles(app, board, 1)
    assert not ch.good[4]
    board.chips[4].set_temperature(24.0)
    run_cycles(app, board, 3)
    assert ch.good[4] and abs(ch.temp[4] - 24000) <= 40


def test_stuck_value(tmp_path):
    app, board, ch = setup(tmp_path, stuck_ms=2000)
    run_cycles(app, board, 25)
    assert all(f & chm._F_STUCK for f in ch.fault)  # perfectly constant fakes are "stuck"
    board.chips[0].set_temperature(20.1)
    run_cycles(app, board, 1)
    board.chips[0].set_temperature(20.2)
    run_cycles(app, board, 1)
    board.chips[0].set_temperature(20.3)
    run_cycles(app, board, 1)
    assert ch.good[0]


def test_bus_error_burst_and_recovery(tmp_path):
    app, board, ch = setup(tmp_path)
    spi = board.buses["spi0"]
    spi.fail = 9  # one failed transfer per MAX31865 channel
    run_cycles(app, board, 1)
    assert ch.faulty_mask() == (1 << 9) - 1
    assert all(f == chm._F_BUS for f in ch.fault[:9])
    run_cycles(app, board, 3)
    assert ch.faulty_mask() == 0


def test_max31865_power_loss_reinitialised(tmp_path):
    app, board, ch = setup(tmp_path)
    chip = board.chips[5]
    for i in range(8):  # power-on reset: configuration 0, no conversions
        chip.regs[i] = 0xFF if i in (3, 4) else 0
    run_cycles(app, board, 2)
    assert ch.fault[5] & chm._F_RANGE
    run_cycles(app, board, 15)  # re-initialised after REINIT_MS, then three good reads
    assert ch.good[5] and chip.regs[0] & 0xC0 == 0xC0


def test_ads122c04_disappears_and_comes_back(tmp_path):
    app, board, ch = setup(tmp_path)
    dev = board.chips[10]
    dev.present = False
    run_cycles(app, board, 3)
    assert ch.fault[10] == chm._F_BUS
    dev.present = True
    dev.command(0x06)  # it came back from a power cycle: registers at reset values
    run_cycles(app, board, 20)
    assert ch.good[10] and dev.regs[1] & 0x08


def test_ads122c04_no_new_conversion_is_stale(tmp_path):
    app, board, ch = setup(tmp_path)
    board.chips[9].auto = False
    run_cycles(app, board, 5)
    assert ch.good[9]  # between conversions the last value stands
    run_cycles(app, board, 10)
    assert ch.fault[9] == chm._F_STALE


def test_two_wire_lead_and_calibration(tmp_path):
    from fwfakes import make_rig, pt100_ohm
    from firmware.app import App
    board = make_rig(1, 0, table_dir=str(tmp_path))
    board.config["channels"][0].update({"wires": 2, "lead_mohm": 800, "cal_mC": -150})
    board.chips[0].set_ohm(pt100_ohm(30.0) + 0.8)
    app = App(board)
    run_cycles(app, board, 4)
    assert abs(app.channels.temp[0] - (30000 - 150)) <= 40


def test_unknown_bus_is_valueerror(tmp_path):
    from fwfakes import make_rig
    from firmware.app import App
    board = make_rig(1, 0, table_dir=str(tmp_path))
    board.config["channels"][0]["bus"] = "spi9"
    with pytest.raises(ValueError, match="spi9"):
        App(board)


def test_chip_missing_at_start_is_picked_up_when_it_appears(tmp_path):
    from fwfakes import make_rig
    from firmware.app import App
    board = make_rig(2, 1, table_dir=str(tmp_path))
    board.chips[2].present = False
    app = App(board)
    ch = app.channels
    assert ch.drivers[2] is None
    run_cycles(app, board, 5)
    assert ch.fault[2] == chm._F_BUS and ch.good[0] and ch.good[1]
    board.chips[2].present = True
    run_cycles(app, board, 15)
    assert ch.drivers[2] is not None and ch.good[2]
