"""Two table slots: fallback to the other slot, atomic switch, cut-off writes never mix tables."""
import os
import zlib

import pytest
from hypothesis import given, settings, strategies as st, HealthCheck

from fwhelpers import make_table
from firmware.slots import TableStore, UploadError

NAMES = ["T1", "T2"]


def store(tmp_path):
    return TableStore(str(tmp_path / "t"))


def put(tmp_path, slot, data):
    d = tmp_path / "t"
    d.mkdir(exist_ok=True)
    (d / ("table_%s.bin" % slot)).write_bytes(data)


def upload(s, data, cut=None):
    s.begin(len(data), zlib.crc32(data))
    for off in range(0, len(data), 64):
        if cut is not None and off >= cut:
            return None
        s.write(off, data[off:off + 64])
    return s.commit()


def test_creates_directory_and_empty_store(tmp_path):
    s = TableStore(str(tmp_path / "a" / "b"))
    assert os.path.isdir(tmp_path / "a" / "b")
    assert s.load() == (None, None)


def test_active_slot_refused_falls_back_to_other(tmp_path):
    a = make_table(kind="linear_direct", sensors=NAMES, S0=1)
    b = bytearray(make_table(kind="linear_direct", sensors=NAMES, S0=2))
    b[20] ^= 0x40
    put(tmp_path, "a", a)
    put(tmp_path, "b", bytes(b))
    (tmp_path / "t" / "active").write_bytes(b"B")
    s = store(tmp_path)
    t, slot = s.load()
    assert slot == 0 and t.S0 == 1
    assert s.refusals[0][0] == "B" and "CRC" in s.refusals[0][1]


def test_upload_goes_to_inactive_slot_and_switches(tmp_path):
    put(tmp_path, "a", make_table(kind="linear_direct", sensors=NAMES, S0=1))
    s = store(tmp_path)
    s.load()
    t, slot = upload(s, make_table(kind="linear_direct", sensors=NAMES, S0=2))
    assert slot == 1 and t.S0 == 2
    t, slot = upload(s, make_table(kind="linear_direct", sensors=NAMES, S0=3))
    assert slot == 0 and t.S0 == 3
    assert store(tmp_path).load()[0].S0 == 3


def test_accept_hook_refuses_foreign_tables(tmp_path):
    from firmware.table import TableError
    def accept(t):
        if t.sensors != NAMES:
            raise TableError("sensor count mismatch", "not this board's sensors")
    s = TableStore(str(tmp_path / "t"), accept)
    with pytest.raises(UploadError, match="not this board"):
        upload(s, make_table(kind="linear_direct", sensors=["X1"]))


def test_upload_checks(tmp_path):
    s = store(tmp_path)
    data = make_table(kind="linear_direct", sensors=NAMES)
    with pytest.raises(UploadError, match="size"):
        s.begin(10, 0)
    with pytest.raises(UploadError, match="no upload"):
        s.write(0, b"x")
    s.begin(len(data), zlib.crc32(data))
    with pytest.raises(UploadError, match="expected 0"):
        s.write(5, data[5:10])
    s.write(0, data)
    with pytest.raises(UploadError, match="beyond size"):
        s.write(len(data), b"xx")
    s.abort()
    s.begin(len(data), zlib.crc32(data) ^ 1)
    s.write(0, data)
    with pytest.raises(UploadError, match="CRC-32"):
        s.commit()
    s.begin(len(data), zlib.crc32(data))
    s.write(0, data[:50])
    with pytest.raises(UploadError, match="received 50"):
        s.commit()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 400), pointer_cut=st.booleans(), stale_new=st.booleans())
def test_power_cut_anywhere_leaves_one_whole_table(tmp_path_factory, cut, pointer_cut, stale_new):
    """Simulate a power cut after ``cut`` bytes of the new slot file, or between
    writing active.new and renaming it: the next boot runs the old or the new table, whole."""
    tmp = tmp_path_factory.mktemp("cut")
    old = make_table(kind="linear_direct", sensors=NAMES, S0=11)
    new = make_table(kind="linear_direct", sensors=NAMES, S0=22)
    put(tmp, "a", old)
    d = tmp / "t"
    if cut < len(new):
        (d / "table_b.bin").write_bytes(new[:cut])  # slot file cut off mid-write
        if stale_new:
            (d / "active.new").write_bytes(b"A")
        expect = 11
    else:
        (d / "table_b.bin").write_bytes(new)
        if pointer_cut:  # active.new written, rename not done: 'active' still says A (or is absent)
            (d / "active.new").write_bytes(b"B")
            expect = 11 if stale_new else 22
            if stale_new:
                (d / "active").write_bytes(b"A")
        else:
            (d / "active").write_bytes(b"B")
            expect = 22
    t, slot = TableStore(str(d)).load()
    assert t is not None and t.S0 == expect
