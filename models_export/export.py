"""export_model: quantise + certify + pack; the report the CLI writes."""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from typing import Any
import math

from firmware.crc32 import crc32
from models_export.certify import DEFAULT_REDUCTION_LIMIT_UM, LIMITS_UM, OU_PER_UM, ExportError
from models_export.document import edited_reason, provenance
from models_export.exact import DEFAULT_ENVELOPE_MARGIN_K, Model
from models_export.plan import Planner
from models_export.tableformat import pack
# The ignore: firmware/table.py defines VERSION as a _NAME const (free on MicroPython) and publishes it under this
# name on CPython only (its globals() loop), which pyright cannot see
from firmware.table import VERSION  # pyright: ignore[reportAttributeAccessIssue]


class Export:
    """Result of export_model: ``table`` (bytes), ``fields`` (dict), ``report`` (dict), ``accs``
    ({accumulator: (lo, hi)} certified intervals of the firmware's checked accumulators, ACC_*), ``errors_ou``
    ({output: (lo, hi)} certified integer-minus-model intervals, output units)."""

    def __init__(self, fields: dict[str, Any], table: bytes, report: dict[str, Any], accs: dict[int, tuple[int, int]], errors_ou: dict[str, Any]) -> None:
        self.fields = fields
        self.table = table
        self.report = report
        self.accs = accs
        self.errors_ou = errors_ou

    def c_header(self, guard: str = "TCOMP_TABLE_H") -> str:
        from models_export.cheader import c_header

        return c_header(self, guard)


def _provenance(doc: dict[str, Any]) -> tuple[str, str | None]:
    """(sha256 of the document being exported, the recorded one or None). The table names the
    actual document; a recorded hash that differs means it was edited after it was saved."""
    return provenance(doc)


def reduction(doc: dict[str, Any], limit_um: float = DEFAULT_REDUCTION_LIMIT_UM) -> dict[str, Any] | None:
    """The certificate's reduction part for a screw document (None for other kinds): the reduced form the firmware
    evaluates against the full model the document was fitted as, on the training runs, from
    thermal.reduced.reduction_error_um (host/learning/screw/reduced.py reduction_certificate). Raises ExportError
    when it is missing or its worst RMS is above ``limit_um``, naming the run and the effects left out."""
    th = doc.get("thermal")
    if doc.get("kind") != "screw" or not isinstance(th, dict):
        return None
    red = th.get("reduced")
    if not isinstance(red, dict):
        return None
    if "parameters" not in th:  # a document of the reduced recurrence alone: it is its own full model
        return {"status": "reduced form only (no full model in the document): nothing reduced", "limit_um": limit_um,
                "rms_um": 0.0, "max_um": 0.0, "runs": {}, "omitted_effects": []}
    errs = red.get("reduction_error_um")
    if not isinstance(errs, dict) or not errs:
        raise ExportError("thermal.reduced.reduction_error_um is missing: the certificate cannot cover the reduction "
                          "of this screw model to the firmware's form; re-fit it with this tcomp")
    runs = {}
    try:
        for name, e in errs.items():
            fr = e.get("feed_range") or {}
            runs[name] = {"rms_um": max(float(e["rms_um"]), float(e.get("rows_rms_um", 0.0))),
                          "max_um": max(float(e["max_um"]), float(e.get("rows_max_um", 0.0))),
                          "feed_range_rms_um": max([float(fr[k]) for k in ("rms_um", "rows_rms_um") if k in fr] or [math.nan]),
                          "feed_range_max_um": max([float(fr[k]) for k in ("max_um", "rows_max_um") if k in fr] or [math.nan])}
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise ExportError("thermal.reduced.reduction_error_um: invalid entry (%s)" % exc)
    worst = max(runs, key=lambda n: runs[n]["rms_um"])
    omitted = list(red.get("omitted_effects") or [])
    reasons = red.get("omitted_reasons") or {}
    out = {"limit_um": limit_um, "rms_um": runs[worst]["rms_um"], "max_um": max(r["max_um"] for r in runs.values()),
           "worst_run": worst, "runs": runs, "omitted_effects": omitted,
           "measure": "RMS and max over the training runs of the full model minus the reduced form, E_m on 21 positions "
                      "at every step and the whole output at the error rows, position reports (feed/range mode beside)"}
    if not math.isfinite(runs[worst]["rms_um"]) or runs[worst]["rms_um"] > limit_um:
        left = ("; effects the firmware's form leaves out: %s" % "; ".join(
            "%s (%s)" % (n, reasons.get(n, "no reduced form")) for n in omitted)) if omitted else ""
        raise ExportError("thermal.reduced: the firmware's reduced form differs from the full model by %.3g um RMS "
                          "(max %.3g um) on training run %s, above the reduction limit %.3g um%s; the board would not "
                          "do what the host model does (raise --reduction-limit to export it anyway)"
                          % (runs[worst]["rms_um"], runs[worst]["max_um"], worst, limit_um, left))
    return out


