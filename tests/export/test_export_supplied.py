"""Lag states the controller supplies (issue 21, table formats 7 and 8): the table marks them (tauc), the board takes them
in its state units, and the certificate covers the board against the host model started at the controller's exact
lag values.

The host side here is the model document read by the host (Observer.from_document, the terms' coefficients) and
doubles; the exact supplied lag is drawn at random inside the state's physical range (0..smax rpm, 0..smax**2 rpm**2,
0..fmax mm/min), and the board gets what the controller sends, round(lag x 2**scale) with scale from the board's own
dictionary (Evaluator.supply_scale). The physical range is checked against the box independently: the box's top
divided by 2**scale must be the envelope's top in the source's units.
"""
import copy
import math
import random
import struct
import zlib

import pytest

from firmware.table import TableError, parse_table
from hil_tests.fixtures.samples import (assert_inside_certified_accumulators, board_and_host_start, dynamic_doc, follow_host,
                                        observer_input_unit, restamp, with_observer, with_supplied)
from models_export import export_model
from models_export.certify import ExportError

SUPPLIED = ("spindle_krpm", "spindle_krpm2", "feed_m_min")
# host signal units per unit the controller measures (rpm, rpm**2, mm/min)
PER_SOURCE_UNIT = {"spindle_krpm": 1e-3, "spindle_krpm2": 1e-6, "feed_m_min": 1e-3}


def _doc(seed, target="direct", dt_s=15.0, keep_gains=False):
    rng = random.Random(seed)
    sig = ["T:T0", "T:T1", "spindle_krpm", "spindle_krpm2", "feed_m_min"]
    doc = dynamic_doc(rng, target, dt_s=dt_s, n_sensors=3, signals=sig)
    for t, tau in zip(doc["thermal"]["terms"], (1800.0, 0.0, 3600.0, 7200.0, 900.0)):
        t["tau_s"] = tau
    doc["envelope"]["spindle_rpm"] = [0, 12000]
    return with_supplied(with_observer(restamp(doc), random.Random(seed)), keep_gains=keep_gains)


def test_table_marks_the_supplied_states_with_their_time_constants():
    doc = _doc(0)
    ex = export_model(doc)
    t = parse_table(ex.table)
    assert t.version == 8
    terms = doc["thermal"]["terms"]
    for j, term in enumerate(terms):
        want = round(term["tau_s"] * 1000) if term["signal"] in SUPPLIED and term["tau_s"] > 0 else 0
        assert t.tauc[j] == want, (j, term)
        if want:  # the board estimates nothing into it
            assert not any(t.Go[j * t.nf + m] for m in range(t.nf)) and t.gO[j] == 0 and t.rG[j] == 0
    # the dictionary's scale against the box and the envelope, in the units the controller measures
    from firmware.evaluate import Evaluator
    ev = Evaluator(t)
    top = {-1: 12000, -2: 12000 ** 2, -3: t.fmax}
    for j in range(t.nf):
        if t.tauc[j]:
            assert t.Ylo[j] == 0 and t.Yhi[j] == top[t.src[j]] * 2 ** ev.supply_scale(j), (j, t.src[j])
    cert = {c["term"]: c for c in ex.report["dynamic"]["observer"]["states"]}
    marked = [c for c in cert.values() if c.get("supplied_by") == "controller"]
    assert len(marked) == 3 and all(c["start_error_units"] == 0.5 for c in marked)  # gains {}: the controller's rounding


