"""Pins the exported bytes: the same model document gives the same table (and C header) bytes.

The documents are committed (tests/export/golden/, and the FL_THERMAL fixture), so a change in
the sample generators cannot move them; the digests were recorded from the exporter before the
table's field order moved into one spec (firmware/table.py). A change here is a table-format
change: bump firmware/table.py VERSION and record new digests on purpose.
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
                                         "220079c434d2ea7e52a24b759a0037953600147309b6f96742c82b592017ac80"),
    "golden/linear_direct.json": ("641ffa4c28e87685a1d267adff70743da3ccd57b6634628f8ed2118dceeca6c7",
                                  "c884c3219cd82227000cec7470150078b031063073bfb717d7cf474612b6ee42"),
    "golden/screw.json": ("9a429f64c2e89db0423f6b620ec17e9ee3b8c35e88cb624b1234b2ed47f17cc9",
                          "be5ded8703d9392d67430ace3cf905c63bd4bba15f2dbc4dc2da6fd68389e839"),
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
