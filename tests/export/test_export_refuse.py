"""Models the exporter must refuse, each with a message naming the term, and the tcomp export verb."""
import json
import random
import subprocess

import pytest

from firmware.table import parse_table
from host.cli import main
from models_export import LIMITS_UM, ExportError, export_model
from hil_tests.fixtures.samples import linear_direct_doc, poly_slope_doc, restamp, screw_doc


def test_huge_slope_coefficient_is_refused_naming_it():
    doc = poly_slope_doc(random.Random(1), n_sensors=3)
    doc["thermal"]["coefficients_um_per_mm_per_K"]["T1"] = 5.0e4
    with pytest.raises(ExportError, match=r"thermal\.coefficients_um_per_mm_per_K\.T1"):
        export_model(doc)


def test_huge_direct_coefficient_is_refused_naming_it():
    doc = linear_direct_doc(random.Random(1), n_sensors=4)
    doc["thermal"]["coefficients_um_per_K"]["T2"] = -3.0e7
    with pytest.raises(ExportError, match=r"thermal\.coefficients_um_per_K\.T2"):
        export_model(doc)


def test_geometric_polynomial_that_overflows_is_refused_naming_the_term():
    doc = poly_slope_doc(random.Random(2), n_sensors=2, degree=3, stroke_mm=2000.0)
    doc["geometric"]["coefficients_um"][3] = 1.0e3  # 1e3 um/mm^3 at 2000 mm: 8e12 um
    with pytest.raises(ExportError, match=r"geometric\.coefficients_um\[3\]"):
        export_model(doc)


def test_non_contracting_screw_recurrence_is_refused():
    doc = screw_doc(random.Random(3), segments=8, air=False)
    A = doc["thermal"]["reduced"]["A"]
    A[2][2] = 1.001  # a segment that heats itself: no bounded state error
    with pytest.raises(ExportError, match=r"thermal\.reduced\.A"):
        export_model(doc)


def test_air_weights_that_amplify_the_air_are_refused():
    doc = screw_doc(random.Random(3), segments=8)
    red = doc["thermal"]["reduced"]
    red["air_K1"][3] += 0.01  # A + c0 + c1 > 1: the state would leave the air's envelope
    with pytest.raises(ExportError, match=r"row 3: A \+ air weights sum above 1"):
        export_model(doc)
    doc = screw_doc(random.Random(3), segments=8)
    doc["thermal"]["reduced"]["air_sensor"] = "T_nowhere"
    with pytest.raises(ExportError, match=r"air_sensor 'T_nowhere' is not in sensors"):
        export_model(doc)


def test_accuracy_limit_refusal_names_largest_term():
    with pytest.raises(ExportError, match=r"not below 1e-06 um .* largest contribution: term "):
        export_model(poly_slope_doc(random.Random(4)), limit_um=1e-6)


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["envelope"]["temperature_C"].pop("T0"), r"envelope\.temperature_C has no range for sensor 'T0'"),
    (lambda d: d["reference_C"].pop("T0"), r"reference_C has no entry for sensor 'T0'"),
    (lambda d: d["envelope"].update(position_mm=[10.0, 5.0]), r"envelope\.position_mm: empty range"),
    (lambda d: d["envelope"].update(position_mm=[0.0, 1e6]), r"envelope\.position_mm"),
    (lambda d: d["thermal"]["coefficients_um_per_mm_per_K"].update(T0=float("nan")), r"coefficients_um_per_mm_per_K\.T0: expected a finite number"),
    (lambda d: d["thermal"]["coefficients_um_per_mm_per_K"].pop("T0"), r"has no entry for sensor 'T0'"),
    (lambda d: d.update(kind="spline"), r"model kind 'spline'"),
    # a kind that is no string (unhashable: the kind lookups raised a TypeError) or a table's kind, not a document's
    # (screw_reduced was planned as a screw and the report then raised a TypeError on its missing reduction part)
    (lambda d: d.update(kind=["poly_slope"]), r"model kind \['poly_slope'\] cannot be exported \(known: poly_slope, "
                                             r"linear_direct, screw, dynamic, mr_poly\)"),
    (lambda d: d.update(kind={"name": "screw"}), r"model kind \{'name': 'screw'\} cannot be exported"),
])
def test_bad_documents_name_the_field(edit, match):
    doc = poly_slope_doc(random.Random(5), n_sensors=2)
    edit(doc)
    with pytest.raises(ExportError, match=match):
        export_model(doc)


def test_screw_without_reduced_block_is_refused():
    doc = screw_doc(random.Random(6), segments=8)
    del doc["thermal"]["reduced"]
    with pytest.raises(ExportError, match="thermal.reduced"):
        export_model(doc)


