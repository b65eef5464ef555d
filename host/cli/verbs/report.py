"""tcomp report RUN... --out DIR [--model MODEL]: an ISO 230-3-style thermal drift report (docs/report.md).

DIR gets report.html, report.json (every figure) and the PNG plots the HTML shows, written together
(host/outputs.py). The figures are host/data/iso230.py's; residuals against a model are host/learning/residuals.py's,
the same as `tcomp predict` and `tcomp check` print.
"""
from __future__ import annotations

import argparse


CLAUSES = {
    "followed": [
        "ISO 230-3 Clause 7 (thermal distortion caused by moving linear axes): deviations at target positions "
        "measured repeatedly over time; per target the drift from the first measurement, its maximum and range; "
        "the change of the positioning error between the two end targets (the axis's thermal expansion); "
        "plots of the deviations against time per target",
        "before/after compensation: the same figures of the residual (measured - the model's prediction), "
        "which the standard allows for machines with thermal compensation",
        "ISO 230-3 Clause 5 (ETVE): the largest deviation range over the test, labelled ETVE only when the run "
        "has neither motion nor spindle (the machine stood still)",
    ],
    "not_followed": [
        "test conditions (machine warm-up state, feed at 50 % of the maximum, test duration until stabilisation, "
        "the environment's own record): the run folder does not record them; the report cannot check them",
        "the measuring set-up (fixture, positions of the sensors near the spindle and table, five-sensor "
        "set-up for tilts): tcomp reads one deviation per target, so tilts (angular deformation) are not reported",
        "measurement uncertainty (ISO/TR 230-9): not estimated",
        "Clause 6 (rotating spindles) and Clause 8 (rotary axes): not implemented",
    ],
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders (a thermal drift test each)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for report.html, report.json and the plots")
    p.add_argument("--model", help="model document: adds the figures after compensation (residual = measured - predicted)")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="use a model whose provenance.sha256 does not match its content, as tcomp predict does")


def run(args: argparse.Namespace) -> int:
    from host.outputs import Outputs

    with Outputs(list(args.runs) + ([args.model] if args.model else [])) as out:
        out.folder(args.out, "--out")
        _report(args, out)
        out.commit()
    print("wrote %s" % args.out)
    return 0


def _safe(text):
    return "".join(c if c.isalnum() else "_" for c in text)


def _report(args, out):
    import json
    import os

    import numpy as np

    from host.cli.predicting import load_checked_model, load_run_or_fail, predict_rows
    from host.data.iso230 import drift_figures, etve_applicable, groups
    from host.learning.residuals import per_channel

    model, provenance = (load_checked_model(args.model, args.allow_edited, "tcomp report") if args.model else (None, None))
    runs = [load_run_or_fail(p) for p in args.runs]
    folder = out.path(args.out)
    doc = {"format": "tcomp-report/1", "standard": "ISO 230-3 (style; docs/report.md)", "clauses": CLAUSES,
           "model": args.model, "model_provenance": provenance, "runs": []}
    for i, (path, run_) in enumerate(zip(args.runs, runs)):
        e = run_.errors
        ok, why = etve_applicable(run_)
        entry = {"run": path, "etve_applicable": ok, "etve_note": why, "groups": [], "plots": []}
        pred = predict_rows(model, args.model, run_, path) if model is not None else None
        if pred is not None:
            entry["residuals"] = per_channel(e, pred)
        entry["plots"].append(_plot_temperatures(run_, path, os.path.join(folder, "run%d_temperatures.png" % i)))
        for label, rows in groups(e):
            g = {"group": label, "before": drift_figures(e.time_s[rows], e.position_mm[rows], e.error_um[rows])}
            if pred is not None:
                used = rows[np.isfinite(pred[rows])]
                if used.size:
                    g["after"] = drift_figures(e.time_s[used], e.position_mm[used], e.error_um[used] - pred[used])
            base = "run%d_%s" % (i, _safe(label))
            g["plots"] = [_plot_drift(e, rows, pred, path, label, os.path.join(folder, base + "_drift.png")),
                          _plot_max_drift(g, path, label, os.path.join(folder, base + "_max_drift.png"))]
            entry["groups"].append(g)
            _print_group(path, g)
        doc["runs"].append(entry)
    with open(os.path.join(folder, "report.json"), "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=2)
        fh.write("\n")
    with open(os.path.join(folder, "report.html"), "w", encoding="utf-8") as fh:
        fh.write(_html(doc))


def _print_group(path, g):
    b = g["before"]
    line = "%s, %s: %d targets over %d times; max drift %.3f µm, max deviation range %.3f µm" % (
        path, g["group"], len(b["positions"]), b["times"], b["max_drift_um"], b["max_deviation_range_um"])
    if "positioning_change" in b:
        line += ", positioning change %.3f µm" % b["positioning_change"]["max_positioning_change_um"]
    if "after" in g:
        line += "; after compensation: max drift %.3f µm, range %.3f µm" % (g["after"]["max_drift_um"], g["after"]["max_deviation_range_um"])
    print(line)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_temperatures(run_, path, png):
    plt = _pyplot()
    t = run_.temperatures
    fig, ax = plt.subplots(figsize=(8, 4))
    for j, name in enumerate(t.names):
        ax.plot(t.time_s / 3600.0, t.values[:, j], lw=1, label=name)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("temperature (°C)")
    ax.set_title("%s: temperatures.csv, every sensor" % path, fontsize=9)
    ax.legend(fontsize=6, ncol=4)
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return _name(png)


def _plot_drift(e, rows, pred, path, label, png):
    import numpy as np

    from host.data.iso230 import drift_table

    plt = _pyplot()
    panels = [("measured deviation (before compensation)", e.error_um[rows])]
    if pred is not None and np.isfinite(pred[rows]).any():
        panels.append(("residual = measured - predicted (after compensation)", e.error_um[rows] - pred[rows]))
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4), squeeze=False, sharey=True)
    for ax, (what, v) in zip(axes[0], panels):
        times, targets, m = drift_table(e.time_s[rows], e.position_mm[rows], v)
        for j, p in enumerate(targets):
            col = m[:, j]
            ok = np.isfinite(col)
            if ok.any():
                first = col[np.flatnonzero(ok)[0]]
                ax.plot(times[ok] / 3600.0, col[ok] - first, lw=1, label="%g mm" % p)
        ax.set_xlabel("time (h)")
        ax.set_ylabel("drift from the first measurement (µm)")
        ax.set_title("%s, %s:\n%s at each target" % (path, label, what), fontsize=8)
        ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return _name(png)


