"""The screw's reduced state estimated from the nut sensor at power-on (issue 21, host/learning/screw/observer.py).

The runs are the bundled twin runs (data/demo, host/twin's own physics: the screw's heat, the nut housing the
sensor sits on, the sensors' lags), not runs of the reduced model: what the nut sensor says about the screw is
the twin's, and the observer is fitted and judged on it."""
import copy
import json
import warnings

import numpy as np
import pytest

from host.learning.documents import ModelFormatError
from host.learning.screw import observer as so
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import ScrewModel

TRAIN = ("v8000_r210_490", "v8000_r0_210", "v15000_r210_490", "v8000_r0_700")
UNSEEN = ("mixed", "v6500_r210_490")
RESTARTS_S = (1800, 3600, 5400, 7200, 10800)


@pytest.fixture(scope="module")
def fitted(demo_runs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return ScrewModel().fit([demo_runs[n] for n in TRAIN])


def test_the_fit_records_an_observer_from_the_nut_sensor(fitted):
    obs = fitted.observer_
    assert obs is not None, fitted.observer_note_
    assert (obs.sensor, obs.air) == ("T1", "T3")  # the demo runs' nut and ambient sensors
    assert fitted.observer_note_.startswith("observer: ")
    # the estimate starts closer than the cold start (fit_observer keeps it only then) and settles sooner
    assert obs.start_error_um < obs.cold_start_error_um
    assert obs.settle_s < obs.cold_settle_s
    # a machine at rest (the nut sensor at the air's rise) gets exactly the cold state: no constant term
    assert np.array_equal(obs.estimate(0.7, 0.0), np.full(obs.gains.size, 0.7))


def test_a_warm_restart_on_unseen_twin_runs_is_closer_to_the_uninterrupted_board_than_a_cold_start(fitted, demo_runs):
    """A reset at several points of unseen twin runs: the largest deviation from the uninterrupted board in the first
    30 min is smaller with the observer at every reset, and by at least half over all of them."""
    worst_obs, worst_cold = [], []
    for name in UNSEEN:
        for t_r in RESTARTS_S:
            el, d_obs = so.restart_deviation_um(fitted, demo_runs[name], t_r, fitted.observer_)
            _, d_cold = so.restart_deviation_um(fitted, demo_runs[name], t_r, None)
            first = el <= 1800
            assert d_obs[first].max() < d_cold[first].max(), (name, t_r)
            worst_obs.append(d_obs[first].max())
            worst_cold.append(d_cold[first].max())
    assert sum(worst_obs) < 0.5 * sum(worst_cold), (worst_obs, worst_cold)


def test_a_warm_restart_predicts_the_twins_measured_errors_better_than_a_cold_start(fitted, demo_runs):
    """Against the twin's own errors (its physics, laser noise 0.5 um), not the model's: RMSE over the error rows of
    the first hour after a reset, the restarted reduced board with and without the observer."""
    from host.learning.screw.reduced import reduced_error_um

    red = fitted.reduced_
    for name in UNSEEN:
        run = demo_runs[name]
        e = run.errors
        for t_r in (3600, 7200):
            rms = {}
            for label, obs in (("observer", fitted.observer_), ("cold", None)):
                ts, T, _ = so.restart(fitted, run, t_r, obs)
                rows = (e.time_s >= ts[0]) & (e.time_s <= ts[0] + 3600)
                k = np.clip(np.floor((e.time_s[rows] - ts[0]) / red["dt_s"] + 1e-9).astype(int), 0, ts.size - 1)
                pred = reduced_error_um(red, T[k], e.position_mm[rows]) + fitted.geometric_um(e.position_mm[rows])
                rms[label] = float(np.sqrt(np.mean((pred - e.error_um[rows]) ** 2)))
            assert rms["observer"] < 0.6 * rms["cold"], (name, t_r, rms)


def test_the_recorded_bound_holds_for_restarts_on_the_training_runs(fitted, demo_runs):
    """E_i is the largest residual on the training runs, so on them the deviation stays under B(t) at every step."""
    obs = fitted.observer_
    for name in TRAIN:
        for t_r in RESTARTS_S:
            el, d = so.restart_deviation_um(fitted, demo_runs[name], t_r, obs)
            bound = so.error_bound_um(fitted, obs.bound, el)
            assert np.all(d <= bound + 1e-9), (name, t_r, float(np.max(d - bound)))
    # the bound falls to the tolerance at settle_s, not before
    b = so.error_bound_um(fitted, obs.bound, np.array([obs.settle_s - fitted.reduced_["dt_s"], obs.settle_s]))
    assert b[0] > obs.tolerance_um >= b[1]
    assert so.error_bound_um(fitted, obs.bound, np.array([0.0]))[0] == pytest.approx(obs.start_error_um)


def test_the_observer_survives_the_document_and_bad_blocks_are_refused(fitted):
    doc = json.loads(json.dumps(fitted.to_document()))
    th = doc["thermal"]
    assert th["observer"]["method"] == "static_state_estimate" and th["observer_note"] == fitted.observer_note_
    back = ScrewModel.from_document(doc)
    assert np.array_equal(back.observer_.gains, fitted.observer_.gains)
    assert back.observer_.settle_s == fitted.observer_.settle_s
    bad = copy.deepcopy(doc)
    bad["thermal"]["observer"]["gains_K_per_K"] = bad["thermal"]["observer"]["gains_K_per_K"][:-1]
    with pytest.raises(ModelFormatError, match=r"thermal\.observer\.gains_K_per_K must list 12 finite numbers"):
        ScrewModel.from_document(bad)
    bad = copy.deepcopy(doc)
    bad["thermal"]["observer"]["bound_K"][3] = -1.0
    with pytest.raises(ModelFormatError, match=r"thermal\.observer\.bound_K must be >= 0"):
        ScrewModel.from_document(bad)
    # documents written before the observer load without one
    old = copy.deepcopy(doc)
    del old["thermal"]["observer"], old["thermal"]["observer_note"]
    assert ScrewModel.from_document(old).observer_ is None


def test_no_nut_sensor_gives_no_observer_and_says_so(demo_runs):
    from host.cli.fit_screw import format_report

    runs = []
    for n in TRAIN[:2]:
        r = copy.copy(demo_runs[n])
        r.meta = copy.deepcopy(r.meta)
        r.meta["sensors"]["T1"]["role"] = "structure"  # the nut sensor is no longer declared as one
        runs.append(r)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        m = ScrewModel().fit(runs)
    assert m.observer_ is None
    doc = m.to_document()
    assert doc["thermal"]["observer"] is None
    assert doc["thermal"]["observer_note"].startswith("no observer: no screw-side sensor (role 'nut'")
    assert doc["thermal"]["observer_note"] in format_report(m)



def test_export_carries_the_observer_into_the_table(fitted, tmp_path, capsys):
    """Table format 6 carries the screw observer (issue 21): the nut sensor is a table input, the gains and settle_s
    are in the table, the certificate has the integer start's figure, and `tcomp export` does not warn."""
    import math

    from firmware.table import parse_table
    from host.cli import main
    from models_export.export import export_model

    doc = json.loads(json.dumps(fitted.to_document()))
    ex = export_model(doc)
    status = ex.report["screw"]["observer"]
    assert status["in_document"] and status["carried"] and "reason" not in status
    assert status["settle_s"] == fitted.observer_.settle_s and status["table_settle_s"] == math.ceil(fitted.observer_.settle_s)
    cert = status["certificate"]
    assert 0 < cert["start_error_K"] < 1e-3 and 0 < cert["start_error_um"] < 0.01
    t = parse_table(ex.table)
    assert t.version == 8 and t.obs == 1 and t.settle_s == math.ceil(fitted.observer_.settle_s)
    assert t.sensors[t.sn] == "T1" and t.sensors[t.sr] == "T3" and "T1" not in doc["sensors"]
    assert all(g > 0 for g in t.Gn)  # every segment warms with the nut (the fit's gains are all positive)
    path = tmp_path / "screw.json"
    path.write_text(json.dumps(doc))
    assert main(["export", str(path), "--out", str(tmp_path / "t.bin"), "--report", str(tmp_path / "r.json")]) == 0
    assert "thermal.observer" not in capsys.readouterr().err
    assert json.loads((tmp_path / "r.json").read_text())["screw"]["observer"]["carried"] is True


def test_the_boards_integer_start_equals_the_hosts_estimate_within_the_certificate(fitted):
    """firmware/evaluate.py's Evaluator.estimate (CPython, checking mode) on generated states: every temperature inside
    the certified envelope, the references latched anywhere in it (base_ref run_start), against the host's
    ScrewObserver.estimate in floats. Where the host's estimate lies inside the state bounds the board is within the
    certified start error; every intermediate stays inside the exporter's intervals."""
    import random

    from firmware.evaluate import ACC_NMUL, ACC_NSUM, Evaluator
    from firmware.table import parse_table
    from models_export.export import export_model

    doc = json.loads(json.dumps(fitted.to_document()))
    ex = export_model(doc)
    cert = ex.report["screw"]["observer"]["certificate"]
    t = parse_table(ex.table)
    assert t.ref_mode == 1 and t.air == t.sr  # the demo model's air sensor T3 is the observer's reference sensor
    obs = fitted.observer_
    ev = Evaluator(t, check=True)
    rng = random.Random(21)
    worst, inside = 0.0, 0
    for k in range(400):
        for i in range(t.n_sensors):
            ev.temps[i] = rng.randint(t.env_lo[i], t.env_hi[i])
        ev.latch_references()
        for i in range(t.n_sensors):  # near the references half the time: the usual warm restart
            lo, hi = (t.env_lo[i], t.env_hi[i]) if k % 2 else (max(t.env_lo[i], ev.ref[i] - 3000), min(t.env_hi[i], ev.ref[i] + 15000))
            ev.temps[i] = rng.randint(lo, hi)
        ev.update()
        ev.estimate()
        d = [(ev.temps[i] - ev.ref[i]) / 1000.0 for i in range(t.n_sensors)]
        host = obs.estimate(d[t.air], d[t.sn] - d[t.sr]) * (1 << t.ft)
        for i in range(t.M):
            if t.Tlo <= host[i] <= t.Tmax:
                inside += 1
                worst = max(worst, abs(ev.T[i] - host[i]) / (1 << t.ft))
    assert inside > 1000 and 0 < worst <= cert["start_error_K"]
    for acc in (ACC_NMUL, ACC_NMUL + 1, ACC_NSUM):
        assert ex.accs[acc][0] <= ev.lo[acc] <= ev.hi[acc] <= ex.accs[acc][1], acc


def test_a_format_5_table_still_loads_and_starts_cold(fitted):
    """A table written before format 6 (the same words without the screw observer's) loads, without an observer."""
    import struct
    import zlib

    from firmware.evaluate import Evaluator
    from firmware.table import parse_table
    from models_export.export import export_model

    doc = json.loads(json.dumps(fitted.to_document()))
    doc["thermal"]["observer"] = None
    b = bytearray(export_model(doc).table)
    t6 = parse_table(bytes(b))
    nw = 7 + 3 * t6.M  # obs settle_s sn sr Rn Lr nr, Gn shGn rN per segment, before the 3 certificate words
    end = len(b) - 4 - 12
    del b[end - 4 * nw:end]
    b[4] = 5
    struct.pack_into("<I", b, 8, len(b))
    struct.pack_into("<I", b, 52, struct.unpack_from("<I", b, 52)[0] - nw)
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])))
    t5 = parse_table(bytes(b))
    assert t5.version == 5 and t5.obs == 0 and t5.C == t6.C and t5.cert_out == t6.cert_out
    ev = Evaluator(t5)
    ev.estimate()  # no observer: the cold start
    assert ev.T == [ev.T[0]] * t5.M