def test_a_table_kind_is_no_document_kind():
    """kind screw_reduced (the firmware table's name of a screw model) is refused; it was planned as a screw and then
    failed with a TypeError: its certificate's reduction part reads kind screw documents only."""
    doc = screw_doc(random.Random(6), segments=8)
    doc["kind"] = "screw_reduced"
    with pytest.raises(ExportError, match=r"model kind 'screw_reduced' cannot be exported \(known: poly_slope, linear_direct, "
                                          r"screw, dynamic, mr_poly\)"):
        export_model(restamp(doc))


def test_every_exportable_kind_has_a_table_accuracy_limit():
    """export_model reads LIMITS_UM[model.kind] for every kind Model accepts (exact.TABLE_KINDS' values)."""
    from models_export.exact import TABLE_KINDS

    assert set(TABLE_KINDS.values()) == set(LIMITS_UM)


def test_cli_writes_table_report_and_header(tmp_path, capsys):
    doc = poly_slope_doc(random.Random(7), n_sensors=4)
    model = tmp_path / "model.json"
    model.write_text(json.dumps(doc))
    out, rep, hdr = tmp_path / "t.bin", tmp_path / "r.json", tmp_path / "table.h"
    assert main(["export", str(model), "--out", str(out), "--report", str(rep), "--c-header", str(hdr), "--ref-position-mm", "100"]) == 0
    t = parse_table(out.read_bytes())
    assert t.kind == "poly_slope" and t.pos_ref == 100000 and t.sensors == doc["sensors"]
    r = json.loads(rep.read_text())
    assert {"model_kind", "max_error_um", "min_headroom_bits", "terms", "envelope"} <= set(r)
    assert r["model_kind"] == "poly_slope" and 0 < r["max_error_um"] < 0.05 and r["min_headroom_bits"] >= 1.0
    assert all({"name", "scale", "headroom_bits", "max_error_um"} <= set(x) for x in r["terms"])
    assert {x["name"] for x in r["terms"]} >= {"thermal.coefficients_um_per_mm_per_K.%s" % s for s in doc["sensors"]}
    assert r["envelope"]["position_um"] == [0, int(doc["envelope"]["position_mm"][1] * 1000)]
    assert r["provenance_verified"] is True and bytes.fromhex(r["provenance_sha256"]) == t.provenance
    assert "#define TCOMP_KIND TCOMP_KIND_POLY_SLOPE\n" in hdr.read_text() and "#define TCOMP_KIND_POLY_SLOPE 1\n" in hdr.read_text() and "TCOMP_TABLE_H" in hdr.read_text()
    assert "certified max |integer - model|" in capsys.readouterr().out


def test_cli_errors_are_user_errors(tmp_path, capsys):
    assert main(["export", str(tmp_path / "missing.json"), "--out", str(tmp_path / "t.bin")]) == 2
    assert "file is missing" in capsys.readouterr().err
    doc = poly_slope_doc(random.Random(8), n_sensors=2)
    doc["thermal"]["coefficients_um_per_mm_per_K"]["T1"] = 1e5
    model = tmp_path / "model.json"
    model.write_text(json.dumps(doc))
    assert main(["export", str(model), "--out", str(tmp_path / "t.bin")]) == 2
    err = capsys.readouterr().err
    assert "thermal.coefficients_um_per_mm_per_K.T1" in err and not (tmp_path / "t.bin").exists()


