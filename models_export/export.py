"""export_model: quantise + certify + pack; the report the CLI writes."""
import math

from firmware.crc32 import crc32
from models_export.certify import LIMITS_UM, OU_PER_UM, ExportError
from models_export.document import document_hash
from models_export.exact import DEFAULT_ENVELOPE_MARGIN_K, Model
from models_export.plan import Planner
from models_export.tableformat import VERSION, pack


class Export:
    """Result of export_model: ``table`` (bytes), ``fields`` (dict), ``report`` (dict), ``accs``
    ({accumulator: (lo, hi)} certified intervals of the firmware's checked accumulators, ACC_*), ``errors_ou``
    ({output: (lo, hi)} certified integer-minus-model intervals, output units)."""

    def __init__(self, fields, table, report, accs, errors_ou):
        self.fields = fields
        self.table = table
        self.report = report
        self.accs = accs
        self.errors_ou = errors_ou

    def c_header(self, guard="TCOMP_TABLE_H"):
        from models_export.cheader import c_header

        return c_header(self, guard)


def _provenance(doc):
    """(sha256 of the document being exported, the recorded one or None). The table names the
    actual document; a recorded hash that differs means it was edited after it was saved."""
    prov = doc.get("provenance")
    declared = prov.get("sha256") if isinstance(prov, dict) else None
    return document_hash(doc), declared


def export_model(doc, ref_position_mm=None, limit_um=None, allow_edited=False, envelope=None,
                 margin_K=DEFAULT_ENVELOPE_MARGIN_K):
    """Quantise and certify ``doc`` (a tcomp-model/1 dict). Raises ExportError.

    The certified temperature envelope (docs/firmware.md, "Operating envelope") is ``envelope``
    ({sensor: (lo_C, hi_C)}) where given, else the training range (the document's
    envelope.temperature_C) widened by ``margin_K`` on both sides.

    A document whose recorded ``provenance.sha256`` does not match its content is refused,
    unless ``allow_edited``: the table then carries the actual hash and the edited mark."""
    if not isinstance(doc, dict):
        raise ExportError("model document must be a JSON object")
    model = Model(doc, ref_position_mm, envelope=envelope, margin_K=margin_K)
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
        raise ExportError("provenance.sha256 %.16s... does not match the document (actual %.16s...): it was edited "
                          "after it was saved; re-save it, or export it marked as edited (--allow-edited)"
                          % (declared, actual))
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
    envelope = {
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
        envelope["position_um"] = [model.pos_lo, model.pos_hi]
        envelope["reference_position_um"] = model.pos_ref
    report = {
        "model_kind": model.kind,
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
        "envelope": envelope,
        "provenance_sha256": prov.hex(),
        "provenance_verified": verified,
        "provenance_edited": edited,
        "certified_bounds": {"offset_um": f["cert_out"] / OU_PER_UM, "ref_offset_um": f["cert_ref"] / OU_PER_UM,
                             "slope_um_per_m": f["cert_slope"] / 100.0},
    }
    if model.kind == "screw_reduced":
        sc = planner.state_cert
        s = planner.s
        envelope["state_K"] = [0.0, float(s["Tmax"])]
        envelope["travel_um_per_step"] = [0, f["umax"]]
        envelope["feed_max_mm_min"] = f["fmax"]
        report["screw"] = {
            "segments": f["M"], "dt_ms": f["dt_ms"], "state_frac_bits": f["ft"], "state_limbs": f["ns"],
            "state_error_bound_K": max(sc["v_state_units"]) / (1 << f["ft"]),
            "per_step_residual_K": max(sc["rho_state_units"]) / (1 << f["ft"]),
            "horizon": "unbounded (steady state): |e| <= v with v >= |A| v + rho verified exactly",
        }
    if model.kind == "dynamic":
        envelope["spindle_rpm"] = [0, f["smax"]]
        envelope["feed_mm_min"] = [0, f["fmax"]]
        report["dynamic"] = {
            "dt_ms": f["dt_ms"], "positional": bool(f["positional"]), "filters": planner.dyn_cert,
            "horizon": "unbounded (steady state) from the cold start (latch): |e| <= v with v >= (1 - a) v + rho verified exactly",
        }
    accs = {k: v for k, v in rec.accs.items() if k >= 0}
    return Export(f, table, report, accs, errs)


def _up(x):
    """float(x) rounded up (x a Fraction or float)."""
    v = float(x)
    return math.nextafter(v, math.inf) if v < x else v
