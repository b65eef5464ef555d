"""``tcomp fit --model screw``: option parsing, fitting, the printed/JSON report.

Options (``--option KEY=VALUE``, repeatable): segments, dt_s, free (comma list of
q,h,lambda,c,alpha), geometric_degree (0..4 or auto), effects (comma list of
host/learning/screw/effects.py names), nut_weight, reduced_segments, reduced_dt_s,
feed_max_mm_min, ambient (on/off/auto: E_e, off by default under either error reference), air (auto, a sensor name, or off),
air_lag_s (the air sensor's time constant in s: the model takes the air the reading lags behind; 0 default), base_ref (run_start/fixed), max_nfev,
fit_window (LO:HI seconds, either side may be empty: fit only on error rows in it).  ``--sensors NAME`` picks the base
sensor of the E_e term (and switches E_e on unless ambient is given); ``--channel`` the errors.csv channel.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING
import json
import warnings

from host import options
from host.options import choice, number
from host.learning.screw.effects import make_effect
from host.learning.screw.identify import IdentifiabilityWarning
from host.learning.screw.screwmodel import MAX_AIR_LAG_S

if TYPE_CHECKING:
    from host.learning.screw.screwmodel import ScrewModel
    from host.outputs import Outputs

MAX_SEGMENTS = 1000  # full model; the reduced one is bounded by the table (32)
MIN_DT_S, MAX_DT_S = 0.1, 600.0
MAX_FEED_MM_MIN = 1e6  # 1 km/min, far above any machine-tool feed (rapid traverses reach ~1e5)


def _geometric_degree(text):
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise ValueError("expected 0..4 or auto")


def _fit_window(text):
    lo, colon, hi = text.partition(":")
    try:
        if not colon:
            raise ValueError
        return (float(lo) if lo.strip() else None, float(hi) if hi.strip() else None)
    except ValueError:
        raise ValueError("expected LO:HI in seconds (e.g. 0:10800 or :10800)")


def _ambient(text):
    """on, off, or auto (the default structure of the runs' error reference, docs/screw-model.md)."""
    v = choice("on", "off", "auto")(text)
    return "auto" if v == "auto" else v == "on"


def _effects(text):
    return [make_effect(n.strip()) for n in text.split(",") if n.strip()]


# --option KEY=VALUE settings of ScrewModel, with their converters (host/options.py)
# Bounds: segments and dt_s size the model's arrays (host/learning/screw/context.py checks their product too);
# reduced_segments and reduced_dt_s are what a table can hold (firmware/table.py: 1..32 segments, 1 ms..1 h);
# a feed is positive, a weight is not negative. The largest feed is at least MIN_FEED_MM_MIN: no machine tool's top
# feed is below 1 mm/min, and a subnormal one (2.2e-308, which `> 0` let through) is a typo, not a machine.
MIN_FEED_MM_MIN = 1.0
OPTIONS = {
    "segments": number(int, 2, MAX_SEGMENTS), "dt_s": number(float, MIN_DT_S, MAX_DT_S), "free": str,
    "geometric_degree": _geometric_degree, "effects": _effects, "nut_weight": number(float, 0.0, 1e6),
    "reduced_segments": number(int, 1, 32), "reduced_dt_s": number(float, 0.001, 3600.0),
    "feed_max_mm_min": number(float, MIN_FEED_MM_MIN, MAX_FEED_MM_MIN),
    "ambient": _ambient, "air": str,  # air: auto, a sensor name, or off
    "air_lag_s": number(float, 0.0, MAX_AIR_LAG_S),
    "max_nfev": number(int, 1, 100000), "base_ref": str, "fit_window": _fit_window,
}


def format_report(model: ScrewModel) -> str:
    st = model.statistics_
    if st is None:  # a model read from a document without statistics; fit always sets them
        raise ValueError("screw model: no fit statistics to report")
    lines = ["screw model: %d segments, dt %g s, geometric degree %d" % (model.geometry_.segments, model.dt_s, model.geometric_degree_),
             "  air: %s (%s)" % (model.air_sensor_ or "constant", model.air_source_),
             "  errors referred to: %s; E_e %s" % ("the machine at each run's start (raw)" if model.error_reference_ == "start"
                                                   else "sensor %s (E_m over its temperature)" % model.error_reference_,
                                                   "on (base sensor %s)" % model.base_sensor_ if model.base_sensor_ else "off")]
    for name, p in st["parameters"].items():
        if p.get("fixed"):
            lines.append("  %-22s %12.5g %-10s (fixed)" % (name, p["value"], p["unit"]))
        else:
            lines.append("  %-22s %12.5g %-10s ± %.3g (%.2f %%)" % (name, p["value"], p["unit"], p["std"], 100 * p["rel_std"]))
    for r in st["runs"]:
        nut = "no nut sensor" if r["nut_rise_rmse_K"] is None else "nut rise RMSE %.2f K" % r["nut_rise_rmse_K"]
        lines.append("  run %s: %d rows, RMSE %.3f um, max |residual| %.3f um, %s"
                     % (r["run"], r["rows"], r["rmse_um"], r["max_abs_residual_um"], nut))
    red = model.reduced_form()
    for run, e in red["reduction_error_um"].items():
        lines.append("  reduced (%d segments, dt %g s) vs full on %s: RMS %.3f um, max %.3f um (E_m); at the error rows "
                     "RMS %.3f um, max %.3f um" % (red["segments"], red["dt_s"], run, e["rms_um"], e["max_um"],
                                                   e.get("rows_rms_um", float("nan")), e.get("rows_max_um", float("nan"))))
    for name, why in (red.get("omitted_reasons") or {}).items():
        what = "option" if name == "air_lag_s" else "effect"  # the air sensor's lag is a setting, not a catalog effect
        lines.append("  WARNING: %s %s has no reduced form (%s): tcomp export refuses the model if leaving it out "
                     "costs more than its reduction limit" % (what, name, why))
    lines.append("  reduced state bound %.2f K at feed %g mm/min" % (red["state_max_K"], red["feed_max_mm_min"]))
    # the screw state at power-on without a trusted heat.bin (issue 21, host/learning/screw/observer.py)
    note = getattr(model, "observer_note_", None)
    if note:
        lines.append("  " + note)
    for w in st["warnings"]:
        lines.append("  WARNING: " + w)
    return "\n".join(lines)


def fit_command(args: argparse.Namespace, out: Outputs) -> int:
    """Fit, print the report, write ``args.out`` (and ``args.json``) through ``out`` (host.outputs.Outputs)."""
    from host.errors import UserError
    from host.learning.documents import save_model
    from host.data.runs import RunFormatError, load_runs
    from host.learning.screw.screwmodel import ScrewModel

    kw = options.parse_options(args.option, OPTIONS)
    if getattr(args, "direct", False) or getattr(args, "no_intercept", False):
        raise UserError("--direct/--no-intercept apply to the empirical models, not to --model screw")
    if args.sensors:
        names = [s.strip() for s in args.sensors.split(",") if s.strip()]
        if len(names) != 1:
            raise UserError("--model screw takes one --sensors name: the base sensor of the ambient term (got %s)" % args.sensors)
        kw["base_sensor"] = names[0]
        kw.setdefault("ambient", True)  # naming E_e's sensor asks for E_e
    try:
        runs = load_runs(args.runs)
    except RunFormatError as exc:
        raise UserError(str(exc))
    model = ScrewModel(channel=args.channel, **kw)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentifiabilityWarning)  # they are in the report
            model.fit(runs)
    except ValueError as exc:
        raise UserError(str(exc))
    doc = save_model(model.to_document(), out.path(args.out))
    print(format_report(model))
    if args.json:
        with out.open(args.json) as fh:
            json.dump({"model": args.out, "statistics": doc["statistics"], "reduced_error_um": model.reduced_form()["reduction_error_um"]}, fh, indent=2)
    return 0
