"""Screw tables: position reports and the feed/range fallback drive the segment state on a fixed step."""
import random

import pytest

from fwhelpers import cmd, frames, run_cycles


@pytest.fixture(scope="module")
def screw_table():
    from hil_tests.fixtures.samples import screw_doc
    from models_export.export import export_model
    doc = screw_doc(random.Random(3), segments=8, dt_s=1.0, length_mm=500.0, feed_max_mm_min=12000.0)
    return export_model(doc).table


def screw_app(tmp_path, table):
    from fwfakes import make_rig
    from firmware.app import App
    (tmp_path / "table_a.bin").write_bytes(table)
    board = make_rig(2, 0, table_dir=str(tmp_path), extra={"frame_ms": 0, "slew_um_per_s": 1000})
    board.config["channels"][0]["name"] = "T_base"
    board.config["channels"][1]["name"] = "T_air"  # the screw's air channel
    return App(board), board


def test_position_reports_drive_the_same_state_as_the_evaluator(tmp_path, screw_table):
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    app, board = screw_app(tmp_path, screw_table)
    assert app.table.kind == "screw_reduced" and app.table.dt_ms == 1000
    ref = Evaluator(parse_table(screw_table))
    run_cycles(app, board, 5)
    ref.temps[0] = app.ev.temps[0]
    ref.temps[1] = app.ev.temps[1]
    ref.update()
    ref.settle()  # the app settled its state on the first good air reading
    assert app.ev.T == ref.T and app.ev.da == ref.da
    elapsed = app.step_ms  # same step phase as the app
    pos = 20000
    for k in range(1200):  # 2 minutes of 100 ms cycles, axis sweeping 20..480 mm at 6 m/min
        pos += 10000 if (k // 46) % 2 == 0 else -10000
        board.serial.feed(cmd(b"TC,P,%d" % pos))
        app.cycle()
        ref.advance_position(pos)
        elapsed += 100
        while elapsed >= 1000:
            ref.step()
            elapsed -= 1000
        board.clock.t += 100
        board.serial.take()
    air_state = app.ev.da * (1 << app.table.ft) // 1000  # the air over its reference, in state units
    assert max(app.ev.T) > air_state + (1 << app.table.ft) // 100  # the screw heated above the air
    assert app.ev.T == ref.T
    assert app.ev.offset_at(300000) == ref.offset_at(300000)
    assert not app.status & 0x60000  # neither rate nor magnitude limited
    assert app.total == app.ev.offset_at(pos)  # the total follows the axis position


def test_feed_range_fallback(tmp_path, screw_table):
    app, board = screw_app(tmp_path, screw_table)
    run_cycles(app, board, 5)
    board.serial.feed(cmd(b"TC,M,6000,50000,450000"))
    app.link.poll(board.clock.t)
    assert frames(board.serial.take())[-1][3:6] == ["A", "M", "6000"]
    assert app.ev.feed
    run_cycles(app, board, 600)
    assert max(app.ev.T) > 0
    hot = list(app.ev.T)
    board.serial.feed(cmd(b"TC,M,0,0,0"))  # feed 0: stopped, the screw cools
    app.link.poll(board.clock.t)
    run_cycles(app, board, 600)
    assert not app.ev.feed and sum(app.ev.T) < sum(hot)
    board.serial.feed(cmd(b"TC,M,6000,50000,450000"))
    app.link.poll(board.clock.t)
    board.serial.feed(cmd(b"TC,P,100000"))  # a position report takes over from the feed state
    app.link.poll(board.clock.t)
    assert not app.ev.feed


def test_feed_command_without_screw_table(tmp_path):
    from fwhelpers import rig_app
    app, board = rig_app(tmp_path)
    board.serial.take()
    board.serial.feed(cmd(b"TC,M,6000,0,100000"))
    app.link.poll(board.clock.t)
    assert frames(board.serial.take())[-1][3:6] == ["E", "5", "state"]
