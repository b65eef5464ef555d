"""The dynamic table (kind 4): lag filters as integer recurrences, certified against the exact model.

The reference is the host's recurrence (host/learning/empirical/dynamic.py) in doubles on the inputs the
firmware sees (temperatures clamped to the envelope minus the latched reference, spindle speed and
feed clamped to theirs): y <- y + a (u_prev - y) with a = 1 - exp(-dt/tau), started at rest at the
latch. The firmware's output must stay within the exporter's certificate at every step, however
long the run (the state error bound holds over an unbounded horizon), and every intermediate
inside the accumulator intervals the exporter certified.
"""
import math
import random

import numpy as np
import pytest

from firmware.evaluate import CLAMP_INPUT, Evaluator
from firmware.table import TableError, parse_table
from hil_tests.fixtures.samples import dynamic_doc, restamp
from models_export import export_model
from models_export.certify import ExportError


def _reference(doc, table):
    """Float model of the document, fed with the firmware's view of the inputs."""
    th = doc["thermal"]
    dt = th["dt_s"]
    terms = [(t["signal"], t["tau_s"], t["coefficient"]) for t in th["terms"]]
    a = [1.0 - np.exp(-dt / tau) if tau > 0 else 0.0 for _, tau, _ in terms]
    return terms, a


def _signal(name, table, temps, ref, rpm, feed):
    if name.startswith("T:"):
        i = table.sensors.index(name[2:])
        v = min(max(temps[i], table.env_lo[i]), table.env_hi[i])
        return (v - ref[i]) / 1000.0
    r = min(abs(rpm), table.smax) / 1000.0
    if name == "spindle_krpm":
        return r
    if name == "spindle_krpm2":
        return r * r
    return min(abs(feed), table.fmax) / 1000.0


def _run(doc, steps, seed, slow_inputs=False):
    ex = export_model(doc)
    t = parse_table(ex.table)
    ev = Evaluator(t, check=True)
    terms, a = _reference(doc, t)
    rng = random.Random(seed)
    th = doc["thermal"]
    geo = doc["geometric"]["coefficients_um"] if doc["geometric"] else [0.0]
    temps = [rng.randint(lo, hi) for lo, hi in zip(t.env_lo, t.env_hi)]
    rpm, feed = rng.randint(0, t.smax), 0
    for i, v in enumerate(temps):
        ev.temps[i] = v
    ev.set_spindle(rpm)
    ev.set_feed_rate(feed)
    ev.update()
    ev.latch_references()
    ref = list(ev.ref)
    y = [0.0] * len(terms)
    u0 = [_signal(n, t, temps, ref, rpm, feed) for n, _, _ in terms]
    worst = 0.0
    cert = ex.report["max_error_um"]
    for k in range(steps):
        # inputs wander (or jump) anywhere in and slightly beyond their envelopes
        for i in range(t.n_sensors):
            if slow_inputs:
                temps[i] = min(max(temps[i] + rng.randint(-200, 200), t.env_lo[i] - 500), t.env_hi[i] + 500)
            else:
                temps[i] = rng.randint(t.env_lo[i] - 2000, t.env_hi[i] + 2000)
            ev.temps[i] = temps[i]
        if k % 7 == 0 or not slow_inputs:
            rpm = rng.choice([0, rng.randint(-t.smax, t.smax + 500), t.smax])
            feed = rng.choice([0, rng.randint(0, t.fmax + 1000)])
        ev.set_spindle(rpm)
        ev.set_feed_rate(feed)
        ev.update()
        ev.step()
        u = [_signal(n, t, temps, ref, rpm, feed) for n, _, _ in terms]
        for j in range(len(terms)):
            if a[j] > 0:
                y[j] = y[j] + a[j] * (u0[j] - y[j])
            else:
                y[j] = u[j]
        u0 = u
        thermal = th["intercept"] + sum(c * v for (_, _, c), v in zip(terms, y))
        for p in (t.pos_lo, t.pos_hi, rng.randint(t.pos_lo, t.pos_hi)):
            pm = p / 1000.0
            want = thermal if th["target"] == "direct" else sum(g * pm ** n for n, g in enumerate(geo)) + thermal * pm
            got = ev.offset_at(p) / 100.0
            worst = max(worst, abs(got - want) / cert)
            assert abs(got - want) <= cert, "step %d P=%d: firmware %.4f um, model %.6f um, certificate %.4f um" % (k, p, got, want, cert)
    for acc_id, (lo, hi) in enumerate(zip(ev.lo, ev.hi)):
        if lo <= hi:
            assert acc_id in ex.accs, "accumulator %d used by the firmware but not certified" % acc_id
            c = ex.accs[acc_id]
            assert c[0] <= lo and hi <= c[1], "accumulator %d: observed %d..%d outside certified %d..%d" % (acc_id, lo, hi, c[0], c[1])
    return worst, ex


@pytest.mark.parametrize("target", ["direct", "slope"])
def test_firmware_within_certificate_of_exact_recurrence(target):
    worst = 0.0
    for seed in range(8):
        doc = dynamic_doc(random.Random(seed), target, dt_s=random.Random(seed).choice([1.0, 15.0, 60.0]))
        w, ex = _run(doc, 400, seed, slow_inputs=seed % 2 == 0)
        assert ex.report["max_error_um"] < 0.1
        worst = max(worst, w)
    assert worst > 0.01  # the comparison resolves the certificate (the test is not vacuous)


