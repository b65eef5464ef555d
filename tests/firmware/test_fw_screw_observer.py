"""A screw table's observer on the board (issue 21; docs/firmware.md "Observer of the screw state").

A screw table with latched references (tcomp fit --model screw's default) whose observer reads the nut sensor T3 over
the air T2. The board restarts with its references stored and no trusted heat.bin: at the first all-good cycle it
starts the segments from the nut's rise (Evaluator.estimate), not in equilibrium with the air, and raises SETTLING
for the table's settle_s. A restored heat.bin, a latch (L: a cold start by definition) or a nut sensor that reads no
good value then give the cold start without SETTLING; a board without the nut's channel refuses the table.
"""
import os
import random

import pytest

from fwhelpers import HELLO_REFS_AT, frames, provision, run_cycles, scmd

from firmware.wire import FALLBACK, HELD, SETTLING

SETTLE_S = 120.0  # the test table's settle_s (the fit's are an hour or more)
COLD = (22.0, 23.0, 23.0)  # T1 base, T2 air, T3 nut: the machine at rest at the first latch
WARM = (22.0, 23.0, 31.0)  # the restart: the nut 8 K over the air (the screw warm under it)


@pytest.fixture(scope="module")
def doc():
    from hil_tests.fixtures.samples import with_screw_observer
    from hil_tests.rig.boards import _finish, screw_doc
    d = screw_doc(["T1", "T2"])
    d["thermal"]["reduced"]["base_ref"] = "run_start"  # latched references, heat.bin
    return _finish(with_screw_observer(d, "T3", random.Random(3), settle_s=SETTLE_S))


@pytest.fixture(scope="module")
def table(doc):
    from hil_tests.rig.boards import export
    return export(doc).table


def _boot(tmp_path, table=None, temps=COLD, channels=3):
    from fwfakes import make_rig
    from firmware.app import App
    if table is not None:
        (tmp_path / "table_a.bin").write_bytes(table)
        provision(tmp_path)
    board = make_rig(channels, 0, temps=list(temps), table_dir=str(tmp_path), extra={"frame_ms": 0}, serial_size=1 << 16)
    app = App(board)
    return app, board, frames(board.serial.take())[0]


def _first_boot(tmp_path, table):
    """Boot on a machine at rest: the references latch at the first good cycle (a cold start)."""
    app, board, hello = _boot(tmp_path, table)
    assert hello[HELLO_REFS_AT] == "N"
    run_cycles(app, board, 3, dt=1000)
    assert not app.status & SETTLING and not app.sobs
    return app


def _cold(app):
    from firmware.evaluate import Evaluator
    ev = Evaluator(app.table)
    ev.ref[:] = app.ev.ref
    ev.temps[:] = app.ev.temps
    ev.update()
    ev.settle()
    return ev.T


def test_a_restart_without_heat_bin_starts_the_screw_from_the_nut_sensor(tmp_path, table, doc):
    from hil_tests.rig.boards import export
    t0 = _first_boot(tmp_path, table).table
    assert t0.obs == 1 and t0.sensors == ["T1", "T2", "T3"] and t0.settle_s == SETTLE_S
    os.remove(str(tmp_path / "heat.bin"))  # none: a new board, a torn file, another table's
    app, board, hello = _boot(tmp_path, temps=WARM)
    assert hello[HELLO_REFS_AT] == "S" and not app.warm
    started = []
    real = app.ev.estimate
    app.ev.estimate = lambda: real() or started.append(list(app.ev.T))  # the state as started, before the cycle's step
    run_cycles(app, board, 3, dt=1000)  # the channels read good from the third cycle on: the estimate
    assert len(started) == 1
    t = app.table
    # the estimate against the document's float gains (state units 2**-ft K): T_i = a + G_i r, a the air's rise over its
    # latched reference, r the nut's rise over the air's (~8 K), within the exporter's certified start error
    gains = doc["thermal"]["observer"]["gains_K_per_K"]
    d = [(app.ev.temps[i] - app.ev.ref[i]) / 1000.0 for i in range(3)]
    cert = export(doc).report["screw"]["observer"]["certificate"]
    assert 7.9 < d[2] - d[1] < 8.1
    for i in range(t.M):
        assert abs(started[0][i] / (1 << t.ft) - (d[1] + gains[i] * (d[2] - d[1]))) <= cert["start_error_K"], i
    assert min(started[0]) > (1 << t.ft) // 2 and min(app.ev.T) > (1 << t.ft) // 2 > max(_cold(app))
    assert app.status & SETTLING and not app.status & (FALLBACK | HELD)
    run_cycles(app, board, int(SETTLE_S) - 2, dt=1000)
    assert app.status & SETTLING
    run_cycles(app, board, 2, dt=1000)
    assert not app.status & SETTLING  # settle_s after the estimate


def test_a_restored_heat_bin_wins_and_raises_no_settling(tmp_path, table):
    _first_boot(tmp_path, table)
    app, board, hello = _boot(tmp_path, temps=WARM)  # heat.bin holds the latch's state for these references
    run_cycles(app, board, 2, dt=1000)
    assert app.warm and not app.sobs and not app.status & SETTLING


def test_a_latch_is_a_cold_start_and_ends_settling(tmp_path, table):
    _first_boot(tmp_path, table)
    os.remove(str(tmp_path / "heat.bin"))
    app, board, _ = _boot(tmp_path, temps=WARM)
    run_cycles(app, board, 3, dt=1000)
    assert app.status & SETTLING
    board.serial.feed(scmd(app, "L"))
    app.link.poll(board.clock.t)
    ack = frames(board.serial.take())[-1]
    assert ack[3:5] == ["A", "L"], ack
    run_cycles(app, board, 1, dt=1000)
    assert not app.status & SETTLING and app.ev.T == _cold(app)


def test_a_faulty_nut_sensor_gives_the_cold_start_without_settling_and_the_model_runs_on(tmp_path, table):
    _first_boot(tmp_path, table)
    os.remove(str(tmp_path / "heat.bin"))
    app, board, _ = _boot(tmp_path, temps=WARM)
    board.chips[2].open_circuit = True
    calls = []
    for name in ("estimate", "settle"):
        real = getattr(app.ev, name)
        setattr(app.ev, name, lambda real=real, name=name: calls.append(name) or real())
    run_cycles(app, board, 60, dt=1000)  # beyond the hold time: the nut is read by the start only
    assert calls == ["settle"] and not app.sobs
    assert not app.status & (SETTLING | FALLBACK | HELD) and app.usable
    assert app.status & (1 << 2)  # the nut's channel reports its fault


def test_a_board_without_the_nut_channel_refuses_the_table(tmp_path, table):
    app, _, _ = _boot(tmp_path, table, temps=COLD[:2], channels=2)
    assert app.table is None  # "table sensor T3 has no channel on this board" (App._accept)
