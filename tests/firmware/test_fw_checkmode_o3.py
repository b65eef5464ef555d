"""The evaluator's checking mode survives ``mpy-cross -O3`` (the build shipped to boards).

-O3 strips ``assert`` statements and ``__debug__`` blocks; the checking mode
uses neither (an ``if`` and OverflowError), so from -O3 .mpy on the
MicroPython unix port it must record the same per-accumulator minima and maxima as
on CPython and still refuse an out-of-range intermediate.
"""
import os

import pytest

from fwhelpers import compile_mpy, make_table, run_micropython

SCRIPT = r"""
from firmware.table import parse_table
from firmware.evaluate import Evaluator
for name in NAMES:
    f = open(name, "rb"); data = f.read(); f.close()
    ev = Evaluator(parse_table(data), check=True)
    for k in range(40):
        for i in range(len(ev.temps)):
            ev.temps[i] = -30000 + 2900 * k + 1000 * i
        ev.update()
        ev.offset_at(-20000 + 13000 * k)
        ev.ref_offset()
        ev.slope()
    print(name, ev.lo, ev.hi, ev.flags)
    try:
        ev._note(0, 1 << 30)
        print("no OverflowError")
    except OverflowError:
        print("OverflowError")
"""


def run_cpython(names, cwd):
    import contextlib
    import io
    out = io.StringIO()
    old = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out):
            exec("NAMES = %r\n" % (names,) + SCRIPT, {})
    finally:
        os.chdir(old)
    return out.getvalue()


@pytest.mark.micropython
def test_check_mode_from_O3_mpy_matches_cpython(tmp_path):
    names = []
    sensors = ["T%d" % i for i in range(1, 5)]
    for kind in ("poly_slope", "linear_direct"):
        (tmp_path / (kind + ".bin")).write_bytes(make_table(kind=kind, sensors=sensors, b=[900, -700, 50, 3]))
        names.append(kind + ".bin")
    mpy = compile_mpy()
    got = run_micropython("NAMES = %r\n" % (names,) + SCRIPT, str(tmp_path), mpy, "64K")
    want = run_cpython(names, str(tmp_path))
    assert got == want
    assert got.count("OverflowError") == 2 and "no OverflowError" not in got
    # the checking mode really recorded the temperature differences (accumulator 0) of every table
    for line in got.splitlines()[::2]:
        lo0 = int(line.split("[", 1)[1].split(",", 1)[0])
        assert lo0 == -40000, line  # -30000 + 2900*0 + 1000*0 minus the 20000 reference
