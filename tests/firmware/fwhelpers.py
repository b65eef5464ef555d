"""Helpers shared by the firmware tests (tables, command frames, rigs, MicroPython runs).

A module with a unique name rather than ``conftest``: test modules import it
by name (conftest.py puts this folder on sys.path), and a plain ``conftest``
import could find another folder's conftest first.
"""
import os

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
CERT_NONE = (1 << 30) - 1


def table_fields(kind="linear_direct", sensors=("T1", "T2"), b=None, shb=4, S0=0, pos=(0, 500000, 0),
                 axis="X"):
    """Fields for models_export.tableformat.pack of a small, integer-safe table."""
    n = len(sensors)
    f = {
        "kind": kind, "sensors": list(sensors), "axis": axis, "provenance": bytes(range(32)),
        "env_lo": [-20000] * n, "env_hi": [80000] * n, "ref": [20000] * n,
        "pos_lo": pos[0], "pos_hi": pos[1], "pos_ref": pos[2],
        "fo": 0, "Lt": 29, "nt": 1, "S0": S0, "fS": 0,
        "b": list(b) if b is not None else [1] * n, "shb": [shb] * n, "fb": [0] * n, "rL": 0,
        # a certificate that bounds nothing these small tables can reach (the exporter proves real ones)
        "cert_out": CERT_NONE, "cert_ref": CERT_NONE, "cert_slope": CERT_NONE,
    }
    if kind != "linear_direct":
        f.update({"Lw": 10, "nw": 2, "shw": 18, "KS": 1, "shK": 0, "fK": 0, "rK": 0, "rT": 0,
                  "degree": 1, "Lg": 10, "ng": 2, "G": [300, 1], "fG": [0, 0], "shg": [14], "rO": 0})
    return f


def make_table(**kw):
    from models_export.tableformat import pack
    if kw.get("kind") == "dynamic":
        return dynamic_table(kw["sensors"])
    if kw.get("kind") == "dynamic_observer":
        return dynamic_table(kw["sensors"], observer=kw.get("settle_s", 30.0))
    if kw.get("kind") == "dynamic_supplied":
        return dynamic_table(kw["sensors"], observer=kw.get("settle_s", 30.0), supplied=True)
    if kw.get("kind") == "dynamic_supplied_gains":
        return dynamic_table(kw["sensors"], observer=kw.get("settle_s", 30.0), supplied="gains",
                             settle_without_record_s=kw.get("settle_without_record_s"))
    if kw.get("kind") == "screw":
        return screw_table(kw["sensors"])
    if kw.get("kind") == "screw_observer":
        return screw_table(kw["sensors"], observer=kw.get("settle_s", 3600.0))
    return pack(table_fields(**kw))


def dynamic_table(sensors, dt_s=1.0, seed=3, observer=None, supplied=False, settle_without_record_s=None):
    """An exported, certified dynamic table over ``sensors`` reading every kind of signal; 1 s filter step.
    ``observer``: None, or the settle_s of an observer (issue 21; the table then has the fixed reference).
    ``supplied``: its spindle, squared-speed and feed lag states are supplied by the controller (table format 7);
    "gains": with the observer's gains for them (the estimate until the controller's values come, as a fit writes);
    ``settle_without_record_s``: the document's settle time without the controller's values (table format 8's settle_nr)."""
    import random
    from hil_tests.fixtures.samples import dynamic_doc
    from models_export import export_model
    sig = ["T:" + s for s in sensors[:3]] + ["spindle_krpm", "spindle_krpm2", "feed_m_min"]
    doc = dynamic_doc(random.Random(seed), "direct", dt_s=dt_s, signals=sig, names=list(sensors))
    for t, tau in zip(doc["thermal"]["terms"], (0.0, 900.0, 3600.0, 600.0, 1800.0, 300.0)):
        t["tau_s"] = tau
    doc["envelope"]["spindle_rpm"] = [0, 12000]
    from hil_tests.fixtures.samples import restamp, with_observer, with_supplied
    if observer is not None:
        doc = with_observer(doc, random.Random(seed), settle_s=observer)
    if supplied:
        doc = with_supplied(doc, keep_gains=supplied == "gains", settle_without_record_s=settle_without_record_s)
    return export_model(restamp(doc)).table


