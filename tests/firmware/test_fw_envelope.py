"""The certified envelope is the operating range; the training range inside it only informs
(docs/firmware.md, "Operating envelope"): between the two the model is evaluated and the status
says EXTRAPOLATING; beyond the envelope the input is clamped and the status says CLAMPED."""
from fwhelpers import frames, run_cycles, table_fields

from firmware.wire import CLAMPED, EXTRAPOLATING


def _table(train=(18000, 30000), env=(5000, 45000)):
    from models_export.tableformat import pack
    f = table_fields(kind="poly_slope", sensors=("T1", "T2"), b=[40, 10])
    f["env_lo"], f["env_hi"] = [env[0]] * 2, [env[1]] * 2
    f["train_lo"], f["train_hi"] = [train[0]] * 2, [train[1]] * 2
    return pack(f)


def _eval(temps):
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    ev = Evaluator(parse_table(_table()))
    ev.temps[:] = temps
    ev.update()
    return ev


def test_evaluator_extrapolates_inside_the_envelope_and_clamps_beyond():
    inside = _eval([25000, 20000])
    assert inside.flags == 0 and inside.extrap == 0
    hot = _eval([38000, 20000])  # 8 K above the training range, inside the envelope
    assert hot.flags == 0 and hot.extrap == 1
    cold = _eval([25000, 10000])
    assert cold.flags == 0 and cold.extrap == 2
    # evaluated, not clamped: the output is the model's at 38 degC, not at the training range's end
    assert hot.S != _eval([30000, 20000]).S
    beyond = _eval([50000, 20000])  # beyond the certified envelope: clamped to its end, and still extrapolated
    assert beyond.flags == 1 and beyond.extrap == 1
    assert beyond.S == _eval([45000, 20000]).S


def test_status_word_says_extrapolating_not_clamped(tmp_path):
    from fwfakes import make_rig
    from firmware.app import App
    (tmp_path / "table_a.bin").write_bytes(_table())
    board = make_rig(2, 0, temps=[25.0, 20.0], table_dir=str(tmp_path), extra={"frame_ms": 100}, serial_size=1 << 16)
    app = App(board)
    now = [25.0]

    def heat_to(t_c):  # slowly: a jump would be a sensor fault (the channels' rate check)
        while abs(now[0] - t_c) > 1e-9:
            now[0] += max(-0.05, min(0.05, t_c - now[0]))
            board.chips[0].set_temperature(now[0])
            run_cycles(app, board, 1)
        run_cycles(app, board, 5)
    run_cycles(app, board, 20)
    assert not app.status & (EXTRAPOLATING | CLAMPED)
    heat_to(38.0)
    assert app.status & EXTRAPOLATING and not app.status & CLAMPED
    out = frames(board.serial.take())
    assert int(out[-1][2], 16) & EXTRAPOLATING  # on the wire too
    heat_to(50.0)
    assert app.status & EXTRAPOLATING and app.status & CLAMPED and not app.status & 0xFFFF
    heat_to(25.0)
    assert not app.status & (EXTRAPOLATING | CLAMPED)
