"""Outputs of the discrepancy workflow: JSON, the final model document, plots, a Markdown report."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import json
import math
import os

import numpy as np

from host.learning.discrepancy.localize import residual_map

if TYPE_CHECKING:
    from host.learning.discrepancy.workflow import Result


def final_model_document(result: Result) -> dict[str, Any]:
    """The model document of the workflow's final fit: host/learning/screw's ScrewModel with the named effects,
    fitted on every run (its reduced firmware form included), with the held-out figures that validated it."""
    model = result.final_fit
    if model is None or not hasattr(model, "to_document"):
        raise ValueError("the workflow's final fit is not a screw model document")
    doc = model.to_document()
    doc.setdefault("training", {})
    doc["training"]["discrepancy"] = {
        "effects": list(result.effects),
        "rmse_before_um": result.before.rmse(),
        "rmse_after_um": result.after.rmse(),
        "held_out_parameters": dict(model.values_),  # as before: the final fit's parameter values
    }
    return doc


def write_json(result: Result, path: str, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    out = result.as_json()
    if extra:
        out.update(extra)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(out, fh, indent=2)
        fh.write("\n")
    return out


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_residual_maps(result: Result, path: str) -> None:
    """Held-out residual over sweep time x position, per run (rows) before/after (columns)."""
    plt = _plt()
    runs = result.runs
    fig, axes = plt.subplots(len(runs), 2, figsize=(10, 2.6 * len(runs) + 0.8), squeeze=False, layout="constrained")
    fig.suptitle("held-out residual; after = base + %s" % (", ".join(result.effects) or "nothing (no effect named)"), fontsize=10)
    allr = np.concatenate(result.before.residuals + result.after.residuals)
    lim = float(np.nanmax(np.abs(allr))) if np.isfinite(allr).any() else 1.0
    im = None
    for i, run in enumerate(runs):
        for j, (label, ho) in enumerate((("before", result.before), ("after", result.after))):
            ax = axes[i][j]
            maps = residual_map(run, ho.residuals[i])
            d = 1 if 1 in maps else sorted(maps)[0]
            t, p, grid = maps[d]
            im = ax.pcolormesh(p, t / 3600.0, grid, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="nearest")
            if run.motion is not None and len(run.motion):
                ax.axhline(float(np.max(run.motion.t_end_s)) / 3600.0, color="k", lw=0.8, ls="--")
                if j == 0:
                    _label_states(ax, run.motion)
            ax.set_title("%s, %s%s" % (run.name, label, "" if d == 0 else " (direction %+d)" % d), fontsize=9)
            ax.set_xlabel("position [mm]")
            ax.set_ylabel("time [h]")
    if im is not None:
        fig.colorbar(im, ax=axes, label="held-out residual [um]", shrink=0.8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _label_states(ax, m):
    """Name each moving state where it starts (the dashed line marks the start of the cool-down)."""
    last = None
    for i in range(len(m)):
        state = (m.feed_mm_min[i], min(m.from_mm[i], m.to_mm[i]), max(m.from_mm[i], m.to_mm[i]))
        if state != last:
            ax.text(0.01, m.t_start_s[i] / 3600.0, "%g mm/min %g-%g" % state, transform=ax.get_yaxis_transform(),
                    fontsize=6, va="bottom", bbox={"facecolor": "white", "alpha": 0.6, "lw": 0, "pad": 1})
            last = state


def evidence(result: Result) -> list[dict[str, Any]]:
    """Per named effect: the round, where the residual was, what improved."""
    out = []
    for k, rnd in enumerate(result.rounds):
        if not rnd.accepted:
            continue
        after = result.rounds[k + 1].localization if k + 1 < len(result.rounds) else []
        share_after = {d["factor"]: d["share"] for d in after}
        top = rnd.localization[:3]
        for c in rnd.candidates:
            if not c.accepted:
                continue
            out.append({
                "effect": c.name,
                "round": k + 1,
                "rmse_before_um": rnd.rmse_before_um,
                "rmse_after_um": rnd.rmse_after_um,
                "score": c.score,
                "p_value": c.p_value,
                "joint_with": c.joint_with,
                "where": [{"factor": d["factor"], "share_before": d["share"], "worst": d["worst"],
                           "share_after": share_after.get(d["factor"])} for d in top],
            })
    return out


def plot_error_curves(result: Result, family: Any, path: str) -> None:
    """Measured error and held-out predictions (base, final) at a few sweeps per run."""
    plt = _plt()
    runs = result.runs
    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 3.6), squeeze=False)
    for i, run in enumerate(runs):
        ax = axes[0][i]
        e = run.errors
        times = np.unique(e.time_s)
        pick = times[np.linspace(0, times.size - 1, min(4, times.size)).round().astype(int)]
        for k, ts in enumerate(pick):
            sel = (e.time_s == ts) & ((e.direction == 1) if e.direction is not None else True)
            o = np.argsort(e.position_mm[sel])
            P = e.position_mm[sel][o]
            color = "C%d" % k
            ax.plot(P, e.error_um[sel][o], "o", ms=3, color=color, label="measured %.1f h" % (ts / 3600))
            ax.plot(P, (e.error_um - result.before.residuals[i])[sel][o], ":", color=color)
            ax.plot(P, (e.error_um - result.after.residuals[i])[sel][o], "-", color=color)
        ax.set_title("%s (dotted: base, solid: final; held-out)" % run.name, fontsize=8)
        ax.set_xlabel("position [mm]")
        ax.set_ylabel("error [um]")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def markdown(result: Result, js: dict[str, Any], model_path: str | None = None, model_error: str | None = None) -> str:
    lines = ["# Discrepancy report", ""]
    lines.append("Runs: %s. Held-out scheme: %s." % (", ".join(r.name for r in result.runs),
                                                     "leave-one-run-out" if len(result.runs) > 1 else "two-block time split"))
    lines.append("")
    lines.append("**Named effects (in the order found):** %s" % (", ".join(result.effects) or "none: no catalog effect explains the gap"))
    lines.append("")
    lines.append("Held-out RMSE: %.3f um before, %.3f um after." % (result.before.rmse(), result.after.rmse()))
    lines.append("")
    if result.reference is not None:
        from host.learning.discrepancy import reference

        lines.append("**Error reference:** %s." % reference.report_line(result.reference))
        lines.append("")
    lines.append("| run | RMSE before [um] | RMSE after [um] |")
    lines.append("|---|---|---|")
    for r in js["per_run"]:
        lines.append("| %s | %.3f | %.3f |" % (r["run"], r["rmse_before_um"] or float("nan"), r["rmse_after_um"] or float("nan")))
    lines.append("")
    lines.append("## Evidence per named effect")
    for ev in js.get("evidence", []):
        lines.append("")
        lines.append("- **%s** (round %d%s): held-out RMSE %.3f -> %.3f um (%.0f %% less), DM p (Holm) %.2g." % (
            ev["effect"], ev["round"], ", jointly with " + ", ".join(ev["joint_with"]) if ev["joint_with"] else "",
            ev["rmse_before_um"], ev["rmse_after_um"], 100 * ev["score"], ev["p_value"]))
        for w in ev["where"]:
            lines.append("  - residual variance explained by %s: %.0f %%%s%s" % (
                w["factor"], 100 * w["share_before"], " (worst: %s)" % w["worst"] if w["worst"] else "",
                "" if w["share_after"] is None else ", after adding it %.0f %% of a smaller residual" % (100 * w["share_after"])))
    if not js.get("evidence"):
        lines.append("")
        lines.append("No catalog effect passed the test; the base model's gap is not explained by the catalog.")
    lines.append("")
    lines.append("## What is left")
    lines.append("")
    from host.learning.discrepancy import unexplained

    lines += unexplained.text(js.get("unexplained_all", []), result.after.rmse())
    for k, rnd in enumerate(result.rounds, 1):
        lines.append("")
        lines.append("## Round %d: base + %s (held-out RMSE %.3f um)" % (k, ", ".join(rnd.base_effects) or "nothing", rnd.rmse_before_um))
        lines.append("")
        lines.append("Where the residual concentrates (share of residual variance):")
        lines.append("")
        for loc in rnd.localization[:6]:
            lines.append("- %s: %.0f %%%s" % (loc["factor"], 100 * loc["share"], "" if not loc["worst"] else " (worst: %s)" % loc["worst"]))
        lines.append("")
        lines.append("| candidate | held-out RMSE [um] | gain | DM p (Holm) | accepted |")
        lines.append("|---|---|---|---|---|")
        for c in rnd.candidates:
            if c.skipped:
                lines.append("| %s | skipped: %s | | | |" % (c.name, c.skipped))
            elif c.error:
                lines.append("| %s | fit failed: %s | | | |" % (c.name, c.error))
            elif c.joint_with:
                lines.append("| %s | %.3f | %+.1f %% | %.3g | yes, jointly with %s (pair below) |" % (
                    c.name, c.single_rmse_um, 100 * c.single_score, c.single_p_value, ", ".join(c.joint_with)))
            else:
                lines.append("| %s | %.3f | %+.1f %% | %.3g | %s |" % (c.name, c.rmse_um, 100 * c.score, c.p_value, "yes" if c.accepted else ""))
        for c in rnd.candidates:
            if c.note:
                lines.append("")
                lines.append("Note on %s: %s." % (c.name, c.note))
        if rnd.pairs:
            lines.append("")
            lines.append("No single candidate passed; pairs tested jointly:")
            lines.append("")
            for c in rnd.pairs:
                if math.isfinite(c.rmse_um):
                    lines.append("- %s: held-out RMSE %.3f um, gain %+.1f %%, p (Holm) %.3g%s" % (c.name, c.rmse_um, 100 * c.score, c.p_value, ", accepted" if c.accepted else ""))
    lines.append("")
    if model_path:
        lines.append("Final model: `%s` (kind screw, docs/model-format.md)." % model_path)
    if model_error:
        lines.append("Final model could not be written: %s" % model_error)
    lines.append("")
    lines.append("Plots: `residual_map.png` (held-out residual before/after), `error_curves.png`.")
    return "\n".join(lines) + "\n"


def residual_diagnostic(result: Result, family: Any) -> Any:
    """host.learning.discrepancy.unexplained on the final model's held-out residual (all signals, strongest first)."""
    from host.learning.discrepancy import unexplained

    used = set()
    if hasattr(family, "used_sensors"):
        for r in result.runs:
            used |= family.used_sensors(r, result.effects)
    return unexplained.diagnose(result.runs, result.after.residuals, used)


