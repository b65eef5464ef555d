"""tcomp export MODEL.json --out table.bin [--report report.json] [--c-header table.h]"""
HELP = "quantise a model into the firmware's integer coefficient table, with a certificate of integer safety and accuracy"


def add_arguments(p):
    p.add_argument("model", help="model document (tcomp-model/1 JSON: poly_slope, linear_direct or screw)")
    p.add_argument("--out", required=True, help="table file to write (docs/table-format.md)")
    p.add_argument("--report", help="write the certificate as JSON (max_error_um, min_headroom_bits, terms, envelope)")
    p.add_argument("--c-header", dest="c_header", help="also write the table and its integer evaluation as a C header")
    p.add_argument("--ref-position-mm", dest="ref_position_mm", type=float,
                   help="reference position of the offset/slope pair (default: 0 if inside the envelope, else its low end)")


def run(args):
    import json
    import os

    from host.cli import UserError
    from host.models import ModelFormatError, read_document
    from models_export import ExportError, export_model

    try:
        doc = read_document(args.model)
    except ModelFormatError as exc:
        raise UserError(str(exc))
    try:
        ex = export_model(doc, ref_position_mm=args.ref_position_mm)
    except ExportError as exc:
        raise UserError("%s: %s" % (args.model, exc))
    outputs = [(args.out, ex.table, "wb")]
    if args.report:
        outputs.append((args.report, json.dumps(ex.report, indent=2) + "\n", "w"))
    if args.c_header:
        guard = "TCOMP_" + "".join(c if c.isalnum() else "_" for c in os.path.basename(args.c_header).upper())
        outputs.append((args.c_header, ex.c_header(guard), "w"))
    for path, data, mode in outputs:
        try:
            with open(path, mode) as fh:
                fh.write(data)
        except OSError as exc:
            raise UserError("cannot write %s: %s" % (path, exc.strerror or exc))
    r = ex.report
    print("%s -> %s: %s table, %d bytes, CRC-32 %s; certified max |integer - model| %.4f um (limit %.2f um), "
          "min headroom %.2f bits" % (args.model, args.out, r["model_kind"], r["table_bytes"], r["crc32"],
                                      r["max_error_um"], r["limit_um"], r["min_headroom_bits"]))
    return 0
