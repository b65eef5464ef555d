"""Settle-bounded structure choice of the dynamic model (option settle_max_s; host/learning/empirical/settle.py).

The synthetic machine is written here, independently of the model's filters (exactlag.py): a structure sensor t1
warmed by the spindle, and a sensor t3 that drifts on its own (two slow sines). The error follows a 30 min lag of t1
and, strongly, a 4 h lag of t3. What a 4 h lag of t3 holds depends on t3's last hours, which nothing the board
reads at switch-on says (t3 now, t1, the spindle): a structure that uses it keeps the observer's start-error bound
above 1 um for hours.
"""
import numpy as np
import pytest

from host.cli import main
from host.data.runs import Errors, Run, Spindle, Temperatures, write_run
from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.fitting import fit_model
from host.learning.empirical.observer import fit_observer

from exactlag import exact_lag  # test-side physics, beside these tests

REF_C = 22.0
DT = 60.0
BOUND_S = 1800.0
# the bound on the observer alone (every state estimated from the sensors), as these tests were built; the bound with
# the controller's record: test_emp_controller.py
SETTINGS = {"taus_s": (0, 1800, 3600, 14400), "forward_blocks": 4, "spindle_states": "observer"}


def _machine(hours=24.0):
    t = np.arange(0.0, hours * 3600.0, DT)
    rpm = np.zeros(t.size)
    for k, speed in enumerate((1000, 3000, 2000, 4000, 2500, 3500)):
        rpm[(t >= 14400 * k + 600) & (t < 14400 * k + 7800)] = speed
    krpm = rpm / 1000.0
    t1 = REF_C + 1.5 * exact_lag(krpm, 7200.0, DT)
    t3 = REF_C + 2.0 * np.sin(2 * np.pi * t / 18000.0) + 1.0 * np.sin(2 * np.pi * t / 46800.0)
    err = 3.0 * exact_lag(t1 - REF_C, 1800.0, DT) + 6.0 * exact_lag(t3 - REF_C, 14400.0, DT)
    temps = Temperatures(t, ["t1", "t3"], np.column_stack([t1, t3]))
    errors = Errors(t.copy(), np.zeros(t.size), err, None, np.array(["ch1"] * t.size, dtype=object))
    meta = {"format": "tcomp-run/1", "axis": "Z", "sensors": {"t1": {"role": "structure"}, "t3": {"role": "ambient"}}}
    return Run(meta, temps, errors, spindle=Spindle(t.copy(), rpm), name="machine")


@pytest.fixture(scope="module")
def run():
    return _machine()


def test_a_structure_with_an_unobservable_long_lag_is_refused(run):
    free = fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=None, **SETTINGS)
    # without the bound the search takes the 4 h lag of t3, and its observer settles only after hours
    assert ("T:t3", 14400.0) in free.terms and free.observer.settle_s > 4 * BOUND_S
    assert "settle_bound" not in free.statistics
    bounded = fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=BOUND_S, **SETTINGS)
    assert bounded.observer.settle_s <= BOUND_S
    assert ("T:t3", 14400.0) not in bounded.terms
    record = bounded.statistics["settle_bound"]
    assert record["settle_max_s"] == BOUND_S and record["structures_refused"] >= 1
    assert record["structures_refused"] <= record["structures_checked"]
    # the structure refused scored better than the one chosen: the bound cost the selection's own score
    assert record["best_refused_score_um"] < bounded.estimator_.cv_rmse_
    # the recorded settle_s is the document's, and an observer refitted independently on the training span agrees
    assert record["settle_s"] == bounded.observer.settle_s == bounded.to_document()["thermal"]["observer"]["settle_s"]
    assert fit_observer(bounded, [run]).settle_s == bounded.observer.settle_s


def test_off_is_the_search_without_bound(run):
    free = fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=None, **SETTINGS)
    for off in (None, 0, "none"):
        same = fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=off, **SETTINGS)
        assert same.terms == free.terms and "settle_bound" not in same.statistics


def test_a_structure_without_lags_settles_at_once(run):
    # only static terms (the static fallback's kind of structure): no state to recover, settle_s 0, nothing refused
    static = fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=1.0, taus_s=(0,), forward_blocks=4)
    assert all(tau == 0 for _, tau in static.terms)
    assert static.observer.settle_s == 0.0
    assert static.statistics["settle_bound"]["settle_s"] == 0.0 and static.statistics["settle_bound"]["structures_refused"] == 0


@pytest.mark.parametrize("value", [-1, -0.5, float("nan"), float("inf"), True, "soon", [1800]])
def test_bad_settle_max_is_refused_by_name(run, value):
    with pytest.raises(EmpiricalDataError, match="settle_max_s must be a finite number of seconds >= 0"):
        fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=value, **SETTINGS)


def test_settle_max_needs_the_observer(run):
    with pytest.raises(EmpiricalDataError, match="settle_max_s.*observer=true"):
        fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=BOUND_S, observer=False, **SETTINGS)


def test_settle_max_is_not_combined_with_structure_averaging(run):
    # the averaged union carries an observer the bound never checked: refused by name, not silently unbounded
    with pytest.raises(EmpiricalDataError, match="settle_max_s and average_structures > 1 cannot be combined"):
        fit_model([run], "dynamic", target="direct", channel="ch1", settle_max_s=BOUND_S, average_structures=2, **SETTINGS)


def test_tcomp_fit_takes_the_option_and_prints_the_bound(run, tmp_path, capsys):
    path = str(tmp_path / "machine")
    write_run(run, path)
    out = str(tmp_path / "m.json")
    assert main(["fit", path, "--model", "dynamic", "--direct", "--channel", "ch1", "--option", "taus_s=0/1800/3600/14400",
                 "--option", "forward_blocks=4", "--option", "settle_max_s=1800", "--out", out]) == 0
    text = capsys.readouterr().out
    assert "settle bound: only structures with settle_s <= 30 min admitted" in text and "refused" in text
    assert main(["fit", path, "--model", "dynamic", "--direct", "--channel", "ch1", "--option", "settle_max_s=-5",
                 "--out", str(tmp_path / "bad.json")]) != 0
    assert "settle_max_s" in capsys.readouterr().err