def _plot_max_drift(g, path, label, png):
    import numpy as np

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    pos = np.array([p["position_mm"] for p in g["before"]["positions"]])
    width = (np.min(np.diff(pos)) if pos.size > 1 else 10.0) * 0.4
    ax.bar(pos - width / 2, [p["max_drift_um"] for p in g["before"]["positions"]], width, label="before compensation")
    if "after" in g:
        pa = np.array([p["position_mm"] for p in g["after"]["positions"]])
        ax.bar(pa + width / 2, [p["max_drift_um"] for p in g["after"]["positions"]], width, label="after compensation")
    ax.set_xlabel("target position (mm)")
    ax.set_ylabel("max |drift| over the test (µm)")
    ax.set_title("%s, %s: maximum drift at each target" % (path, label), fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return _name(png)


def _name(png):
    import os

    return os.path.basename(png)


def _html(doc):
    from html import escape

    def num(v):
        return "%.3f" % v if isinstance(v, float) else escape(str(v))

    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>tcomp thermal drift report</title>",
             "<style>body{font-family:sans-serif;max-width:1100px}table{border-collapse:collapse}"
             "td,th{border:1px solid #999;padding:2px 6px;text-align:right}</style></head><body>",
             "<h1>Thermal drift report, ISO 230-3 style</h1>",
             "<p>Model: %s (provenance %s). Figures in report.json; definitions in docs/report.md.</p>"
             % (escape(str(doc["model"] or "none: before compensation only")), escape(str(doc["model_provenance"]))),
             "<h2>Clauses followed</h2><ul>%s</ul>" % "".join("<li>%s</li>" % escape(c) for c in doc["clauses"]["followed"]),
             "<h2>Not followed</h2><ul>%s</ul>" % "".join("<li>%s</li>" % escape(c) for c in doc["clauses"]["not_followed"])]
    for entry in doc["runs"]:
        parts.append("<h2>%s</h2><p>%s</p>" % (escape(entry["run"]), escape(entry["etve_note"])))
        parts.append("<img src='%s' alt='temperatures'>" % escape(entry["plots"][0]))
        if "residuals" in entry:
            parts.append("<table><tr><th>channel</th><th>rows</th><th>RMSE µm</th><th>max residual µm</th>"
                         "<th>min residual µm</th><th>R²</th></tr>")
            for c, f in entry["residuals"].items():
                parts.append("<tr><td>%s</td><td>%d</td><td>%s</td><td>%s</td><td>%s</td><td>%s</td></tr>" % (
                    escape(c), f["rows"], num(f["rmse_um"]), num(f["max_residual_um"]), num(f["min_residual_um"]), num(f["r2"])))
            parts.append("</table>")
        for g in entry["groups"]:
            parts.append("<h3>%s</h3>" % escape(g["group"]))
            parts.append("<table><tr><th>target mm</th><th>measurements</th><th>max drift µm (before)</th>"
                         "<th>drift range µm (before)</th><th>max drift µm (after)</th><th>drift range µm (after)</th></tr>")
            after = {p["position_mm"]: p for p in g.get("after", {}).get("positions", [])}
            for p in g["before"]["positions"]:
                a = after.get(p["position_mm"])
                parts.append("<tr><td>%g</td><td>%d</td><td>%s</td><td>%s</td><td>%s</td><td>%s</td></tr>" % (
                    p["position_mm"], p["measurements"], num(p["max_drift_um"]), num(p["drift_range_um"]),
                    num(a["max_drift_um"]) if a else "-", num(a["drift_range_um"]) if a else "-"))
            parts.append("</table>")
            for key in ("before", "after"):
                f = g.get(key)
                if f and "positioning_change" in f:
                    pc = f["positioning_change"]
                    parts.append("<p>%s compensation: positioning error change between %g mm and %g mm: max %s µm; "
                                 "max deviation range %s µm%s</p>" % (
                                     key.capitalize(), pc["from_mm"], pc["to_mm"], num(pc["max_positioning_change_um"]),
                                     num(f["max_deviation_range_um"]), " (ETVE)" if entry["etve_applicable"] else ""))
            for png in g["plots"]:
                parts.append("<img src='%s' alt='%s'>" % (escape(png), escape(png)))
    parts.append("</body></html>\n")
    return "\n".join(parts)
