"""Table format: round trip, CRC-32 check values, and every corruption rejected with its reason."""
import random
import struct
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware.crc32 import crc32, crc32_nibble
from firmware.table import (
    HEADER_SIZE, REASON_CRC, REASON_FIELD, REASON_KIND, REASON_LENGTH, REASON_MAGIC, REASON_SENSORS, REASON_TRUNCATED,
    REASON_UNIT, REASON_VERSION, TableError, parse_table,
)
from models_export import export_model
from hil_tests.fixtures.samples import linear_direct_doc, poly_slope_doc, screw_doc
from models_export.tableformat import payload_words


@pytest.fixture(scope="module")
def exports():
    return {
        "poly_slope": export_model(poly_slope_doc(random.Random(1), n_sensors=5, degree=3)),
        "linear_direct": export_model(linear_direct_doc(random.Random(2), n_sensors=3)),
        "screw_reduced": export_model(screw_doc(random.Random(3), segments=8)),
    }


def refresh_crc(buf):
    buf = bytearray(buf)
    struct.pack_into("<I", buf, len(buf) - 4, zlib.crc32(bytes(buf[:-4])))
    return bytes(buf)


def reason(buf, **kw):
    with pytest.raises(TableError) as exc:
        parse_table(buf, **kw)
    return exc.value.reason


def test_crc32_check_values():
    assert crc32(b"123456789") == 0xCBF43926
    assert crc32_nibble(b"123456789") == 0xCBF43926
    assert crc32(b"") == 0 and crc32_nibble(b"") == 0


@settings(deadline=None)  # pure-Python CRC loop: the default 200 ms deadline flakes on a loaded machine
@given(st.binary(max_size=300), st.integers(0, 2 ** 32 - 1))
def test_crc32_fallback_equals_zlib(data, start):
    assert crc32_nibble(data, start) == zlib.crc32(data, start)
    assert crc32(data, start) == zlib.crc32(data, start)


@pytest.mark.parametrize("kind", ["poly_slope", "linear_direct", "screw_reduced"])
def test_round_trip(exports, kind):
    ex = exports[kind]
    t = parse_table(ex.table, expected_sensors=len(ex.fields["sensors"]))
    f = ex.fields
    assert t.kind == kind and t.version == 8 and t.unit_code == 1 and t.error_ref == 0
    assert t.axis == f["axis"] and t.sensors == f["sensors"] and t.provenance == f["provenance"]
    assert (t.env_lo, t.env_hi, t.ref) == (f["env_lo"], f["env_hi"], f["ref"])
    assert (t.train_lo, t.train_hi) == (f["train_lo"], f["train_hi"])
    # the certified envelope is the training range widened by the default margin (15 K) on both sides
    assert all(lo == tlo - 15000 and hi == thi + 15000
               for lo, hi, tlo, thi in zip(t.env_lo, t.env_hi, t.train_lo, t.train_hi))
    for name, value in payload_words(f):
        base, _, idx = name.partition("[")
        got = getattr(t, base)
        if idx:
            got = got[int(idx[:-1])]
        assert got == value, name
    assert t.crc == zlib.crc32(ex.table[:-4])
    assert ex.report["crc32"] == "%08x" % t.crc


@pytest.mark.parametrize("kind", ["poly_slope", "linear_direct", "screw_reduced"])
def test_every_bit_flip_is_rejected(exports, kind):
    buf = exports[kind].table
    seen = set()
    for i in range(len(buf)):
        for bit in range(8):
            bad = bytearray(buf)
            bad[i] ^= 1 << bit
            r = reason(bytes(bad))
            seen.add(r)
            if i < 4:
                assert r == REASON_MAGIC
            elif i == 4:  # a flip to 5 or 6 (formats that still load) is caught by the CRC
                assert r == (REASON_CRC if bad[4] in (5, 6) else REASON_VERSION), (bit, r)
            elif i == 5:
                assert r in (REASON_KIND, REASON_CRC)
            elif 8 <= i < 12:
                assert r in (REASON_TRUNCATED, REASON_LENGTH)
            else:
                assert r == REASON_CRC, (i, bit, r)
    assert {REASON_MAGIC, REASON_VERSION, REASON_CRC, REASON_TRUNCATED, REASON_LENGTH} <= seen


@pytest.mark.parametrize("kind", ["poly_slope", "screw_reduced"])
def test_every_truncation_and_extension_is_rejected(exports, kind):
    buf = exports[kind].table
    for n in range(len(buf)):
        assert reason(buf[:n]) == REASON_TRUNCATED
    assert reason(buf + b"\x00") == REASON_LENGTH
    assert reason(refresh_crc(buf + b"\x00\x00\x00\x00")) == REASON_LENGTH