def screw_table(sensors, seed=5, observer=None):
    """An exported screw table over ``sensors`` (base sensors[0], air sensors[1], the rest read and unused) with
    the effect terms of formats 4 and 5 (bearing heat per mm of travel, a reversal term, the friction heat's speed factor,
    the extra convection while moving); 1 s steps. ``observer``: None, or the settle_s of a screw observer (format 6,
    issue 21) whose nut sensor is sensors[2] (then the table's last sensor)."""
    import random
    from hil_tests.fixtures.samples import restamp, screw_doc
    from models_export import export_model
    doc = screw_doc(random.Random(seed), segments=8, dt_s=1.0, length_mm=800.0, feed_max_mm_min=12000.0, speed_effects=True)
    red = doc["thermal"]["reduced"]
    assert red["reversal_um"] and red["travel_heat_K_per_mm"][0] > 0 and red["heat_scale_per_mm"] and min(red["convection_per_mm"]) > 0
    names = list(sensors)
    ren = {"T_base": names[0], "T_air": names[1]}
    red = doc["thermal"]["reduced"]
    red["base_sensor"], red["air_sensor"] = ren[red["base_sensor"]], ren[red["air_sensor"]]
    doc["reference_C"] = {ren[k]: v for k, v in doc["reference_C"].items()}
    env = {ren[k]: v for k, v in doc["envelope"]["temperature_C"].items()}
    for n in names[2:]:
        doc["reference_C"][n] = 20.0
        env[n] = [10.0, 40.0]
    doc["envelope"]["temperature_C"] = env
    doc["envelope"]["position_mm"] = [0.0, 700.0]
    doc["sensors"] = names
    if observer is not None:
        from hil_tests.fixtures.samples import with_screw_observer
        doc["sensors"] = [n for n in names if n != names[2]]
        del doc["reference_C"][names[2]]
        with_screw_observer(doc, names[2], random.Random(seed), settle_s=observer, envelope_C=env[names[2]])
    table = export_model(restamp(doc)).table
    from firmware.table import parse_table
    t = parse_table(table)
    assert t.fg and t.Gv and min(t.D) > 0  # the table carries the speed terms the cycle must evaluate
    assert t.obs == (observer is not None)
    return table


def need_micropython():
    """The chosen MicroPython's path (TCOMP_MICROPYTHON, hil_tests/rig/interpreters.py); missing: the test fails."""
    from hil_tests.rig import interpreters
    try:
        return interpreters.get().require().path
    except interpreters.InterpreterMissing as e:
        pytest.fail(str(e))


def cmd(body):
    """A command line ``$<body>*CRC\\r\\n`` for ``body`` like b"TC,P,1000"."""
    from firmware.crc16 import crc16_ccitt
    return b"$" + body + b"*%04X\r\n" % crc16_ccitt(body)


TEST_KEY = bytes(range(100, 132))  # the board key the firmware tests provision
TEST_NONCE = b"\x5e\x55\x10\x4e"  # the session nonce the fakes' boards draw at boot (fwfakes.make_rig)


def provision(table_dir, key=TEST_KEY):
    """Write the board key where tcomp flash puts it (firmware/auth.py)."""
    with open(os.path.join(str(table_dir), "key.bin"), "wb") as f:
        f.write(key)


def scmd(app, *fields, extra=b"", key=TEST_KEY, counter=None):
    """An authorised command line for ``app``: the next counter after its last one, its session nonce
    (host/board/linkauth.py)."""
    from host.board.linkauth import LinkSigner
    # a commit is bound to its upload (the nonce and counter of the U,B that opened it)
    bound = getattr(app.link, "upload_id", None) or None if tuple(fields[:2]) == ("U", "C") else None
    return LinkSigner(key, app.auth.last if counter is None else counter - 1,
                      _nonce(app)).stream_line(*fields, extra=extra, bound=bound)


def _nonce(app):
    # a firmware before protocol 2 has no session nonce: its tags start with nothing (so the new
    # tests can be run against it and fail for what they test)
    return app.auth.nonce() if hasattr(app.auth, "nonce") else b""


def tagged_chunk(app, off, data, key=TEST_KEY):
    """A U,D line with ``data`` at ``off`` for ``app``'s open upload, tagged as host/board/linkauth.py does."""
    from host.board.link import body, command_line
    from host.board.linkauth import LinkSigner
    f = ("U", "D", off, data.hex().upper())
    return command_line(*(f + (LinkSigner(key).tag(body(f), b"", app.link.upload_id).hex().upper(),)))


def signer_for(app, key=TEST_KEY):
    """A LinkSigner that knows ``app``'s last counter and session nonce, as a controller reading its hello."""
    from host.board.linkauth import LinkSigner
    return LinkSigner(key, app.auth.last, _nonce(app))


def modbus_auth_block(app, req, key=TEST_KEY):
    """The FC16 request (slave 1, no CRC) writing the auth block that authorises the write ``req``."""
    from host.board.linkauth import LinkSigner
    start = req[2] << 8 | req[3]
    if req[1] == 6:
        values = [req[4] << 8 | req[5]]
    else:
        values = [req[7 + 2 * i] << 8 | req[8 + 2 * i] for i in range(req[5])]
    regs = LinkSigner(key, app.auth.last, _nonce(app)).modbus_auth(1, start, values)
    return bytes([1, 16, 0, 8, 0, 10, 20]) + b"".join(v.to_bytes(2, "big") for v in regs)


