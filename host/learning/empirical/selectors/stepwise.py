"""Stepwise regression with partial F as a sensor selector.

The regression itself is :class:`host.learning.empirical.regression.Stepwise` (one
implementation for the model and the selector); this module runs it on the
pooled runs and reports the entry/removal history as the reason.
"""

from __future__ import annotations

from typing import Any

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.selectors.common import Selection, SelectionError, check_params, data_label, number, pooled

DEFAULTS = {"f_enter": 100.0, "f_remove": 50.0}


def select_stepwise(arrays: Any, context: dict[str, Any] | None = None, **params: Any) -> Selection:
    from host.learning.empirical.regression import Stepwise

    prm = check_params("stepwise", params, DEFAULTS)
    prm["f_enter"] = number("stepwise", "f_enter", prm["f_enter"], 0.0)
    prm["f_remove"] = number("stepwise", "f_remove", prm["f_remove"], 0.0)
    X, y, names = pooled(arrays)
    try:
        est = Stepwise(f_enter=float(prm["f_enter"]), f_remove=float(prm["f_remove"])).fit(X, y, names)
    except EmpiricalDataError as exc:
        raise SelectionError(str(exc)) from exc
    chosen = set(est.selected_names_)
    sensors = [s for s in names if s in chosen]
    stats = est.statistics()
    reason = {
        "criterion": "enter while the best partial F > f_enter, remove while the worst partial F <= f_remove (Fan & Guo 2017)",
        "f_enter": float(prm["f_enter"]),
        "f_remove": float(prm["f_remove"]),
        "entry_order": list(est.selected_names_),
        "history": est.history_,
        "r2": stats.get("r2", getattr(est, "rsquared_", None)),
        "samples": int(X.shape[0]),
        "statistics": stats,
    }
    label = data_label(context, X.shape[0])

    def plotter(path):
        _plot(path, est, prm, label)

    return Selection(sensors, "stepwise", reason, plotter)


def _plot(path, est, prm, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hist = est.history_
    fig, ax = plt.subplots(figsize=(max(6.0, 0.7 * len(hist) + 3), 4.5))
    xs = range(1, len(hist) + 1)
    colors = ["C0" if h["action"] == "enter" else "C3" for h in hist]
    ax.bar(xs, [h["F"] if h["F"] is not None else 0.0 for h in hist], color=colors)
    ax.set_xticks(list(xs))
    ax.set_xticklabels(["%s %s" % ("+" if h["action"] == "enter" else "−", h["sensor"]) for h in hist], rotation=45, ha="right")
    ax.axhline(prm["f_enter"], color="C0", ls="--", lw=0.8, label="F_enter = %g" % prm["f_enter"])
    ax.axhline(prm["f_remove"], color="C3", ls=":", lw=0.8, label="F_remove = %g" % prm["f_remove"])
    ax.set_yscale("log")
    ax.set_ylabel("partial F at the step")
    ax.legend(fontsize=8)
    ax.set_title("Stepwise sensor selection: R² = %.4f with %s\n%s" % (est.rsquared_, ", ".join(est.selected_names_), label), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