def test_specific_reasons(exports):
    buf = exports["poly_slope"].table
    n = len(exports["poly_slope"].fields["sensors"])
    v2 = bytearray(buf)
    v2[4] = 9  # a format newer than this firmware
    assert reason(bytes(v2)) == REASON_VERSION
    assert reason(refresh_crc(v2)) == REASON_VERSION
    # tables of format 1 (before the screw's air channel), 2 (before the training range) and 3 (before the screw's
    # effect terms, the power inputs of dynamic tables and the error reference) and 4 (before the speed effects' screw
    # terms, issue 19, and the dynamic table's observer, issue 21) are refused with a message that says to re-export
    # (formats 5, without the screw observer, 6, without the supplied lag states, and 7, without settle_nr, still load:
    # tests/export/test_export_screw_observer.py, tests/export/test_export_supplied.py)
    for old in (1, 2, 3, 4):
        v1 = bytearray(buf)
        v1[4] = old
        with pytest.raises(TableError, match="table format version %d is no longer supported; re-export the model "
                                             "with this tcomp \\(format 8\\)" % old) as exc:
            parse_table(bytes(refresh_crc(v1)))
        assert exc.value.reason == REASON_VERSION
    # a training range outside the envelope is an exporter/firmware mismatch
    tr = bytearray(buf)
    struct.pack_into("<i", tr, 64 + 16 * n + 12, struct.unpack_from("<i", tr, 64 + 16 * n)[0] - 1)
    with pytest.raises(TableError, match="training range") as exc:
        parse_table(refresh_crc(tr))
    assert exc.value.reason == REASON_FIELD
    k = bytearray(buf)
    k[5] = 9
    assert reason(refresh_crc(k)) == REASON_KIND
    bad_crc = buf[:-4] + struct.pack("<I", (zlib.crc32(buf[:-4]) + 1) & 0xFFFFFFFF)
    assert reason(bad_crc) == REASON_CRC
    assert reason(buf, expected_sensors=n + 1) == REASON_SENSORS
    with pytest.raises(TableError, match="table has %d sensors, board has %d" % (n, n - 1)):
        parse_table(buf, expected_sensors=n - 1)
    ns = bytearray(buf)
    ns[6] = n + 1  # header sensor count disagrees with the sizes
    with pytest.raises(TableError, match="sensors") as exc:
        parse_table(refresh_crc(ns))
    assert exc.value.reason == REASON_LENGTH
    ns[6] = 200
    assert reason(refresh_crc(ns)) == REASON_SENSORS
    u = bytearray(buf)
    u[7] = 2
    assert reason(refresh_crc(u)) == REASON_UNIT
    r = bytearray(buf)
    r[60] = 1
    assert reason(refresh_crc(r)) == REASON_FIELD
    # the error reference (byte 58) names one of the table's sensors (1..n) or the start (0)
    e = bytearray(buf)
    e[58] = n
    assert parse_table(refresh_crc(e)).error_ref == n
    e[58] = n + 1
    with pytest.raises(TableError, match="error reference %d \\(table has %d sensors\\)" % (n + 1, n)) as exc:
        parse_table(refresh_crc(e))
    assert exc.value.reason == REASON_FIELD
    nm = bytearray(buf)
    nm[HEADER_SIZE + 15] = ord("x")  # first sensor name: garbage after the NUL
    with pytest.raises(TableError, match="NUL-padded"):
        parse_table(refresh_crc(nm))
    assert reason(b"XXXX" + buf[4:]) == REASON_MAGIC
    assert reason(b"") == REASON_TRUNCATED


def test_field_range_checks_name_the_field(exports):
    ex = exports["poly_slope"]
    f = dict(ex.fields)
    from models_export.tableformat import pack

    f["Lt"] = 0
    with pytest.raises(TableError, match="Lt=0") as exc:
        parse_table(pack(f))
    assert exc.value.reason == REASON_FIELD
    f = dict(ex.fields, pos_ref=ex.fields["pos_hi"] + 1)
    with pytest.raises(TableError, match="position envelope"):
        parse_table(pack(f))
    g = dict(exports["screw_reduced"].fields)
    g["edges"] = list(g["edges"])
    g["edges"][3] = g["edges"][2]
    with pytest.raises(TableError, match="edges not ascending at 3"):
        parse_table(pack(g))


def test_table_is_data_not_code(exports):
    """The loader never evaluates table content: a payload full of Python source is just bytes with a bad CRC."""
    buf = bytearray(exports["linear_direct"].table)
    src = b"__import__('os').system('false')"
    buf[HEADER_SIZE:HEADER_SIZE + len(src)] = src
    assert reason(bytes(buf)) == REASON_CRC
    t = parse_table(refresh_crc(buf))  # with a valid CRC it is parsed as what it is: sensor names
    assert t.sensors[:2] == [src[:16].decode(), src[16:32].decode()]


def test_pack_refuses_a_list_the_layout_does_not_fit(exports):
    # the list lengths come from the table's layout (firmware/table.py count codes), not from the list given
    from models_export.tableformat import pack

    f = dict(exports["poly_slope"].fields)
    f["G"] = list(f["G"]) + [0]
    with pytest.raises(ValueError, match=r"table field G has %d entries, the table's layout needs %d"
                       % (len(f["G"]), len(f["G"]) - 1)):
        pack(f)
    g = dict(exports["screw_reduced"].fields)
    g["shB"] = list(g["shB"])[:-1]
    with pytest.raises(ValueError, match="table field shB"):
        pack(g)
    h = dict(exports["linear_direct"].fields)
    h["fb"] = list(h["fb"])[:-1]
    with pytest.raises(ValueError, match="table field fb has 2 entries for 3 sensors"):
        pack(h)


def test_c_header_leaves_out_only_what_the_evaluator_never_reads():
    # the C header takes its coefficients from the table spec; the ones it omits must be spec fields
    # that firmware/evaluate.py (whose operations the C code repeats) never reads
    import re
    from pathlib import Path

    from firmware import table
    from models_export import cheader
    from models_export.tableformat import spec_names

    spec = {n for s in (table.COMMON, table.POSITION, table.SCREW, table.SCREW_OBS) for n, _ in spec_names(s)}
    emitted = {n for g in cheader.SCALARS.values() for n in g} | {n for g in cheader.ARRAYS.values() for n in g}
    assert spec - emitted == set(cheader.INFORMATIONAL)
    source = (Path(table.__file__).with_name("evaluate.py")).read_text()
    read = set(re.findall(r"\b(?:t|table)\.([A-Za-z_]\w*)", source))
    assert "b" in read and "shb" in read and "S0" in read  # the scan sees the evaluator's reads
    assert not read & set(cheader.INFORMATIONAL)