# positions in a hello split by frames() ("TC", seq, status, "H", then the fields): read from the start, since fields
# are appended after the counter (docs/protocol.md, Versioning)
def _hello_positions():
    from firmware.wire import HELLO_COUNTER

    return 4 + HELLO_COUNTER - 1, 4 + HELLO_COUNTER


HELLO_REFS_AT, HELLO_COUNTER_AT = _hello_positions()


def frames(data):
    """Split device output into frames, checking each CRC; returns lists of str fields."""
    from firmware.crc16 import crc16_ccitt
    out = []
    for line in data.split(b"\r\n"):
        if not line:
            continue
        assert line[:1] == b"$" and line[-5:-4] == b"*", line
        body = line[1:-5]
        assert int(line[-4:], 16) == crc16_ccitt(body), line
        out.append(body.decode().split(","))
    return out


def rig_app(tmp_path, kind="poly_slope", n_max=9, n_ads=2, table=True, extra=None, serial_mode="stream",
            table_kw=None, key=TEST_KEY):
    """An App on fakes with a table in slot A and the board key ``key`` (None: none); returns (app, board)."""
    from fwfakes import make_rig
    from firmware.app import App
    names = ["T%d" % i for i in range(1, n_max + n_ads + 1)]
    if table:
        kw = {"kind": kind, "sensors": names}
        kw.update(table_kw or {})
        (tmp_path / "table_a.bin").write_bytes(make_table(**kw))
    if key is not None:
        provision(tmp_path, key)
    board = make_rig(n_max, n_ads, table_dir=str(tmp_path), extra=extra, serial_mode=serial_mode,
                     serial_size=1 << 20)
    return App(board), board


def run_cycles(app, board, n, dt=100):
    for _ in range(n):
        app.cycle()
        board.clock.t += dt


def compile_mpy(fakes=False):
    """The firmware's .mpy build (host/board/fwbuild.py), as ``tcomp flash`` ships it; returns its folder
    (a MICROPYPATH entry, shared and read-only). ``fakes``: with the register-level fakes
    (tests/firmware/manifest.py, which includes firmware/manifest.py: the same firmware files).

    The unix port loads .mpy without compiling, so the heap the firmware needs is
    that of the code and data, as on a board that ships .mpy files. One option set
    for every build (host/board/fwbuild.py MPY_CROSS_ARGS: -O3, bytecode only).
    """
    from host.board.fwbuild import BOARD_MANIFEST, build
    return build(os.path.join(HERE, "manifest.py") if fakes else BOARD_MANIFEST).root


# MicroPython source: a file whose next write reaches the flash only as far as `view` (a power cut in the middle of a
# record); the warm-state tests (heat.bin, lags.bin) put it in front of their scripts
POWER_CUT_FILE = r"""
class Cut:
    # the power fails after the first k bytes of the record reached the flash
    def __init__(self, f, view):
        self.f = f
        self.view = view
    def seek(self, o, w=0):
        return self.f.seek(o, w)
    def write(self, b):
        return self.f.write(self.view)
    def flush(self):
        self.f.flush()
"""


