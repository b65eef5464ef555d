"""A dynamic table on the rig: the firmware's offsets on the real FL_THERMAL run equal the host model's.

The model is one `tcomp fit --model dynamic --direct --channel ch1` fitted on data/fl_thermal
(hil_tests/fixtures/dynamic_fl_thermal_ch1.json: lag-filtered rises of t2, t4, t15 and the spindle
speed and its square, time constants 0 s .. 4 h, 15 s step). The rig plays the run's first hours:
temperatures through the simulated Pt100 chips, the spindle speed as P,<pos>,<rpm> from spindle.csv,
the signed L at the run's start (the cold start: references latched, filters at rest, as the host's
at the run's first sample). Each query comes 200 ms after its row's time, after the board's filter
step at that sample.

Tolerance per answer: the exporter's certificate (integer table vs the exact recurrence) + every
temperature term's coefficient x twice the RTD chain bound (the reading and the latched reference;
a lag filter passes an input error through with gain <= 1) + half the 0.1 um frame resolution.
Answers whose status says RATE_LIMITED are not compared (the limiter lags on purpose).
"""
import json
import os

import numpy as np
import pytest

from hil_tests.conftest import SLOW
from hil_tests.rig.boards import export, rig_config
from hil_tests.rig.play import play, rtd_bound_K
from firmware.wire import CLAMPED
from host.board.link import RATE_LIMITED

pytestmark = pytest.mark.rig

HERE = os.path.dirname(os.path.abspath(__file__))
FIXTURE = os.path.join(HERE, "fixtures", "dynamic_fl_thermal_ch1.json")
RUN = os.path.join(os.path.dirname(HERE), "data", "fl_thermal")


def _subset(run, hours, channel):
    """The first ``hours`` of ``run``, errors of one channel only."""
    from host.data.runs import Errors, Run, Spindle, Temperatures
    t = run.temperatures
    keep = t.time_s <= hours * 3600
    e = run.errors
    ke = (e.time_s <= hours * 3600) & (np.asarray(e.channel) == channel)
    sp = run.spindle
    ks = sp.time_s <= hours * 3600
    return Run(run.meta, Temperatures(t.time_s[keep], t.names, t.values[keep]),
               Errors(e.time_s[ke], e.position_mm[ke], e.error_um[ke], None, np.asarray(e.channel)[ke]), None,
               Spindle(sp.time_s[ks], sp.rpm[ks]))


def test_dynamic_table_on_the_rig_matches_host_model(make_rig):
    from host.learning.documents import load_model
    from host.data.runs import load_run
    with open(FIXTURE) as fh:
        doc = json.load(fh)
    run = _subset(load_run(RUN), 12.0 if SLOW else 3.0, doc["channel"])
    sensors = list(doc["sensors"])
    ex = export(doc)
    assert ex.report["dynamic"]["dt_ms"] == 15000
    temps = {s: float(run.temperatures.column(s)[0]) for s in sensors}
    from hil_tests.rig import interpreters
    heap = os.environ.get("TCOMP_HIL_HEAP") or interpreters.heap("rig_dynamic")
    rig = make_rig(rig_config(sensors), ex.table, temps=temps, noise_uohm=0, heap=heap)
    answers = play(rig, run, sensors, motion=False, spindle=True, latch=True, query_delay_ms=200)
    model = load_model(doc)
    pred = np.asarray(model.predict(run))
    dT = rtd_bound_K(run, sensors)
    rtd_um = sum(abs(t["coefficient"]) * 2 * dT[t["signal"][2:]] for t in doc["thermal"]["terms"] if t["signal"].startswith("T:"))
    bound = ex.report["max_error_um"] + rtd_um + 0.05 + 1e-9
    compared = 0
    worst = 0.0
    spindle_on = 0
    for a, p, t in zip(answers, pred, run.errors.time_s):
        st = int(a["status"], 16)
        assert not a["held"] and not a["fallback"] and not st & CLAMPED, a
        if st & RATE_LIMITED:
            continue
        compared += 1
        err = abs(a["offset_um"] - p)
        worst = max(worst, err)
        assert err <= bound, "t=%.0f s: firmware %.2f um, host %.4f um, bound %.4f um (status %s)" % (
            t, a["offset_um"], p, bound, a["status"])
        spindle_on += float(np.interp(t, run.spindle.time_s, run.spindle.rpm)) > 0
    assert len(answers) == len(run.errors) and compared >= 0.85 * len(answers), (compared, len(answers))
    assert spindle_on > 0.5 * compared  # the spindle terms were exercised
    # the model moved well beyond the tolerance over the run: the comparison is not vacuous
    assert float(np.ptp(pred)) > 5 * bound, (np.ptp(pred), bound)
    print("dynamic on the rig: %d answers, worst |firmware - host| %.3f um, bound %.3f um" % (compared, worst, bound))
    st = rig.stats()
    for name, c in st["chips"].items():
        assert c["violations"] == 0, c["violation_text"]
    assert not rig.reader.decoder.bad
