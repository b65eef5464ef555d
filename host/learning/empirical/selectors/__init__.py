"""Temperature-sensor selection (issue 3): which few sensors a thermal model should use.

One entry point for every method, used by ``tcomp select`` and ``tcomp compare``::

    from host.learning.empirical.selectors import select
    sel = select(method, data, *, target="slope", channel=None, sensors=None, **params)
    sel.sensors   # list of chosen sensor names, in the data's column order
    sel.method    # "maxtree" | "stepwise" | "hclust-ga"
    sel.reason    # JSON-able dict: the numbers behind the choice
    sel.plot(path)  # writes a PNG whose title says which data it shows

``data`` is either

* a list of :class:`host.data.runs.Run` -- turned into arrays with
  ``host.learning.empirical.targets.training_arrays(runs, target=target, channel=channel,
  sensors=sensors)``, or
* a list of ``(X, y, names)`` tuples, one per run (``X`` (n, p) temperatures,
  ``y`` (n,) target, ``names`` the p sensor names, identical in every run), or a
  single ``(X, y, names)`` tuple (one run).

Methods (docs/selection.md has the criteria and thresholds):

``"maxtree"``
    fuzzy clustering by the maximal-tree method on the pooled runs; params
    ``alpha=0.05`` (F-test level), ``criterion="paper"`` (Li 2021: the largest
    R² among significant sets whose variables pass SPSS's tolerance
    ``min_tolerance=0.0001``), ``"r2-change"`` (R² gains accepted by the F test,
    coarse to fine) or ``"tolerance"`` (with ``r2_tolerance=0.01``:
    R² slack before F decides), ``max_sensors=None``, ``absolute=True``
    (similarity |r| rather than r).  :func:`maximal_tree` is the same method on a precomputed
    correlation matrix.
``"stepwise"``
    stepwise regression with partial F on the pooled runs (the estimator of
    ``host.learning.empirical.regression``); params ``f_enter=100``, ``f_remove=50``.
``"hclust-ga"``
    hierarchical clustering on D = a*D_e + (1-a)*D_r with a and the number of
    clusters chosen by a seeded binary GA whose fitness is robustness (fit on
    ``train_run``, predict the other runs with a 0.5 °C disturbance, mean RMSE).
    Needs >= 3 runs; with exactly 2 runs it falls back to predicting the one
    other run (``reason["fallback"]`` says so); 1 run raises.  Params
    ``seed=0``, ``population=20``, ``crossover=0.8``, ``mutation=0.005``,
    ``generations=20``, ``disturbance_C=0.5``, ``disturbance="uniform"``,
    ``train_run=0``, ``max_clusters=10``, ``max_combinations=20000``,
    ``alpha=None``/``k=None`` (fix the distance weight / cluster count: the
    paper's comparison groups), ``distance_on="values"`` (or ``"rises"``),
    ``normalisation="max"`` (or ``"minmax"``), ``intercept=False`` (Eq. 16).

Errors in the data (NaN, a constant sensor, fewer samples than parameters, too
few runs, unknown method or parameter) raise :class:`SelectionError` with a
message naming the sensor, run or parameter.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from host.learning.empirical.selectors.common import Selection, SelectionError

from host.learning.empirical.methods import SELECTORS as METHODS  # the registry's

if TYPE_CHECKING:
    from host.learning.empirical.selectors.maxtree import MaxTree


def select(method: str, data: Any, *, target: str = "slope", channel: str | None = None, sensors: Sequence[str] | None = None, **params: Any) -> Selection:
    """Run one selection method on runs or arrays; returns a :class:`Selection`."""
    from host.learning.empirical.selectors.common import as_arrays

    if method not in METHODS:
        raise SelectionError("unknown selection method %r (known: %s)" % (method, ", ".join(METHODS)))
    arrays, labels = as_arrays(data, target=target, channel=channel, sensors=sensors)
    context = {"target": target, "channel": channel, "runs": labels}
    if method == "maxtree":
        from host.learning.empirical.selectors.maxtree import select_maxtree as fn
    elif method == "stepwise":
        from host.learning.empirical.selectors.stepwise import select_stepwise as fn
    else:
        from host.learning.empirical.selectors.hclust_ga import select_hclust_ga as fn
    return fn(arrays, context=context, **params)


def maximal_tree(corr: Any, names: Sequence[str], target_corr: Any = None, absolute: bool = True) -> MaxTree:
    """Maximal-tree fuzzy clustering of a precomputed correlation matrix.

    Returns :class:`host.learning.empirical.selectors.maxtree.MaxTree` with ``edges``
    ``[(name_a, name_b, weight)]`` in Prim order from sensor 1, ``partitions``
    (every distinct partition with its λ interval and representatives) and
    ``to_json()``.
    """
    from host.learning.empirical.selectors.maxtree import maximal_tree as fn

    return fn(corr, names, target_corr=target_corr, absolute=absolute)