@pytest.mark.parametrize("seed, target", [(0, "direct"), (1, "slope"), (2, "direct")])
def test_board_started_with_the_supplied_states_follows_the_host_within_the_certificate(seed, target):
    """The board estimates the temperature lags, takes the controller's spindle/feed lags, and then stays within
    max_error_um of the host model started there; without the supplied values (states at rest) it does not."""
    doc = _doc(seed, target)
    ex, t, terms, est, ev, (temps, rpm, feed), u0, rng = board_and_host_start(doc, seed)
    top = {"spindle_krpm": 12000.0, "spindle_krpm2": 12000.0 ** 2, "feed_m_min": float(t.fmax)}
    y, vals = [], []
    for j, (n, tau, _) in enumerate(terms):
        if tau > 0 and n in SUPPLIED:
            lag = rng.uniform(0.05, 0.95) * top[n]  # the controller's exact lag, in rpm / rpm**2 / mm/min
            vals.append(int(round(lag * 2.0 ** ev.supply_scale(j))))
            y.append(lag * PER_SOURCE_UNIT[n])
        elif tau > 0:
            per = observer_input_unit(n, t) / 2.0 ** t.fy[j]
            y.append(min(max(est[j], t.Ylo[j] * per), t.Yhi[j] * per))
        else:
            y.append(u0[n])
    unsupplied = list(ev.Y)
    ev.supply(vals)
    assert [ev.Y[j] for j in range(t.nf) if t.tauc[j]] == vals
    assert [ev.Y[j] for j in range(t.nf) if not t.tauc[j]] == [unsupplied[j] for j in range(t.nf) if not t.tauc[j]]
    cert = ex.report["max_error_um"]
    rest = [0.0 if (tau > 0 and n in SUPPLIED) else v for (n, tau, _), v in zip(terms, y)]
    off, off_rest = follow_host(ev, t, doc, [y, rest], temps, rpm, feed, rng)
    assert off <= cert, (off, cert)
    assert off_rest > 100 * cert  # the supplied values matter: started without them the board is far off
    assert_inside_certified_accumulators(ev, ex)


@pytest.mark.parametrize("seed, target", [(3, "direct"), (4, "slope")])
def test_before_the_controllers_values_the_board_follows_the_hosts_estimate(seed, target):
    """A fit writes gains for the supplied states too: the estimate a board starts them at when the controller's values do
    not come (no --signal-record; the host's predict without --controller-history). The board's start is the host's
    float estimate within the certified start error, and from there it stays within max_error_um; taking the steady
    state of the first speed instead (the start without gains) it does not."""
    doc = _doc(seed, target, keep_gains=True)
    ex, t, terms, est, ev, (temps, rpm, feed), u0, rng = board_and_host_start(doc, seed)
    assert any(t.tauc[j] and any(t.Go[j * t.nf + m] for m in range(t.nf)) for j in range(t.nf))  # the rows are in the table
    cert = {c["filter"]: c for c in ex.report["dynamic"]["observer"]["states"]}
    y, steady = [], []
    for j, (n, tau, _) in enumerate(terms):
        if tau > 0:
            per = observer_input_unit(n, t) / 2.0 ** t.fy[j]
            y.append(min(max(est[j], t.Ylo[j] * per), t.Yhi[j] * per))
            assert abs(ev.Y[j] * per - y[-1]) <= cert[j]["start_error_units"] * per + 1e-12, (j, n)
            steady.append(u0[n] if n in SUPPLIED else y[-1])
        else:
            y.append(u0[n])
            steady.append(u0[n])
    off, off_steady = follow_host(ev, t, doc, [y, steady], temps, rpm, feed, rng)
    assert off <= ex.report["max_error_um"], off
    assert off_steady > 10 * ex.report["max_error_um"], off_steady
    assert_inside_certified_accumulators(ev, ex)


def _older(table, version, cut):
    """``table`` (a direct dynamic table) as format ``version``: the ``cut`` words before the certificate's 3 removed,
    the length, word count and CRC recomputed."""
    buf = bytearray(table[:-4])
    end = len(buf) - 3 * 4
    old = buf[:end - 4 * cut] + buf[end:]
    old[4] = version
    struct.pack_into("<I", old, 8, len(old) + 4)
    struct.pack_into("<I", old, 52, struct.unpack_from("<I", buf, 52)[0] - cut)
    old += struct.pack("<I", zlib.crc32(bytes(old)) & 0xFFFFFFFF)
    return bytes(old)


