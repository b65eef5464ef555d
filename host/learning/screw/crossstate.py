"""Validation like the literature's: fit on one moving state, predict the others.

The screw model and empirical MLR slope models (host/learning/empirical, ``poly_slope``,
temperature rises referenced to each run's start like the screw model's E_e)
are fitted on the heating phase of one run (by default 8000 mm/min over
210–490 mm) and evaluated on every other run (other feeds, other ranges, a mixed
programme) and on the fitting run's own cool-down, which neither model saw.

    python -m host.learning.screw.crossstate FIT_RUN OTHER_RUN... --out DIR

writes DIR/validation.md (RMSE and max |residual| per state and model),
DIR/validation.json and DIR/validation.png.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import argparse
import json
import os
import sys

import numpy as np

from host.data.runs import load_run
from host.learning.screw.screwmodel import ScrewModel

if TYPE_CHECKING:
    from host.data.runs import Run


def _heating_end(run):
    return float(run.motion.t_end_s.max())


def fit_models(fit_run: Run, mlr_sensor_sets: Mapping[str, Sequence[str]] | None = None) -> dict[str, Any]:
    """{label: fitted model} on the heating phase of ``fit_run``."""
    t_end = _heating_end(fit_run)
    # E_e on: the bundled runs hold the frame's drift with the base (the twin's ambient_expansion), which E_e stands for
    models = {"screw (base sensor + motion)": ScrewModel(ambient=True, fit_window=(None, t_end)).fit([fit_run])}
    from host.learning.empirical.fitting import fit_model

    def first(role):
        return [s for s in fit_run.sensors_with_role(role) if s in fit_run.temperatures.names][:1]

    nut, base = first("nut"), first("base")
    # a heating phase gives one slope target per sweep (12 in the bundled runs), so
    # the larger set stays at one sensor per role rather than all sensors
    five = nut + base + first("ambient") + first("bearing") + first("motor")
    sets = mlr_sensor_sets or {"MLR slope (nut+base)": nut + base, "MLR slope (%s)" % "+".join(five): five}
    for label, sensors in sets.items():
        # run_start: rises from each run's own start, the same convention as the screw
        # model's E_e (the bundled runs start 0.3-1.3 K apart; "fixed" would penalise the MLR)
        models[label] = fit_model([fit_run], method="mlr", sensors=sensors, window=(0.0, t_end), reference="run_start")
    return models


def states(fit_run: Run, runs: Sequence[Run]) -> list[tuple[str, Run, np.ndarray, bool]]:
    """(state label, run, row indices, seen-in-training) for every evaluated state."""
    t = fit_run.errors.time_s
    t_end = _heating_end(fit_run)
    out = [("%s heating (fitted)" % fit_run.name, fit_run, np.flatnonzero(t <= t_end), True),
           ("%s cool-down" % fit_run.name, fit_run, np.flatnonzero(t > t_end), False)]
    for r in runs:
        out.append((r.name, r, np.arange(len(r.errors)), False))
    return [s for s in out if s[2].size]


def state_errors(models: Mapping[str, Any], fit_run: Run, runs: Sequence[Run]) -> list[dict[str, Any]]:
    rows = []
    for label, run, idx, seen in states(fit_run, runs):
        for name, model in models.items():
            pred = np.asarray(model.predict(run), dtype=float)[idx]
            res = run.errors.error_um[idx] - pred
            rows.append({"state": label, "model": name, "seen": seen, "rows": int(idx.size),
                         "rmse_um": float(np.sqrt(np.mean(res ** 2))), "max_abs_um": float(np.max(np.abs(res)))})
    return rows


def summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean RMSE over the unseen states per model."""
    out = {}
    for m in sorted({r["model"] for r in rows}):
        un = [r["rmse_um"] for r in rows if r["model"] == m and not r["seen"]]
        out[m] = {"mean_unseen_rmse_um": float(np.mean(un)), "worst_unseen_rmse_um": float(np.max(un))}
    return out


def markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    models = list(dict.fromkeys(r["model"] for r in rows))
    lines = ["| state | " + " | ".join("%s RMSE / max [µm]" % m for m in models) + " |",
             "|---|" + "---|" * len(models)]
    for st in dict.fromkeys(r["state"] for r in rows):
        cells = []
        for m in models:
            r = next(x for x in rows if x["state"] == st and x["model"] == m)
            cells.append("%.2f / %.2f" % (r["rmse_um"], r["max_abs_um"]))
        lines.append("| %s | %s |" % (st, " | ".join(cells)))
    return "\n".join(lines)


def plot(rows: Sequence[Mapping[str, Any]], models: Mapping[str, Any], fit_run: Run, runs: Sequence[Run], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["model"] for r in rows))
    sts = list(dict.fromkeys(r["state"] for r in rows))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 5))
    w = 0.8 / len(names)
    for j, m in enumerate(names):
        v = [next(x["rmse_um"] for x in rows if x["state"] == s and x["model"] == m) for s in sts]
        ax1.bar(np.arange(len(sts)) + j * w, v, w, label=m)
    ax1.set_xticks(np.arange(len(sts)) + 0.4 - w / 2)
    ax1.set_xticklabels(sts, rotation=30, ha="right", fontsize=8)
    ax1.set_ylabel("RMSE [µm]")
    ax1.set_title("fitted on %s heating phase" % fit_run.name)
    ax1.legend(fontsize=8)
    run = runs[-1] if runs else fit_run
    e = run.errors
    far = e.position_mm == e.position_mm.max()
    ax2.plot(e.time_s[far] / 3600, e.error_um[far], "k.", label="measured")
    for m in names:
        ax2.plot(e.time_s[far] / 3600, np.asarray(models[m].predict(run))[far], label=m)
    ax2.set_xlabel("time [h]")
    ax2.set_ylabel("error at P = %g mm [µm]" % e.position_mm.max())
    ax2.set_title("unseen state %s" % run.name)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host.learning.screw.crossstate", description=(__doc__ or "").split("\n\n")[0])  # None only under python -OO
    ap.add_argument("fit_run")
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    fit_run = load_run(a.fit_run)
    runs = [load_run(r) for r in a.runs]
    models = fit_models(fit_run)
    rows = state_errors(models, fit_run, runs)
    os.makedirs(a.out, exist_ok=True)
    md = markdown(rows)
    with open(os.path.join(a.out, "validation.md"), "w", encoding="utf-8") as fh:
        fh.write(md + "\n")
    with open(os.path.join(a.out, "validation.json"), "w", encoding="utf-8") as fh:
        json.dump({"rows": rows, "summary": summary(rows)}, fh, indent=2)
    plot(rows, models, fit_run, runs, os.path.join(a.out, "validation.png"))
    print(md)
    for m, s in summary(rows).items():
        print("%s: mean RMSE on unseen states %.2f um (worst %.2f um)" % (m, s["mean_unseen_rmse_um"], s["worst_unseen_rmse_um"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
