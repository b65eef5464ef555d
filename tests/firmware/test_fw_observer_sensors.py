"""A dynamic table whose observer reads a sensor no term reads (option observer_sensors, issue 21; docs/firmware.md
"Observer"): the board reads it as any table input. At the start it waits for it: while that sensor reads no good
value the lag states stay unset (no start from a worse estimate) and the offset is not usable (no wild offset);
once it reads good the states are estimated from every input, that sensor's reading included."""
import random

from fwhelpers import rig_app, run_cycles

NAMES = ["T%d" % i for i in range(1, 12)]  # the rig's channels (fwhelpers.rig_app: 9 MAX31865 + 2 ADS122C04)


def _table():
    from hil_tests.fixtures.samples import dynamic_doc, restamp, with_observer
    from models_export import export_model
    doc = dynamic_doc(random.Random(3), "direct", dt_s=1.0, signals=["T:T1", "T:T2", "T:T1"], names=list(NAMES))
    for t, tau in zip(doc["thermal"]["terms"], (900.0, 3600.0, 0.0)):
        t["tau_s"] = tau
    for s in NAMES:  # the rig's temperatures (20 + i degC) inside every envelope
        doc["envelope"]["temperature_C"][s] = [0.0, 60.0]
        doc["reference_C"][s] = 22.0
    doc = with_observer(doc, random.Random(3), settle_s=20.0)
    for st in doc["thermal"]["observer"]["states"]:
        st["gains"]["T:T4"] = 0.8  # T4, read by no term: the observer's own sensor
    return export_model(restamp(doc)).table


def test_an_observer_only_sensor_without_a_good_value_delays_the_start_and_then_enters_it(tmp_path):
    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    table = _table()
    t = parse_table(table)
    assert t.obs == 1 and t.nf == 4  # the three terms and T4's filter (coefficient 0)
    (tmp_path / "table_a.bin").write_bytes(table)
    app, board = rig_app(tmp_path, table=False, extra={"frame_ms": 0})
    board.chips[3].open_circuit = True  # T4 reads no good value from boot
    run_cycles(app, board, 40)
    assert app.table is not None and app.table.obs == 1
    assert app.unobserved and not app.usable  # no start, and no offset put out
    board.chips[3].open_circuit = False
    board.chips[3].set_temperature(31.0)
    for _ in range(40):
        run_cycles(app, board, 1)
        if not app.unobserved:
            break
    assert not app.unobserved and app.usable
    est = list(app.ev.Y)
    lag = [j for j in range(t.nf) if t.A[j]]
    # the board's estimate is the table's on its inputs, T4's reading included: a fresh evaluator gives it, and with
    # T4 at the reference (its rise 0) it would differ
    for t4, same in ((None, True), (22000, False)):
        ev = Evaluator(t)
        ev.temps[:] = app.ev.temps
        if t4 is not None:
            ev.temps[t.sensors.index("T4")] = t4
        ev.update()
        ev.observe()
        assert (all(ev.Y[j] == est[j] for j in lag)) == same