def findings(result: Result, family: Any, model_path: str | None = None, model_error: str | None = None) -> dict[str, Any]:
    """The JSON fields beyond ``result.as_json()``: model, model_error, evidence, unexplained, unexplained_all."""
    from host.learning.discrepancy import unexplained

    from host.learning.discrepancy import reference

    diag = residual_diagnostic(result, family)
    return {**reference.json_fields(result.reference), "model": model_path, "model_error": model_error, "evidence": evidence(result),
            "unexplained": unexplained.summary(diag),
            "unexplained_all": [{k: d[k] for k in ("signal", "partial_r", "rmse_share", "rmse_share_heldout", "above_threshold", "where")}
                                for d in diag]}


def write_report(result: Result, family: Any, folder: str | None, json_path: str | None = None, shown_folder: str | None = None) -> dict[str, Any]:
    """JSON (``json_path``), model.json, plots and report.md in ``folder`` (None: the JSON alone); returns the JSON dict.

    ``shown_folder``: the folder's name as recorded in the report, when ``folder`` is a staging place.
    """
    if folder is None:
        extra = findings(result, family)
        if json_path:
            write_json(result, json_path, extra)
        js = result.as_json()
        js.update(extra)
        return js
    os.makedirs(folder, exist_ok=True)
    model_path, model_error = os.path.join(shown_folder or folder, "model.json"), None
    try:
        from host.learning.documents import save_model

        save_model(final_model_document(result), os.path.join(folder, "model.json"))
    except Exception as exc:  # the findings stand even when the final document cannot be built
        model_path, model_error = None, "%s: %s" % (type(exc).__name__, exc)
    extra = findings(result, family, model_path, model_error)
    js = result.as_json()
    js.update(extra)
    if json_path:
        write_json(result, json_path, extra)
    with open(os.path.join(folder, "discrepancy.json"), "w", encoding="utf-8") as fh:
        json.dump(js, fh, indent=2)
    plot_residual_maps(result, os.path.join(folder, "residual_map.png"))
    plot_error_curves(result, family, os.path.join(folder, "error_curves.png"))
    with open(os.path.join(folder, "report.md"), "w", encoding="utf-8") as fh:
        fh.write(markdown(result, js, model_path, model_error))
    return js
