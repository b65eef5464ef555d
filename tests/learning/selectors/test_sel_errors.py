"""Bad input to the selectors: every case gives an error naming what is wrong."""
import numpy as np
import pytest

from host.learning.empirical.selectors import SelectionError, select


def _base(n=30, p=4, seed=0):
    rng = np.random.default_rng(seed)
    X = np.cumsum(rng.normal(size=(n, p)), axis=0)
    y = X[:, 0] * 2 + rng.normal(scale=0.1, size=n)
    return X, y, ["A", "B", "C", "D"][:p]


@pytest.mark.parametrize("method", ["maxtree", "stepwise", "hclust-ga"])
def test_constant_sensor(method):
    runs = [_base(seed=s) for s in range(3)]
    X, y, names = runs[1]
    X = X.copy()
    X[:, 2] = 21.5
    runs[1] = (X, y, names)
    with pytest.raises(SelectionError, match=r"run 2: sensor\(s\) C are constant"):
        select(method, runs)


@pytest.mark.parametrize("method", ["maxtree", "stepwise", "hclust-ga"])
def test_nan_temperature_and_target(method):
    runs = [_base(seed=s) for s in range(3)]
    X = runs[2][0].copy()
    X[7, 1] = np.nan
    with pytest.raises(SelectionError, match="run 3: sensor B has a non-finite value .* at sample 8"):
        select(method, runs[:2] + [(X, runs[2][1], runs[2][2])])
    y = runs[0][1].copy()
    y[3] = np.inf
    with pytest.raises(SelectionError, match="run 1: the target has a non-finite value"):
        select(method, [(runs[0][0], y, runs[0][2])] + runs[1:])


def test_too_few_samples():
    X, y, names = _base()
    with pytest.raises(SelectionError, match="2 samples; at least 3"):
        select("maxtree", (X[:2], y[:2], names))
    with pytest.raises(SelectionError, match="run 1: 2 samples"):
        select("hclust-ga", [(X[:2], y[:2], names), (X, y, names)])
    # 4 samples of an unrelated target: only 1-2 sensor partitions leave residual degrees of
    # freedom, and none is significant
    noise = np.array([0.3, -1.2, 0.8, 0.1])
    with pytest.raises(SelectionError, match="no partition's representatives give a regression significant"):
        select("maxtree", (X[:4], noise, names))


def test_too_few_runs_and_mismatched_sensors():
    X, y, names = _base()
    with pytest.raises(SelectionError, match="hclust-ga needs runs"):
        select("hclust-ga", (X, y, names))
    with pytest.raises(SelectionError, match="same sensors in the same order"):
        select("maxtree", [(X, y, names), (X, y, names[::-1])])
    with pytest.raises(SelectionError, match="no runs given"):
        select("maxtree", [])


def test_shape_and_name_problems():
    X, y, names = _base()
    with pytest.raises(SelectionError, match="4 sensor names for 3"):
        select("maxtree", (X[:, :3], y, names))
    with pytest.raises(SelectionError, match="29 target values for 30"):
        select("maxtree", (X, y[:-1], names))
    with pytest.raises(SelectionError, match="appear more than once"):
        select("maxtree", (X, y, ["A", "B", "A", "D"]))
    with pytest.raises(SelectionError, match="has no sensor Z"):
        select("maxtree", (X, y, names), sensors=["A", "Z"])


def test_constant_target_unknown_method_and_parameter():
    X, y, names = _base()
    with pytest.raises(SelectionError, match="target is constant"):
        select("maxtree", (X, np.full_like(y, 3.0), names))
    with pytest.raises(SelectionError, match="unknown selection method 'pca'"):
        select("pca", (X, y, names))
    with pytest.raises(SelectionError, match=r"unknown parameter\(s\) f_entry"):
        select("stepwise", (X, y, names), f_entry=3)


def test_stepwise_refusal_and_collinear_sensors_are_clear():
    X, y, names = _base()
    with pytest.raises(SelectionError, match="no sensor reaches F_enter"):
        select("stepwise", (X, np.random.default_rng(5).normal(size=y.size), names))
    # an exact copy of the relevant sensor: stepwise takes one of them, never both
    Xc = np.column_stack([X, X[:, 0] * 1.0])
    sel = select("stepwise", (Xc, y, names + ["A2"]), f_enter=4.0, f_remove=2.0)
    assert not {"A", "A2"} <= set(sel.sensors)
    # maxtree puts the pair in one cluster at every λ < 1
    mt = select("maxtree", (Xc, y, names + ["A2"]))
    assert not {"A", "A2"} <= set(mt.sensors)


def test_selection_without_plot_data():
    from host.learning.empirical.selectors import Selection

    with pytest.raises(SelectionError, match="no plot data"):
        Selection(["A"], "manual", {}).plot("x.png")


@pytest.mark.parametrize(
    "method, params, message",
    [
        ("maxtree", {"alpha": "abc"}, "maxtree: alpha must be a number >= 0 and <= 1"),
        ("maxtree", {"alpha": 1.5}, "alpha must be"),
        ("maxtree", {"max_sensors": 0}, "max_sensors must be an integer >= 1"),
        ("maxtree", {"absolute": "yes"}, "absolute must be true or false"),
        ("stepwise", {"f_enter": -1}, "f_enter must be a number >= 0"),
        ("hclust-ga", {"seed": 1.5}, "seed must be an integer"),
        ("hclust-ga", {"generations": 0}, "generations must be an integer >= 1"),
        ("hclust-ga", {"mutation": 2}, "mutation must be a number >= 0 and <= 1"),
        ("hclust-ga", {"disturbance_C": float("nan")}, "disturbance_C must be"),
        # an integer beyond the float range (json.loads of 400 digits): numpy's isfinite raised a TypeError
        ("maxtree", {"max_sensors": 10 ** 400}, "max_sensors must be an integer >= 1, got 1000"),
        ("stepwise", {"f_enter": 10 ** 400}, "f_enter must be a number >= 0, got 1000"),
    ],
)
def test_bad_parameters_are_named(method, params, message):
    runs = [_base(seed=s) for s in range(3)]
    with pytest.raises(SelectionError, match=message):
        select(method, runs, **params)


def test_single_run_arrays_object_is_accepted():
    from host.learning.empirical.targets import RunArrays

    X, y, names = _base()
    sel = select("maxtree", RunArrays(X, y, names, np.arange(len(y)), "long-run"))
    assert sel.reason["samples"] == len(y)