def test_long_horizon_state_error_stays_bounded():
    """Short step, the longest time constant: 20000 steps, the state error bound holds in steady state."""
    doc = dynamic_doc(random.Random(3), "direct", n_sensors=2, dt_s=1.0,
                      signals=["T:T0", "T:T1", "spindle_krpm2", "spindle_krpm"])
    for term in doc["thermal"]["terms"]:
        term["tau_s"] = 57600.0
    doc = restamp(doc)
    _run(doc, 20000, 11, slow_inputs=True)


def test_spindle_and_feed_clamped_and_flagged():
    ex = export_model(dynamic_doc(random.Random(2), "direct", signals=["spindle_krpm", "feed_m_min"]))
    t = parse_table(ex.table)
    ev = Evaluator(t)
    ev.set_spindle(t.smax)
    ev.update()
    assert not ev.flags & CLAMP_INPUT
    ev.set_spindle(-(t.smax + 1))  # reverse rotation: the magnitude counts, beyond the envelope: clamped
    ev.update()
    assert ev.flags & CLAMP_INPUT
    ev.set_spindle(0)
    ev.set_feed_rate(t.fmax + 1)
    ev.update()
    assert ev.flags & CLAMP_INPUT
    ev.set_feed_rate(t.fmax)
    ev.update()
    assert not ev.flags & CLAMP_INPUT


def test_latch_restarts_the_filters_from_rest():
    doc = dynamic_doc(random.Random(5), "direct", signals=["spindle_krpm"])
    doc["thermal"]["terms"][0]["tau_s"] = 900.0
    ex = export_model(restamp(doc))
    t = parse_table(ex.table)
    ev = Evaluator(t)
    rest = ev.offset_at(0)
    ev.set_spindle(t.smax)
    ev.update()
    for _ in range(50):
        ev.step()
    assert ev.offset_at(0) != rest and ev.Y[0] != 0
    ev.set_spindle(0)
    ev.update()
    ev.latch_references()
    assert ev.Y[0] == 0 and ev.offset_at(0) == rest


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["thermal"].pop("dt_s"), "thermal.dt_s"),
    (lambda d: d["thermal"].update(dt_s=0.0004), "thermal.dt_s"),
    (lambda d: d["envelope"].pop("spindle_rpm"), "envelope.spindle_rpm"),
    (lambda d: d["thermal"]["terms"].append({"signal": "T:nope", "tau_s": 0.0, "coefficient": 1.0}), "T:nope"),
    (lambda d: d["thermal"]["terms"].append({"signal": "torque", "tau_s": 0.0, "coefficient": 1.0}), "torque"),
    (lambda d: d["thermal"].update(target="sideways"), "thermal.target"),
    # a signal that is no string: unhashable, the source lookup raised a TypeError (tcomp export printed a traceback)
    (lambda d: d["thermal"]["terms"].append({"signal": ["spindle_krpm"], "tau_s": 0.0, "coefficient": 1.0}),
     "thermal.terms[2].signal must be 'T:<sensor>', 'T2:'..'T4:<sensor>' or one of spindle_krpm, spindle_krpm2, "
     "feed_m_min, found ['spindle_krpm']"),
])
def test_export_refuses_naming_the_field(edit, message):
    doc = dynamic_doc(random.Random(1), "direct", n_sensors=2, signals=["T:T0", "spindle_krpm"])
    edit(doc)
    with pytest.raises(ExportError) as e:
        export_model(restamp(doc))
    assert message in str(e.value)


def test_tcomp_export_refuses_a_signal_that_is_no_string(tmp_path, capsys):
    """The document check before the exporter does not look into thermal.terms: a list signal reached the exporter's
    source lookup and tcomp export ended in a TypeError traceback; now a user error naming the term, no table."""
    import json

    from host.cli import main

    doc = dynamic_doc(random.Random(1), "direct", n_sensors=2, signals=["T:T0", "spindle_krpm"])
    doc["thermal"]["terms"][1]["signal"] = ["spindle_krpm"]
    model = tmp_path / "model.json"
    model.write_text(json.dumps(restamp(doc)))
    assert main(["export", str(model), "--out", str(tmp_path / "t.bin")]) == 2
    assert "thermal.terms[1].signal must be " in capsys.readouterr().err and not (tmp_path / "t.bin").exists()


def test_loader_refuses_a_filter_reading_a_missing_sensor():
    import struct
    import zlib
    ex = export_model(dynamic_doc(random.Random(1), "direct", n_sensors=2, signals=["T:T0", "spindle_krpm"]))
    t = parse_table(ex.table)
    assert t.kind == "dynamic" and t.src == [0, -1]
    b = bytearray(ex.table)
    # the first src word follows COMMON (8 + 3 per sensor + rL) and the 16-word dynamic head
    from firmware.table import HEADER_SIZE, NAME_SIZE, SENSOR_SIZE
    off = HEADER_SIZE + (NAME_SIZE + SENSOR_SIZE) * t.n_sensors + 4 * (8 + 3 * t.n_sensors + 1 + 16)
    assert struct.unpack_from("<i", b, off)[0] == 0
    struct.pack_into("<i", b, off, t.n_sensors)
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    with pytest.raises(TableError) as e:
        parse_table(bytes(b))
    assert e.value.reason == "invalid field"


def test_report_carries_the_filter_certificate():
    ex = export_model(dynamic_doc(random.Random(7), "direct"))
    r = ex.report
    assert r["model_kind"] == "dynamic" and r["dynamic"]["dt_ms"] == parse_table(ex.table).dt_ms
    filt = r["dynamic"]["filters"]
    assert len(filt) == len(ex.fields["A"])
    for f in filt:
        assert f["state_error_units"] >= 0 and math.isfinite(f["state_error_units"])
