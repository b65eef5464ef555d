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



def test_export_says_the_table_does_not_carry_the_observer(fitted, tmp_path, capsys):
    """Table format 5 has no screw observer: the certificate says so, and `tcomp export` warns, naming the settle
    times; it does not drop the document's observer silently."""
    from host.cli import main
    from models_export.export import export_model

    doc = json.loads(json.dumps(fitted.to_document()))
    status = export_model(doc).report["screw"]["observer"]
    assert status["in_document"] and not status["carried"]
    assert "starts the screw cold" in status["reason"] and status["settle_s"] == fitted.observer_.settle_s
    path = tmp_path / "screw.json"
    path.write_text(json.dumps(doc))
    assert main(["export", str(path), "--out", str(tmp_path / "t.bin"), "--report", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert "WARNING: thermal.observer (screw state from T1 at power-on" in err and "is not in the table" in err
    assert json.loads((tmp_path / "r.json").read_text())["screw"]["observer"]["carried"] is False
    # a document without an observer: no warning, its note in the certificate
    doc["thermal"]["observer"] = None
    doc["thermal"]["observer_note"] = "no observer: test"
    assert export_model(doc).report["screw"]["observer"] == {"in_document": False, "carried": False, "note": "no observer: test"}


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