def test_c_header_compiles_and_matches_firmware(tmp_path, runner):
    """The C evaluation gives the firmware's integers (gcc, -fsanitize=undefined: no UB on the way)."""
    import shutil

    if not shutil.which("gcc"):
        pytest.skip("gcc not installed")
    rng = random.Random(10)
    def observed_screw_doc(rng):  # a format-6 screw table with its observer: the C start (tcomp_estimate) too
        from hil_tests.fixtures.samples import with_screw_observer
        from hil_tests.rig.boards import _finish
        from hil_tests.rig.boards import screw_doc as rig_screw_doc
        return _finish(with_screw_observer(rig_screw_doc(["T1", "T2"]), "T3", rng, settle_s=600.0))

    for make in (poly_slope_doc, linear_direct_doc, screw_doc, observed_screw_doc):
        doc = make(random.Random(11))
        if make is poly_slope_doc:
            doc["thermal"]["reference"] = "run_start"
        ex = export_model(restamp(doc))
        t = parse_table(ex.table)
        (tmp_path / "table.h").write_text(ex.c_header())
        lines, ops = [], []
        x = t.pos_lo
        for k in range(60):
            temps = [rng.randint(t.env_lo[i] - 2000, t.env_hi[i] + 2000) for i in range(t.n_sensors)]
            ops.append(["t", temps])
            lines.append("".join("e.temps[%d] = %d; " % (i, v) for i, v in enumerate(temps)) + "tcomp_update(&e);")
            if k == 20 and t.ref_mode == 1:
                ops.append(["l"])
                lines.append("tcomp_latch_references(&e);")
            if t.kind == "screw_reduced":
                if k in (10, 40):  # a start without a stored state (the cold start on a table without an observer)
                    ops.append(["o"])
                    lines.append("tcomp_estimate(&e);")
                if k == 30:
                    ops.append(["f", t.fmax // 2, t.pos_lo, t.pos_hi])
                    lines.append("tcomp_set_feed(&e, %d, %d, %d);" % (t.fmax // 2, t.pos_lo, t.pos_hi))
                x = rng.randint(t.pos_lo, t.pos_hi)
                ops += [["p", x], ["s"]]
                lines.append("tcomp_advance_position(&e, %d); tcomp_step(&e);" % x)
            p = rng.randint(t.pos_lo - 500, t.pos_hi + 500)
            ops.append(["e", p])
            lines.append('o = tcomp_offset_at(&e, %d); printf("%%ld %%ld %%ld %%lu\\n", (long)o, (long)tcomp_ref_offset(&e), '
                         '(long)tcomp_slope(&e), (unsigned long)e.flags);' % p)
        src = ('#include <stdio.h>\n#include "table.h"\nint main(void) {\n tcomp_eval_t e; int32_t o;\n tcomp_init(&e);\n '
               + "\n ".join(lines) + "\n return 0;\n}\n")
        (tmp_path / "main.c").write_text(src)
        exe = tmp_path / "main"
        subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wno-unused-function", "-O1", "-fsanitize=undefined",
                        "-fno-sanitize-recover=all", "-o", str(exe), str(tmp_path / "main.c")], check=True, capture_output=True)
        got = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split("\n")[:-1]
        want, _ = runner.run_case(ex.table, ops)
        assert got == ["%d %d %d %d" % tuple(r) for r in want], t.kind


def test_an_edited_document_is_refused_or_exported_marked_with_the_hash_it_has(tmp_path, capsys):
    # issue 14: export hashes the document it actually exports; a recorded provenance.sha256 that does not
    # match is refused, or with --allow-edited the table carries the actual hash and the edited mark
    from firmware.table import VERSION
    from models_export.document import document_hash

    doc = poly_slope_doc(random.Random(7), n_sensors=4)
    out, rep = tmp_path / "t.bin", tmp_path / "r.json"
    model = tmp_path / "model.json"
    model.write_text(json.dumps(doc))
    assert main(["export", str(model), "--out", str(out), "--report", str(rep)]) == 0
    t, r = parse_table(out.read_bytes()), json.loads(rep.read_text())
    assert t.provenance == bytes.fromhex(doc["provenance"]["sha256"]) and t.edited == 0
    assert r["provenance_edited"] is False and r["table_format"] == VERSION == t.version
    out.unlink()
    rep.unlink()
    edited = json.loads(json.dumps(doc))
    edited["thermal"]["intercept_um_per_mm"] += 0.001  # by hand, after it was saved: the recorded hash is stale
    model.write_text(json.dumps(edited))
    capsys.readouterr()
    assert main(["export", str(model), "--out", str(out), "--report", str(rep)]) == 2
    err = capsys.readouterr().err
    assert "provenance.sha256" in err and "does not match the document" in err and "--allow-edited" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]
    assert main(["export", str(model), "--out", str(out), "--report", str(rep), "--allow-edited"]) == 0
    t, r = parse_table(out.read_bytes()), json.loads(rep.read_text())
    actual = bytes.fromhex(document_hash(edited))
    assert t.provenance == actual != bytes.fromhex(doc["provenance"]["sha256"]) and t.edited == 1
    assert r["provenance_verified"] is False and r["provenance_edited"] is True and r["provenance_sha256"] == actual.hex()


def test_a_document_of_another_format_is_refused_naming_the_format():
    # the format tag is models_export/document.py's FORMAT; export_model reads no other document
    from models_export.document import FORMAT

    doc = poly_slope_doc(random.Random(3))
    for wrong in ("tcomp-model/2", None):
        with pytest.raises(ExportError, match="format must be %r" % FORMAT):
            export_model(restamp(dict(doc, format=wrong)))