def test_format_6_dynamic_table_still_loads_without_supplied_states():
    """A format-6 table is a format-8 one without the tauc words and settle_nr: it loads, every state the board's."""
    doc = with_observer(restamp(dynamic_doc(random.Random(5), "direct", dt_s=15.0)), random.Random(5))
    ex = export_model(doc)
    nf = len(doc["thermal"]["terms"])
    # the tauc words and settle_nr are the dynamic block's last nf + 1 words; for a direct table the certificate follows
    t6, t8 = parse_table(_older(ex.table, 6, nf + 1)), parse_table(ex.table)
    assert t6.version == 6 and t6.tauc == [0] * nf and t6.settle_nr == 0 and t6.Go == t8.Go and t6.cert_out == t8.cert_out


def test_format_7_table_keeps_settling_until_the_values_come():
    """A format-7 table is a format-8 one without settle_nr: it loads with its supplied states, and settle_nr reads
    2**30 - 1 s (SETTLING until the controller's values come, as format 7 did)."""
    ex = export_model(_doc(0))
    t7, t8 = parse_table(_older(ex.table, 7, 1)), parse_table(ex.table)
    assert t7.version == 7 and t7.tauc == t8.tauc and any(t7.tauc) and t7.Go == t8.Go
    assert t7.settle_nr == (1 << 30) - 1 == t8.settle_nr  # the document has no settle_without_record_s either


def test_settle_nr_is_the_documents_settle_time_without_the_record():
    doc = _doc(0)
    obs = doc["thermal"]["observer"]
    obs["settle_without_record_s"] = obs["settle_s"] + 1234.2
    t = parse_table(export_model(restamp(doc)).table)
    assert t.settle_nr == math.ceil(obs["settle_s"] + 1234.2) and t.settle_s == math.ceil(obs["settle_s"])
    # a time below settle_s, or one without a supplied state, is refused, naming the field
    obs["settle_without_record_s"] = obs["settle_s"] - 1.0
    with pytest.raises(ExportError, match=r"settle_without_record_s must be settle_s"):
        export_model(restamp(doc))
    plain = with_observer(restamp(dynamic_doc(random.Random(5), "direct", dt_s=15.0)), random.Random(5))
    plain["thermal"]["observer"]["settle_without_record_s"] = 10.0
    with pytest.raises(ExportError, match=r"settle_without_record_s belongs to an observer with states the controller supplies"):
        export_model(restamp(plain))
    # and the loader refuses a settle_nr without supplied states (an exporter/firmware mismatch)
    t8 = export_model(with_observer(restamp(dynamic_doc(random.Random(5), "direct", dt_s=15.0)), random.Random(5))).table
    bad = bytearray(t8)
    struct.pack_into("<i", bad, len(bad) - 4 - 4 * 4, 5)
    struct.pack_into("<I", bad, len(bad) - 4, zlib.crc32(bytes(bad[:-4])) & 0xFFFFFFFF)
    with pytest.raises(TableError, match=r"settle_nr 5 s with 0 supplied states"):
        parse_table(bytes(bad))


@pytest.mark.parametrize("edit, message", [
    (lambda th: th["observer"]["states"][0].update(source="controller", gains={}, bound=0.0),
     "only a lag of the spindle speed, its square or the feed"),
    (lambda th: th["observer"]["states"][-1].update(source="operator"), "source 'operator'"),
])
def test_export_refuses_a_supplied_state_that_is_not_the_controllers(edit, message):
    doc = copy.deepcopy(_doc(0))
    edit(doc["thermal"])
    with pytest.raises(ExportError, match=message):
        export_model(restamp(doc))


def test_export_refuses_more_supplied_states_than_the_board_takes():
    rng = random.Random(7)
    sig = ["T:T0", "spindle_krpm", "spindle_krpm", "spindle_krpm2", "spindle_krpm2", "feed_m_min"]
    doc = dynamic_doc(rng, "direct", dt_s=15.0, signals=sig)
    for t, tau in zip(doc["thermal"]["terms"], (600.0, 1800.0, 7200.0, 1800.0, 7200.0, 900.0)):
        t["tau_s"] = tau
    doc = with_supplied(with_observer(restamp(doc), random.Random(7)))
    with pytest.raises(ExportError, match="5 lag states are supplied by the controller .* at most 4"):
        export_model(doc)