def run_micropython(script, cwd, path, heap="128K", timeout=120):
    """Run ``script`` (text) on the chosen MicroPython; returns stdout, fails on error.

    The script is run from a file, not with -c: a -c source string stays on the
    heap for the whole run and would distort memory figures.
    """
    import subprocess
    mp = need_micropython()
    env = dict(os.environ, MICROPYPATH=path)
    f = os.path.join(cwd, "_fw_script.py")
    with open(f, "w") as fh:
        fh.write(script)
    p = subprocess.run([mp, "-X", "heapsize=" + heap, f], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, "MicroPython failed:\n" + p.stdout + p.stderr
    return p.stdout


# The benchmarks' cycle (tools/bench_firmware.py on the unix ports, tools/bench_qemu_board.py on the
# emulated board), written once: an 11-channel rig on the fakes warmed up for 100 cycles, and the P
# line fed every cycle; then the fakes' own bus traffic without the firmware, to be subtracted.
BENCH_RIG = r"""
import firmware.app
import fwfakes
from firmware.crc16 import crc16_ccitt
board = fwfakes.make_rig(table_dir=".", extra={"frame_ms": 100})
app = firmware.app.App(board)
for k in range(100):
    app.cycle(); board.clock.t += 100
    board.serial.nout = 0
body = b"TC,P,123456"
cmd = b"$" + body + b"*" + (b"%04X" % crc16_ccitt(body)) + b"\r\n"
"""

BENCH_FAKES = r"""
spi = board.buses["spi0"]; i2c = board.buses["i2c0"]
tx = bytearray(3); rx = bytearray(3); b1 = bytearray(1); b3 = bytearray(3)
pins = [board.pin(10 + i) for i in range(9)]
def fakes_traffic(n):
    for k in range(n):
        for p in pins:
            p.value(0); tx[0] = 1; spi.write_readinto(tx, rx); p.value(1)
        for ad in (0x40, 0x41):
            i2c.readfrom_mem_into(ad, 0x28, b1); i2c.readfrom_mem_into(ad, 0x10, b3)
"""


# The steady-state cycle under micropython.heap_lock() on the unix port (prefix
# "MODE = 'stream'|'modbus'\nN = cycles\n"). Used by test_fw_heaplock.py and by
# tools/bench_firmware.py (smallest heap that works). Prints
# "OK cycles bytes_sent status pos free_delta app_data peak": app_data is the heap
# the running app holds (table, evaluator, channels, drivers, buffers) after boot
# and warm-up, peak the largest live heap after a collection at the end of each
# warm-up cycle (code + fakes + data; transient boot garbage is not in it: the
# smallest heap that works, which tools/bench_firmware.py searches, covers that).
HEAPLOCK_SCRIPT = r"""
import gc, micropython, sys
# the mode's modules first, as main.py on a board would: each import from a file
# needs a contiguous buffer, which a heap full of small objects may no longer have
import firmware.app, firmware.max31865, firmware.ads122c04
__import__("firmware.protocol" if MODE == "stream" else "firmware.modbus")
from firmware.app import App
from firmware.crc16 import crc16_ccitt, crc16_modbus
from fwfakes import make_rig
board = make_rig(table_dir=".", serial_mode=MODE, extra={"frame_ms": 100})
gc.collect()
h1 = gc.mem_alloc()
peak = h1
app = App(board)
for k in range(100):  # warm-up: channels become good, the output ramps up
    app.cycle(); board.clock.t += 100
    board.serial.take()
    gc.collect()
    a = gc.mem_alloc()
    peak = a if a > peak else peak
# MicroPython's GC is conservative: a stale word can keep boot garbage alive for
# a while, so the settled figure is the lowest after a few collections
data = 1 << 30
for k in range(5):
    gc.collect()
    a = gc.mem_alloc() - h1
    data = a if a < data else data
def line(body):
    c = crc16_ccitt(body)
    return b"$" + body + b"*" + b"%04X" % c + b"\r\n"
def rtu(body):
    c = crc16_modbus(body)
    return body + bytes([c & 0xFF, c >> 8])
try:
    DYN  # the prefix may say the table is a dynamic one: the spindle speed and feed are reported too
except NameError:
    DYN = False
if MODE == "stream":
    msgs = [line(b"TC,P,%d" % (1000 * k)) for k in range(10)] + [line(b"TC,Q,250000")]
    if DYN:
        msgs = [line(b"TC,M,%d,0,0" % (1500 * k)) for k in range(3)] + [line(b"TC,P,%d,%d" % (1000 * (k + 1), 900 * k)) for k in range(10)] + msgs
else:
    msgs = [rtu(bytes([1, 16, 0, 3, 0, 2, 4, 0, 0, 0x30, k])) for k in range(10)] + [
        rtu(bytes([1, 4, 0, 0, 0, 15])), rtu(bytes([1, 4, 0, 16, 0, 35]))]
    if DYN:
        msgs += [rtu(bytes([1, 16, 0, 18, 0, 2, 4, 0, 0, 0x10 + k, 0])) for k in range(5)]
OBS = N // 2  # a dynamic table with an observer estimates its states again there (as after a table switch), under the lock
try:
    SUP  # the prefix may say the dynamic table's spindle/feed lags are supplied: at OBS the start waits for them again
except NameError:
    SUP = False
SUP_AT = N - 20  # and there the controller's states come (table format 7)
sup_msg = line(b"TC,Y,0,0,0") if MODE == "stream" else rtu(bytes([1, 16, 0, 20, 0, 6, 12]) + bytes(12))
try:
    SOBS  # the prefix may say the table is a screw table with an observer: it starts the segments again at OBS
except NameError:
    SOBS = False
sent = 0
err = None
free1 = 0  # every global exists before the lock: a new one could grow the module dict
gc.collect()
free0 = gc.mem_free()
micropython.heap_lock()
try:
    for k in range(N):
        if DYN and k == OBS:
            app.unobserved = True
            if SUP:  # waits _SUPPLY_WAIT_MS (100 cycles), starts without them, takes them at SUP_AT
                app.supply = 1
                app.sup_wait_ms = 0
        if SOBS and k == OBS:
            app.unsettled = app.sobs = True
        board.serial.feed(sup_msg if SUP and k == SUP_AT else msgs[k % len(msgs)])
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
a = gc.mem_alloc()
peak = a if a > peak else peak
print("OK", app.cycles, sent, "%08X" % app.status, app.pos, free1 - free0, data, peak)
"""
