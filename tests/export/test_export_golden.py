"""Pins the exported bytes: the same model document gives the same table (and C header) bytes.

The documents are committed (tests/export/golden/, and the FL_THERMAL fixture), so a change in
the sample generators cannot move them; the digests were recorded from the exporter before the
table's field order moved into one spec (firmware/table.py). A change here is a table-format
change: bump firmware/table.py VERSION and record new digests on purpose.

The table digests are the ones recorded before the spec move. The C header digests were recorded
again once: the header now spells the kind codes as ``TCOMP_KIND_<NAME>`` defines generated from
firmware/table.py's KINDS (``#define TCOMP_KIND TCOMP_KIND_SCREW_REDUCED``, ``#if TCOMP_KIND ==
TCOMP_KIND_SCREW_REDUCED``) instead of literals, and lists the screw scalars in table order; sorted,
the lines differ in nothing else.
"""
import hashlib
import json
from pathlib import Path

import pytest

from models_export.export import export_model

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]

# document -> (sha256 of the table, sha256 of the C header or None: dynamic tables have no C evaluator)
GOLDEN = {
    "golden/poly_slope_run_start.json": ("abc6bc947929b09948c78737ab78489e901c7b906f64560e98f786117a440a40",
                                         "8f301c94cf9e4dd8712751ed255e4fa64dbe093d3024615b3b1911bdba6e56b3"),
    "golden/linear_direct.json": ("641ffa4c28e87685a1d267adff70743da3ccd57b6634628f8ed2118dceeca6c7",
                                  "08bdd9ac8888c2fc5e2d3ecdaaead186f80c4313d574b95b800ef9336ab60bcd"),
    "golden/screw.json": ("9a429f64c2e89db0423f6b620ec17e9ee3b8c35e88cb624b1234b2ed47f17cc9",
                          "1afa21436ec828234225b8f42e15d0b816b5ee5604bb74136a112ef4738de7ae"),
    "golden/dynamic_direct.json": ("8fb5af924865e85c177c54c60d383ab57ef0b02608fcce1297d1f9a74e8e2e7f", None),
    "golden/dynamic_slope.json": ("4738b42078da849122c69f10c49dcd15e3adab4bdbaf2681372bde935068bffe", None),
    "../../hil_tests/fixtures/dynamic_fl_thermal_ch1.json":
        ("9d946e52425ff111018fd5bb469ea5e03d66e506d88d9a641e47ada774e943b0", None),
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_same_document_same_bytes(name):
    doc = json.loads((HERE / name).read_text())
    ex = export_model(doc)
    table_sha, header_sha = GOLDEN[name]
    assert hashlib.sha256(ex.table).hexdigest() == table_sha, name
    if header_sha is not None:
        assert hashlib.sha256(ex.c_header().encode()).hexdigest() == header_sha, name
