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

Recorded again for table format 4 (issues 19 and 23, merged together): the poly_slope and linear_direct
tables differ from the format-3 digests only in the version byte (set back to 3, with the CRC recomputed, they
give the old digests: checked when recorded); the dynamic tables gained the power inputs' four header words
(Lp np shp2 shp) and the screw table the effect terms (Bu shBu per segment, Rv); the C headers follow the new
version and the screw's new coefficients.

Recorded again for table format 5, which carries two changes (issue 19: the reduced forms of speed_dependent_heat
and moving_convection in the screw section; issue 21: the dynamic table's observer). poly_slope and linear_direct
tables differ from their format-4 digests only in the version byte; the screw table also in eleven new screw fields
(fg g0 Gv shGv Lgu ngu, D and shD per segment, fe Ly ny, "absent" values for this document); the three dynamic
tables without an observer in the observer's words (obs 0, settle_s 0, LO, nO, Go/shO zeros, gO/rG zeros). Checked
when each branch recorded them: with the version set back to 4 and the new words cut out (length, word count and CRC
recomputed) every table gives its format-4 digest. The C headers follow the version, the new screw coefficients and
the two new terms of tcomp_step. golden/dynamic_observer.json (hil_tests/fixtures/samples.py with_observer) and the
FL_THERMAL fit with its observer (hil_tests/fixtures/dynamic_observer_fl_thermal_ch1.json) pin tables with an
observer. At the merge of the two branches each digest below is the one of the branch that changed that kind
(screw and C headers: effects19; dynamic: the observer branch), and the test recomputes them all. The three C
header digests effects19 recorded predated its own last change to the header (its branch's golden test failed on
them); they are the headers its final code writes, byte for byte the same as the merged tree's.

Recorded again for table format 6 (issue 21: the screw table's observer, ten words after the screw block: obs settle_s
sn sr Rn Lr nr and Gn shGn rN per segment; golden/screw.json has no observer, so they are its "absent" values). Checked
when recorded: with the version set back to 5 and, in the screw table, those words cut out (length, word count and CRC
recomputed), every table gives its format-5 digest. The C headers differ in the table bytes they embed only (the C evaluator has no
screw observer: it starts the screw cold).

C header digests recorded again (integ28): the header gained the screw observer's start (tcomp_rise, tcomp_estimate
under TCOMP_OBS), the screw table's observer scalars and arrays (TCOMP_OBS ... tcomp_rN) and two usage lines; against
the previous exporter's header the lines differ in nothing else (the one usage line that ended the comment now ends
with ';' and is followed by the two new lines: checked when recorded). The table digests did not change.

Recorded again for table format 7 (issue 21: the lag states the controller supplies, one word per filter, tauc, after
the dynamic block; none of these documents supplies a state, so every tauc is 0). Checked when recorded (stop 32):
with the version set back to 6 and the tauc words cut out (length, word count and CRC recomputed) every table gives its
format-6 digest. The three C headers differ from the format-6 ones only in
the embedded table's version byte and CRC (diffed when recorded).

Recorded again for table format 8 (issue 21: settle_nr, SETTLING of a start without the controller's supplied states,
one word after the tauc words; none of these documents supplies a state, so it is 0). Checked when recorded (stop 33):
with the version set back to 7 and the settle_nr word cut out (length, word count and CRC recomputed) every table gives
its format-7 digest; the three C headers differ from the format-7 ones only in the embedded table's version byte and
CRC (diffed when recorded).
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
    "golden/poly_slope_run_start.json":
        ("a1350dac45d3193c93c68ccc7f52718bce100977b67a24b62ac66a81a4478048",
         "e7d889f73baf9986a4416c7332b1ae256b1d1c92973611f80bf94cfd476c8757"),
    "golden/linear_direct.json":
        ("081cd60c556ca91bf9458624c0ed9384adbaa2753dba5a4a16cb2464d505308c",
         "d5fcf715adc63da4e99146b1a41f1cfc2d708dc3c72e0ee79a6ff13795f9f191"),
    "golden/screw.json":
        ("6ae183b0083430e53aed784bb9e5f02470ef71f017ed33a9aec23e842e8e858a",
         "757751816bf292e4a0685b551cb0c0aa33756c222e066d934399fc3fc25b76ec"),
    "golden/dynamic_direct.json": ("57b1ca0257ddf8ba786dca055e2c24ccac6d9bb83fcf27367d2c18ed7e8f86e5", None),
    "golden/dynamic_observer.json": ("2e91a6549ce1dfe988d03e56a237d75f6ea651177065e6bb9688c75c6b50e4c0", None),
    # `tcomp fit data/fl_thermal --model dynamic --direct --channel ch1` (defaults: with the observer); rows coarser than
    # the state (negative guard bits) for its spindle states
    "../../hil_tests/fixtures/dynamic_observer_fl_thermal_ch1.json":
        ("92eb1d2b8b096d8bf354b78032a7ec163735434cad161f336fd02e8bb0a281c0", None),
    "golden/dynamic_slope.json": ("2d0b567567a75d08d4568cc5071c0d5ad4334d0e64da3e7c07b0463687aa890d", None),
    "../../hil_tests/fixtures/dynamic_fl_thermal_ch1.json":
        ("a443fa2b2bbc182b743b3ad771144711ace6c0b5871a9c58b73e94c00b5450a9", None),
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_same_document_same_bytes(name):
    doc = json.loads((HERE / name).read_text())
    ex = export_model(doc)
    table_sha, header_sha = GOLDEN[name]
    assert hashlib.sha256(ex.table).hexdigest() == table_sha, name
    if header_sha is not None:
        assert hashlib.sha256(ex.c_header().encode()).hexdigest() == header_sha, name