def export_model(doc: dict[str, Any], ref_position_mm: float | None = None, limit_um: float | None = None, allow_edited: bool = False,
                 envelope: Mapping[str, tuple[float, float]] | None = None, margin_K: float = DEFAULT_ENVELOPE_MARGIN_K,
                 reduction_limit_um: float = DEFAULT_REDUCTION_LIMIT_UM) -> Export:
    """Quantise and certify ``doc`` (a tcomp-model/1 dict). Raises ExportError.

    A screw model's reduced form must be within ``reduction_limit_um`` (RMS on the training runs) of the full model
    (:func:`reduction`); the report states it beside the integer error.

    The certified temperature envelope (docs/firmware.md, "Operating envelope") is ``envelope``
    ({sensor: (lo_C, hi_C)}) where given, else the training range (the document's
    envelope.temperature_C) widened by ``margin_K`` on both sides.

    A document whose recorded ``provenance.sha256`` does not match its content is refused,
    unless ``allow_edited``: the table then carries the actual hash and the edited mark."""
    if not isinstance(doc, dict):
        raise ExportError("model document must be a JSON object")
    if not (isinstance(reduction_limit_um, (int, float)) and reduction_limit_um >= 0):
        raise ExportError("reduction limit must be a number of um >= 0 (got %r)" % (reduction_limit_um,))
    model = Model(doc, ref_position_mm, envelope=envelope, margin_K=margin_K)
    red_cert = reduction(doc, reduction_limit_um)
    planner = Planner(model)
    if model.direct:
        errs = planner.linear_direct()
    else:
        errs = planner.positional()
    f = planner.f
    actual, declared = _provenance(doc)
    verified = declared == actual
    edited = declared is not None and not verified
    prov = bytes.fromhex(actual)
    f.update(kind=model.kind, sensors=model.sensors, env_lo=model.env_lo, env_hi=model.env_hi, ref=model.ref,
             train_lo=model.train_lo, train_hi=model.train_hi, ref_mode=model.ref_mode, error_ref=model.error_ref,
             pos_lo=model.pos_lo, pos_hi=model.pos_hi, pos_ref=model.pos_ref, provenance=prov, edited=edited,
             axis=str(doc.get("axis") or "?"))
    try:
        table = pack(f)
    except ValueError as exc:
        raise ExportError("table: %s" % exc)
    if edited and not allow_edited:  # after the model's and the table's own checks, which name the field
        raise ExportError(edited_reason(declared, actual))
    rec = planner.rec
    limit = LIMITS_UM[model.kind] if limit_um is None else limit_um
    scale_um = 1.0 / OU_PER_UM
    max_err = _up(max(abs(errs["offset"][0]), abs(errs["offset"][1])) * scale_um) + 1e-9
    terms = []
    for t in planner.terms:
        terms.append({"name": t["name"], "scale": t["scale"], "headroom_bits": round(rec.headroom(t["key"]), 3),
                      "max_error_um": _up(t["err_ou"] * scale_um) if t["err_ou"] else 0.0})
    if max_err >= limit:
        worst = max(terms, key=lambda t: t["max_error_um"])
        raise ExportError("certified worst-case error %.4g um is not below %.4g um for %s; largest contribution: term %s "
                          "(%.4g um)" % (max_err, limit, model.kind, worst["name"], worst["max_error_um"]))
    peak = max(max(abs(lo), abs(hi)) for lo, hi in rec.accs.values())
    # the report's envelope (the certified one, in table units); the argument ``envelope`` is what the caller set
    certified: dict[str, Any] = {
        "temperature_mC": {s: [lo, hi] for s, lo, hi in zip(model.sensors, model.env_lo, model.env_hi)},
        "reference_mC": dict(zip(model.sensors, model.ref)),
        # the certified envelope above is the operating range; the model was fitted over this one: between the two
        # the firmware evaluates the model and reports EXTRAPOLATING, beyond the envelope it clamps (CLAMPED)
        "training_temperature_mC": {s: [lo, hi] for s, lo, hi in zip(model.sensors, model.train_lo, model.train_hi)},
        "temperature_source": {s: ("--envelope" if src == "set" else "training range +- %g K" % margin_K)
                               for s, src in zip(model.sensors, model.env_source)},
        "temperature_margin_K": margin_K,
        "reference_mode": "latched (any reference inside the envelope)" if model.ref_mode else "fixed",
    }
    if not model.direct:
        certified["position_um"] = [model.pos_lo, model.pos_hi]
        certified["reference_position_um"] = model.pos_ref
    report: dict[str, Any] = {
        "model_kind": model.kind,
        "document_kind": model.doc_kind,  # mr_poly is written as a dynamic table (models_export.exact.mr_poly_as_dynamic)
        # what the offsets compensate: the machine relative to its cold start, or to a workpiece at this sensor's temperature
        "error_reference": model.error_reference,
        "table_format": VERSION,  # the version byte of the table written (firmware/table.py owns it)
        "table_bytes": len(table),
        "crc32": "%08x" % crc32(table[:-4]),
        "units": {"offset": "0.01 um", "slope": "0.01 um/m", "temperature": "milli-degC", "position": "um"},
        "max_error_um": max_err,
        "limit_um": limit,
        "ref_offset_max_error_um": _up(max(map(abs, errs["ref_offset"])) * scale_um) + 1e-9,
        "slope_max_error_um_per_m": _up(max(map(abs, errs["slope"])) * 0.01) + 1e-9,
        "min_headroom_bits": round(30.0 - math.log2(peak), 3) if peak else 30.0,
        "terms": terms,
        "envelope": certified,
        "provenance_sha256": prov.hex(),
        "provenance_verified": verified,
        "provenance_edited": edited,
        "certified_bounds": {"offset_um": f["cert_out"] / OU_PER_UM, "ref_offset_um": f["cert_ref"] / OU_PER_UM,
                             "slope_um_per_m": f["cert_slope"] / 100.0},
    }
    if model.kind == "screw_reduced":
        sc = planner.state_cert
        s = planner.s
        certified["state_K"] = [0.0, float(s["Tmax"])]
        certified["travel_um_per_step"] = [0, f["umax"]]
        certified["feed_max_mm_min"] = f["fmax"]
        report["screw"] = {
            "segments": f["M"], "dt_ms": f["dt_ms"], "state_frac_bits": f["ft"], "state_limbs": f["ns"],
            "state_error_bound_K": max(sc["v_state_units"]) / (1 << f["ft"]),
            "per_step_residual_K": max(sc["rho_state_units"]) / (1 << f["ft"]),
            "horizon": "unbounded (steady state): |e| <= v with v >= |A| v + rho verified exactly",
        }
        report["screw"]["observer"] = screw_observer_status(doc, model, planner.sobs_cert)
        # what the board does against the host model: the integer arithmetic (certified) plus the reduction
        # (measured on the training runs)
        assert red_cert is not None  # a screw document (exact.TABLE_KINDS) whose thermal.reduced Model read: reduction() read it too
        report["reduction"] = red_cert
        report["total_max_error_um"] = max_err + red_cert["max_um"]
    if model.kind == "dynamic":
        certified["spindle_rpm"] = [0, f["smax"]]
        certified["feed_mm_min"] = [0, f["fmax"]]
        report["dynamic"] = {
            "dt_ms": f["dt_ms"], "positional": bool(f["positional"]), "filters": planner.dyn_cert,
            "horizon": "unbounded (steady state) from the cold start (latch): |e| <= v with v >= (1 - a) v + rho verified exactly",
        }
        if planner.obs_cert is not None:
            assert model.observer is not None  # Planner.dyn_observer certifies an observer only for a model with one
            # the observer's integer start against the host's estimate (exact arithmetic on the document's float gains):
            # each state's start error is inside its filter's state error bound, which the offset error above includes
            report["dynamic"]["observer"] = {
                "method": model.observer["method"], "settle_s": f["settle_s"], "states": planner.obs_cert,
                # a start without the controller's supplied states (0: none supplied; SETTLE_NEVER: until they come)
                "settle_without_record_s": f["settle_nr"],
                "start_error_um": _up(planner.obs_start_um) + 1e-9 if planner.obs_start_um is not None else None,
                "horizon": "from the estimate: |e| <= max(v + |ein|, |start error|), kept by every step",
            }
    accs = {k: v for k, v in rec.accs.items() if k >= 0}
    return Export(f, table, report, accs, errs)