def test_a_document_without_the_nut_envelope_keeps_the_observer_out_and_says_so(fitted, tmp_path, capsys):
    """A document fitted before the table carried the observer has no envelope for its nut sensor: the export leaves
    the observer out and says why (a warning naming the settle times); nothing is guessed. A document without an
    observer has its note in the certificate and no warning."""
    from host.cli import main
    from models_export.export import export_model

    doc = json.loads(json.dumps(fitted.to_document()))
    del doc["envelope"]["temperature_C"]["T1"]
    status = export_model(doc).report["screw"]["observer"]
    assert status["in_document"] and not status["carried"] and "certificate" not in status
    assert "re-fit the model" in status["reason"] and "starts the screw cold" in status["reason"]
    path = tmp_path / "screw.json"
    path.write_text(json.dumps(doc))
    assert main(["export", str(path), "--out", str(tmp_path / "t.bin"), "--report", str(tmp_path / "r.json"),
                 "--allow-edited"]) == 0
    err = capsys.readouterr().err
    assert "WARNING: thermal.observer (screw state from T1 at power-on" in err and "is not in the table" in err
    doc["thermal"]["observer"] = None
    doc["thermal"]["observer_note"] = "no observer: test"
    assert export_model(doc, allow_edited=True).report["screw"]["observer"] == {
        "in_document": False, "carried": False, "note": "no observer: test"}


def test_a_training_run_without_the_nut_column_gives_no_observer_not_a_failed_fit(demo_runs):
    """The nut sensor is optional for the screw model: a run that lacks its column leaves the fit as it was and the
    document says why there is no observer."""
    from host.data.runs import Temperatures

    a, b = copy.copy(demo_runs[TRAIN[0]]), copy.copy(demo_runs[TRAIN[1]])
    tt = b.temperatures
    keep = [i for i, n in enumerate(tt.names) if n != "T1"]
    b.temperatures = Temperatures(tt.time_s, [tt.names[i] for i in keep], tt.values[:, keep])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        m = ScrewModel().fit([a, b])
    assert m.observer_ is None
    assert m.observer_note_.startswith("no observer: training run ") and "no column for sensor T1" in m.observer_note_
