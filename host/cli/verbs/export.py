"""tcomp export MODEL.json --out table.bin [--report report.json] [--json summary.json] [--c-header table.h] [--allow-edited]
    [--envelope SENSOR=LO:HI[,SENSOR=LO:HI...]]... [--envelope-margin K] [--reduction-limit UM]"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model document (tcomp-model/1 JSON: poly_slope, linear_direct, screw or dynamic)")
    p.add_argument("--out", required=True, help="table file to write (docs/table-format.md)")
    p.add_argument("--report", help="write the certificate as JSON (max_error_um, min_headroom_bits, terms, envelope)")
    p.add_argument("--json", metavar="PATH",
                   help="write the certificate as JSON, the same document as --report (every result-producing verb takes --json)")
    p.add_argument("--c-header", dest="c_header", help="also write the table and its integer evaluation as a C header")
    p.add_argument("--ref-position-mm", dest="ref_position_mm", type=float,
                   help="reference position of the offset/slope pair (default: 0 if inside the envelope, else its low end)")
    p.add_argument("--allow-edited", dest="allow_edited", action="store_true",
                   help="export a model whose recorded provenance.sha256 does not match its content (edited after "
                        "it was saved): the table names the actual document and is marked edited")
    p.add_argument("--envelope", action="append", default=[], metavar="SENSOR=LO:HI",
                   help="certified temperature envelope of a sensor in degC (the machine's operating range; repeat "
                        "or comma-separate, e.g. T1=10:60,T2=15:45). Must contain the model's training range. Inside "
                        "it the firmware evaluates the model (EXTRAPOLATING outside the training range); beyond it "
                        "it clamps (CLAMPED). Default: the training range widened by --envelope-margin")
    p.add_argument("--reduction-limit", dest="reduction_limit", type=float, default=None, metavar="UM",
                   help="screw models: refuse when the firmware's reduced form differs from the full model by more "
                        "than this RMS on the training runs (default 0.5 um; docs/table-format.md \"Reduction\")")
    p.add_argument("--envelope-margin", dest="envelope_margin", type=float, default=None, metavar="K",
                   help="widen the training range by this many K on both sides for sensors without --envelope "
                        "(default 15, docs/firmware.md \"Operating envelope\")")


def run(args: argparse.Namespace) -> int:
    import math

    from host.errors import UserError
    from host.outputs import Outputs
    from models_export.exact import SETTLE_NEVER  # pyright: ignore[reportAttributeAccessIssue] (published on CPython at table.py's end)

    if args.ref_position_mm is not None and not math.isfinite(args.ref_position_mm):
        raise UserError("--ref-position-mm %s: must be a finite position in mm" % args.ref_position_mm)
    with Outputs([args.model]) as out:
        for flag, path in (("--out", args.out), ("--report", args.report), ("--json", args.json), ("--c-header", args.c_header)):
            if path:
                out.file(path, flag)
        ex = _export(args)
        _write(args, ex, out)
        out.commit()
    r = ex.report
    print("%s -> %s: %s table, %d bytes, CRC-32 %s; certified max |integer - model| %.4f um (limit %.2f um), "
          "min headroom %.2f bits" % (args.model, args.out, r["model_kind"], r["table_bytes"], r["crc32"],
                                      r["max_error_um"], r["limit_um"], r["min_headroom_bits"]))
    if r.get("reduction"):
        rd = r["reduction"]
        print("reduced form vs full model on the training runs: %.3f um RMS, max %.3f um (limit %.2f um RMS)%s; "
              "integer + reduction max %.3f um" % (rd["rms_um"], rd["max_um"], rd["limit_um"],
                                                   "; left out: " + ", ".join(rd["omitted_effects"]) if rd["omitted_effects"] else "",
                                                   r["total_max_error_um"]))
    supplied = [c for c in ((r.get("dynamic") or {}).get("observer") or {}).get("states") or [] if c.get("supplied_by")]
    if supplied:
        # an integration requirement: the controller must send these at the board's start (docs/linuxcnc.md)
        nr = r["dynamic"]["observer"]["settle_without_record_s"]
        print("NOTE: the controller supplies %d lag state(s) of this table (%s): run `tcomp linuxcnc --spindle "
              "--signal-record FILE`; without them the board starts them 10 s after boot at the observer's "
              "estimate and keeps SETTLING %s" % (len(supplied), ", ".join(c["term"] for c in supplied),
                                                  "until they come (a document fitted before settle_without_record_s)"
                                                  if nr >= SETTLE_NEVER else "for %.0f min (%.0f min with them)" % (
                                                      nr / 60, r["dynamic"]["observer"]["settle_s"] / 60)), file=sys.stderr)
    obs = (r.get("screw") or {}).get("observer") or {}
    if obs.get("in_document") and not obs.get("carried"):
        # the document's power-on state estimate (issue 21) left out of the table (a document without its nut sensor's
        # envelope, fitted before format 6 carried it): say so, not drop it silently
        print("WARNING: thermal.observer (screw state from %s at power-on, settles in %.0f min against %.0f min cold) "
              "is not in the table: %s" % (obs["sensor"], obs["settle_s"] / 60, obs["cold_settle_s"] / 60, obs["reason"]),
              file=sys.stderr)
    return 0


def parse_envelope(values: Iterable[str]) -> dict[str, tuple[float, float]]:
    """``--envelope`` values ("T1=10:60", "T1=10:60,T2=15:45", repeatable) -> {sensor: (lo, hi)} in degC."""
    import math

    from host.errors import UserError
    from host.data.runs import TEMPERATURE_RANGE_C

    PT100_LO, PT100_HI = TEMPERATURE_RANGE_C
    out = {}
    for value in values:
        for item in value.split(","):
            name, eq, rng = item.strip().partition("=")
            lo, colon, hi = rng.partition(":")
            if not eq or not colon or not name.strip():
                raise UserError("--envelope %r: expected SENSOR=LO:HI in degC (e.g. T1=10:60)" % item)
            try:
                lo, hi = float(lo), float(hi)
            except ValueError:
                raise UserError("--envelope %s: %r is not a pair of temperatures in degC" % (item, rng))
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise UserError("--envelope %s: temperatures must be finite numbers" % item)
            if lo >= hi:
                raise UserError("--envelope %s: the low end %g degC must be below the high end %g degC" % (item, lo, hi))
            if lo < PT100_LO or hi > PT100_HI:
                # a bound below absolute zero, or beyond what a Pt100 reads: the certificate would cover nothing real
                raise UserError("--envelope %s: outside %g..%g degC, the range of a Pt100 (IEC 60751), the sensor the "
                                "board reads" % (item, PT100_LO, PT100_HI))
            name = name.strip()
            if name in out:
                raise UserError("--envelope: sensor %s given twice" % name)
            out[name] = (lo, hi)
    return out


def _export(args):
    import math

    from host.errors import UserError
    from host.learning.documents import ModelFormatError, read_document
    from models_export import ExportError, export_model

    try:
        doc = read_document(args.model)
    except ModelFormatError as exc:
        raise UserError(str(exc))
    from models_export.exact import DEFAULT_ENVELOPE_MARGIN_K

    envelope = parse_envelope(args.envelope)
    margin = DEFAULT_ENVELOPE_MARGIN_K if args.envelope_margin is None else args.envelope_margin
    if not (math.isfinite(margin) and margin >= 0):
        raise UserError("--envelope-margin %s: must be a finite number of K >= 0" % args.envelope_margin)
    from host.data.runs import TEMPERATURE_RANGE_C

    trained = (doc.get("envelope") or {}).get("temperature_C") if isinstance(doc.get("envelope"), dict) else None
    for sensor, rng in (trained.items() if isinstance(trained, dict) else ()):
        if sensor in envelope or not (isinstance(rng, list) and len(rng) == 2
                                      and all(isinstance(v, (int, float)) for v in rng)):
            continue  # given by --envelope, or a malformed range the export names itself
        lo, hi = rng[0] - margin, rng[1] + margin
        if lo < TEMPERATURE_RANGE_C[0] or hi > TEMPERATURE_RANGE_C[1]:
            raise UserError("--envelope-margin %g: widens %s's training range %g..%g degC to %g..%g degC, outside "
                            "%g..%g degC, the range of a Pt100 (IEC 60751); give a smaller margin or --envelope %s=LO:HI"
                            % (margin, sensor, rng[0], rng[1], lo, hi, TEMPERATURE_RANGE_C[0], TEMPERATURE_RANGE_C[1], sensor))
    from models_export.certify import DEFAULT_REDUCTION_LIMIT_UM

    limit = DEFAULT_REDUCTION_LIMIT_UM if args.reduction_limit is None else args.reduction_limit
    if not (math.isfinite(limit) and limit >= 0):
        raise UserError("--reduction-limit %s: must be a finite number of um >= 0" % args.reduction_limit)
    try:
        ex = export_model(doc, ref_position_mm=args.ref_position_mm, allow_edited=args.allow_edited,
                          envelope=envelope, margin_K=margin, reduction_limit_um=limit)
    except ExportError as exc:
        raise UserError("%s: %s" % (args.model, exc))
    return ex


def _write(args, ex, out):
    import json
    import os

    outputs = [(args.out, ex.table, "wb")]
    if args.report:
        outputs.append((args.report, json.dumps(ex.report, indent=2) + "\n", "w"))
    if args.json:
        outputs.append((args.json, json.dumps(ex.report, indent=2) + "\n", "w"))
    if args.c_header:
        guard = "TCOMP_" + "".join(c if c.isalnum() else "_" for c in os.path.basename(args.c_header).upper())
        outputs.append((args.c_header, ex.c_header(guard), "w"))
    for path, data, mode in outputs:
        with out.open(path, mode) as fh:
            fh.write(data)
