"""The steady-state cycle allocates nothing: run under micropython.heap_lock() on the real interpreter.

Each cycle reads 11 channels (9 MAX31865 on SPI, 2 ADS122C04 on I2C, fakes
at register level), converts, evaluates a poly_slope table, limits, parses a
position report and a query from the serial input and emits $TC frames; in
Modbus mode it answers a read of all input registers. Any allocation under
heap_lock raises MemoryError and fails the test.

The firmware runs from .mpy files compiled by mpy-cross (-O3, as shipped), so
nothing is compiled on the device. It runs on the interpreter TCOMP_MICROPYTHON
chooses: in make test the 32-bit port (ports/linux32), where small ints stop at
2**30 as on the MCU, so a 32-bit value formed in the cycle allocates and fails here.
Heap (tools/bench_firmware.py --heaps-only, stream / Modbus; docs/firmware.md):
on the 32-bit port the loaded code is 60.0 / 56.0 kB, the test fakes 12 kB, the app's
data after warm-up 8.7 / 9.3 kB, and the smallest heaps that boot and run the
locked cycles 98 / 92 kB (table format 5: the dynamic observer and the screw speed
terms; 48 / 44 kB of code and 87 / 84 kB before them; format 6, the screw observer: code 62.0 / 58.0 kB, smallest
heaps 99 / 95 kB, the screw table with its observer 102 / 100 kB); on the 64-bit unix wheel (pointers and objects twice
the size) 65 / 60 kB, 19 kB, 22.4 / 23.5 kB and 129 / 123 kB. Each runs with
about 10 % above its measured minimum (interpreters.HEAPS), so a change that
costs RAM fails here.
"""
import os

import pytest

from fwhelpers import compile_mpy, run_micropython, make_table, HEAPLOCK_SCRIPT
from firmware.wire import SETTLING

def heap(mode, kind="poly_slope"):
    """The test heap for the chosen interpreter's word size (hil_tests/rig/interpreters.py HEAPS); a dynamic
    table (6 filters) has its own entries."""
    from hil_tests.rig import interpreters
    return interpreters.heap("fw_heaplock_" + ("%s_" % kind if kind in ("dynamic", "screw") else "") + mode)


@pytest.fixture(scope="module")
def mpy_dir():
    return str(compile_mpy(fakes=True))


@pytest.mark.micropython
@pytest.mark.parametrize("kind", ["poly_slope", "dynamic", "dynamic_supplied", "screw"])
@pytest.mark.parametrize("mode", ["stream", "modbus"])
def test_cycle_allocates_nothing_under_heap_lock(tmp_path, mpy_dir, mode, kind):
    """The dynamic table (1 s filter step: a step every 10 cycles, an observer that estimates the lag states at the
    first all-good cycle and again halfway through the locked cycles) with spindle speed and feed reports; the screw
    table (formats 4 and 5: bearing heat per mm of travel, the reversal term, the friction heat's speed factor and the
    extra convection while moving; format 6: the observer, which starts the segments from the nut sensor at the first
    all-good cycle and again halfway through the locked cycles) with position reports going up and back. The dynamic
    table whose spindle and feed lags the controller supplies (format 7): halfway through, its start waits for them
    again, starts without them after 10 s (their steady state) and takes them 20 cycles before the end, under the lock."""
    names = ["T%d" % i for i in range(1, 12)]
    table = {"dynamic": "dynamic_observer", "screw": "screw_observer", "dynamic_supplied": "dynamic_supplied_gains"}.get(kind, kind)
    sup = kind == "dynamic_supplied"
    kind = "dynamic" if sup else kind
    (tmp_path / "table_a.bin").write_bytes(make_table(kind=table, sensors=names))
    n = 2000 if os.environ.get("TCOMP_SLOW") else 300
    out = run_micropython("MODE = %r\nN = %d\nDYN = %r\nSOBS = %r\nSUP = %r\n" % (mode, n, kind == "dynamic", kind == "screw", sup)
                          + HEAPLOCK_SCRIPT, str(tmp_path), mpy_dir, heap(mode, kind))
    ok, cycles, sent, status, pos, dfree, data, peak = out.split()
    assert ok == "OK" and int(cycles) == 100 + n
    assert int(sent) > 0  # frames / replies really went out under the lock
    assert int(status, 16) & 0xFFFF == 0  # all 11 sensors good throughout
    assert int(pos) > 0  # position reports were parsed under the lock
    assert int(dfree) == 0  # nothing allocated
    if kind == "dynamic":
        assert int(status, 16) & SETTLING  # the estimate halfway through: settle_s (30 s) not yet passed
    if kind == "screw":
        assert int(status, 16) & SETTLING  # the screw observer's start halfway through: settle_s (1 h) not yet passed
    # the app's own data (table, evaluator, channels, drivers, buffers), bounded so that growth is
    # noticed: on 32 bits the firmware's target (< 16 kB), on 64 bits objects are twice the size
    from hil_tests.rig import interpreters
    assert 0 < int(data) < (16 if interpreters.get().bits == 32 else 24) * 1024, data
    print("heap %s %s: app data %s B, largest live %s B of %s" % (mode, kind, data, peak, heap(mode, kind)))