SCREW_OBSERVER_NOT_CARRIED = (
    "%s; without a trusted heat.bin (none, torn, another table, or a machine that cooled or heated while the board was "
    "off) the board starts the screw cold, in equilibrium with the air, and its offsets are off until the screw's heat "
    "relaxes (docs/screw-model.md, \"Restart observer\")")


def screw_observer_status(doc: dict[str, Any] | None, model: Model | None = None,
                          cert: dict[str, Any] | None = None) -> dict[str, Any]:
    """What the table does with the screw document's thermal.observer (issue 21; host/learning/screw/observer.py). Carried
    (table format 6): the nut sensor is a table sensor and ``certificate`` is the integer start's (Planner.screw_observer:
    its largest deviation from the host's estimate, per segment and in um of offset). Not carried (a document that does
    not record the nut sensor's envelope): the reason, which ``tcomp export`` prints as a warning. A document without an
    observer gets its recorded note (why the sensors did not allow one)."""
    th = doc.get("thermal") if isinstance(doc, dict) else None
    obs = th.get("observer") if isinstance(th, dict) else None
    if not isinstance(obs, dict):
        note = th.get("observer_note") if isinstance(th, dict) else None
        return {"in_document": False, "carried": False, "note": note if isinstance(note, str) else "no observer in the document"}
    out: dict[str, Any] = {"in_document": True, "carried": cert is not None}
    if cert is None:
        note = getattr(model, "screw_obs_note", None) or "the table does not carry it"
        out["reason"] = SCREW_OBSERVER_NOT_CARRIED % note
    for key in ("sensor", "air_sensor", "start_error_um", "settle_s", "cold_start_error_um", "cold_settle_s"):
        out[key] = obs.get(key)
    if cert is not None:
        # the host's figures above (start_error_um: its estimate's bound on the training runs) and the board's integer
        # start against the host's estimate (exact arithmetic; inside the state error bound the offset error includes)
        out["certificate"] = cert
        out["table_settle_s"] = cert["settle_s"]
    return out


def _up(x: float | Fraction) -> float:
    """float(x) rounded up (x a Fraction or float)."""
    v = float(x)
    return math.nextafter(v, math.inf) if v < x else v
