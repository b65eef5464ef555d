"""The steady-state cycle allocates nothing: run under micropython.heap_lock() on the real interpreter.

Each cycle reads 11 channels (9 MAX31865 on SPI, 2 ADS122C04 on I2C, fakes
at register level), converts, evaluates a poly_slope table, limits, parses a
position report and a query from the serial input and emits $TC frames; in
Modbus mode it answers a read of all input registers. Any allocation under
heap_lock raises MemoryError and fails the test.

Heap size: the PyPI unix port is a 64-bit build that loads .mpy bytecode into
the GC heap, so code and every object take about twice the RAM of a 32-bit
microcontroller. The firmware, its table, the fakes and this script need
144 kB there (128 kB fails: the heap fragments until an import finds no
contiguous block); the test gives it 160 kB. tools/bench_firmware.py prints
the breakdown.
"""
import os

import pytest

from fwhelpers import compile_mpy, run_micropython, make_table, HERE

HEAP = "160K"

SCRIPT = r"""
import gc, micropython, sys
# every module first, as main.py on a board would: each import from a file needs
# a contiguous buffer, which a heap full of small objects may no longer have
import firmware.app, firmware.max31865, firmware.ads122c04
__import__("firmware.protocol" if MODE == "stream" else "firmware.modbus")
from firmware.app import App
from firmware.crc16 import crc16_ccitt, crc16_modbus
from fwfakes import make_rig
board = make_rig(table_dir=".", serial_mode=MODE, extra={"frame_ms": 100})
app = App(board)
for k in range(100):  # warm-up: channels become good, the output ramps up
    app.cycle(); board.clock.t += 100
    board.serial.take()
def line(body):
    c = crc16_ccitt(body)
    return b"$" + body + b"*" + b"%04X" % c + b"\r\n"
def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])
if MODE == "stream":
    msgs = [line(b"TC,P,%d" % (1000 * k)) for k in range(10)] + [line(b"TC,Q,250000")]
else:
    msgs = [rtu(bytes([1, 16, 0, 3, 0, 2, 4, 0, 0, 0x30, k])) for k in range(10)] + [rtu(bytes([1, 4, 0, 0, 0, 48]))]
sent = 0
gc.collect()
free0 = gc.mem_free()
micropython.heap_lock()
err = None
try:
    for k in range(N):
        board.serial.feed(msgs[k % len(msgs)])
        app.cycle()
        board.clock.t += 100
        sent += board.serial.nout
        board.serial.nout = 0
except Exception as e:
    err = e
micropython.heap_unlock()
free1 = gc.mem_free()
if err is not None:
    sys.print_exception(err)
    raise SystemExit(1)
print("OK", app.cycles, sent, "%08X" % app.status, app.pos, free1 - free0)
"""


@pytest.fixture(scope="module")
def mpy_dir(tmp_path_factory):
    return str(compile_mpy(str(tmp_path_factory.mktemp("mpy")), [os.path.join(HERE, "fwfakes.py")]))


@pytest.mark.micropython
@pytest.mark.parametrize("mode", ["stream", "modbus"])
def test_cycle_allocates_nothing_under_heap_lock(tmp_path, mpy_dir, mode):
    names = ["T%d" % i for i in range(1, 12)]
    (tmp_path / "table_a.bin").write_bytes(make_table(kind="poly_slope", sensors=names))
    n = 2000 if os.environ.get("TCOMP_SLOW") else 300
    out = run_micropython("MODE = %r\nN = %d\n" % (mode, n) + SCRIPT, str(tmp_path), mpy_dir, HEAP)
    ok, cycles, sent, status, pos, dfree = out.split()
    assert ok == "OK" and int(cycles) == 100 + n
    assert int(sent) > 0  # frames / replies really went out under the lock
    assert int(status, 16) & 0xFFFF == 0  # all 11 sensors good throughout
    assert int(pos) > 0  # position reports were parsed under the lock
    assert int(dfree) == 0  # nothing allocated
