"""Tables certified for latched references (models fitted on rises from the run start):
the firmware takes its reference temperatures at the first cycle in which every needed sensor is good."""
import random


from fwhelpers import run_cycles


def _table(base_ref):
    from models_export.export import export_model
    from hil_tests.fixtures.samples import restamp, screw_doc
    doc = screw_doc(random.Random(5), segments=8, dt_s=1.0, length_mm=500.0, feed_max_mm_min=12000.0)
    doc["thermal"]["reduced"]["base_ref"] = base_ref
    return export_model(restamp(doc)).table


def _app(tmp_path, table, base_temp):
    from fwfakes import make_rig

    from firmware.app import App
    (tmp_path / "table_a.bin").write_bytes(table)
    board = make_rig(2, 0, temps=[base_temp, 21.0], table_dir=str(tmp_path), extra={"frame_ms": 0, "slew_um_per_s": 1000})
    board.config["channels"][0]["name"] = "T_base"
    board.config["channels"][1]["name"] = "T_air"  # the screw's air channel
    return App(board), board


def test_run_start_table_latches_the_first_good_reading(tmp_path):
    app, board = _app(tmp_path, _table("run_start"), 23.5)
    assert app.table.ref_mode == 1
    assert app.ev.ref[0] == 20000  # the table's own reference until a good reading
    run_cycles(app, board, 3)
    latched = app.ev.ref[0]
    assert abs(latched - 23500) < 50, latched  # the reading at boot, within the RTD conversion
    assert app.ev.temps[0] == latched  # so the ambient term starts at zero
    for k in range(1, 21):  # warming later (slowly: a jump would be flagged) does not move the reference
        board.chips[0].set_temperature(23.5 + 0.05 * k)
        run_cycles(app, board, 10)
    assert not app.status & 1, "the base channel stayed good"
    assert app.ev.ref[0] == latched and app.ev.temps[0] > latched + 900


def test_fixed_table_keeps_its_reference(tmp_path):
    app, board = _app(tmp_path, _table("fixed"), 23.5)
    assert app.table.ref_mode == 0
    run_cycles(app, board, 3)
    assert app.ev.ref[0] == 20000
