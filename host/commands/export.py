"""tcomp export MODEL.json --out table.bin [--report report.json] [--json summary.json] [--c-header table.h] [--allow-edited]"""


def add_arguments(p):
    p.add_argument("model", help="model document (tcomp-model/1 JSON: poly_slope, linear_direct or screw)")
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


def run(args):
    import math

    from host.cli import UserError
    from host.outputs import Outputs

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
    return 0


def _export(args):
    from host.cli import UserError
    from host.models import ModelFormatError, read_document
    from models_export import ExportError, export_model

    try:
        doc = read_document(args.model)
    except ModelFormatError as exc:
        raise UserError(str(exc))
    try:
        ex = export_model(doc, ref_position_mm=args.ref_position_mm, allow_edited=args.allow_edited)
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
