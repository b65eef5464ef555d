"""Firmware budgets, measured: cycle time, instructions per cycle, .mpy size, heap.

    .venv/bin/python tools/bench_firmware.py [--cycles N] [--no-valgrind] [--interpreter KIND|PATH] [--heaps-only]

The interpreter is the one TCOMP_MICROPYTHON chooses (hil_tests/rig/interpreters.py; default the
32-bit port ports/linux32), or --interpreter (``unix64``: the 64-bit unix wheel).

Prints
- cycle time for 11 channels (9 MAX31865 on SPI + 2 ADS122C04 on I2C,
  register-level fakes from tests/firmware/fwfakes.py) on the MicroPython unix
  port, poly_slope table, one $TC frame per cycle and a position report every
  cycle: mean and worst over N cycles (wall clock, so it varies with load);
- instructions per steady-state cycle under ``valgrind --tool=callgrind``
  (stable): the difference in total instructions between two runs with
  different cycle counts, divided by the difference;
- the size of every file firmware/manifest.py puts on a board, as host/board/fwbuild.py
  builds it for ``tcomp flash`` (-O3, bytecode only: byte for byte what
  ``mpy-cross -march=armv6m`` gives, the firmware has no native code), next to
  the same files at -O0 (the firmware has no asserts or ``__debug__`` blocks,
  so -O3 only drops line numbers from tracebacks): the whole build, the
  manifest's per-mode builds (``serial="stream"`` / ``"modbus"``), and per
  serial mode what a booted board loads (a board runs in ONE mode: the stream
  link or the Modbus link is imported only when configured; the boot-only
  config check ``bootcfg.py`` counts, it is on flash); target < 24 kB.
  The files the manifest leaves off (``NOT_ON_BOARD``: ``linux_adapters.py``,
  ``boards/linux.py``, ``wire.py``) are not counted;
- heap on the unix port (a 64-bit build: objects and loaded bytecode are
  about twice their size on a 32-bit MCU), per serial mode with the firmware
  loaded from the same build: code of the modules that mode imports, the test
  fakes, data of the running app after warm-up (target < 16 kB), the largest
  live heap, and the smallest ``-X heapsize`` (binary search, 1 kB steps) with
  which boot, warm-up and heap-locked cycles run (the script of
  tests/firmware/test_fw_heaplock.py, fwhelpers.HEAPLOCK_SCRIPT).
The fakes' own cost is included in cycle time and instructions, and measured
separately (a cycle of the bare fakes) so it can be subtracted.
- evaluation cost per table kind (``--eval-only`` prints only this): the
  evaluator alone (no channels, no link), 11 sensors, on the unix port from
  -O3 .mpy: microseconds per ``update()``, per ``step()`` and per
  ``offset_at()`` (mean over N calls, wall clock), and callgrind instructions
  per ``update() + step() + offset_at()`` (difference of two runs). The
  dynamic table is the FL_THERMAL ch1 model (hil_tests/fixtures/
  dynamic_fl_thermal_ch1.json: 7 lag filters, 3 sensors) and a 6-filter
  table over all 11 channels; poly_slope for comparison.
Then the figures on the emulated Cortex-M3 board (tools/bench_qemu_board.py: instructions per
cycle and per table kind, on M3 and M0+ code; heap with the firmware frozen).
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests", "firmware"))
MP = None  # the interpreter's executable, set by main() (hil_tests/rig/interpreters.py)

from fwhelpers import BENCH_FAKES, BENCH_RIG  # noqa: E402 (after the sys.path lines)

SCRIPT = "import time\n" + BENCH_RIG + r"""
N = NCYC
worst = 0
t0 = time.ticks_us()
for k in range(N):
    board.serial.feed(cmd)
    a = time.ticks_us()
    app.cycle()
    d = time.ticks_diff(time.ticks_us(), a)
    if d > worst:
        worst = d
    board.clock.t += 100
    board.serial.nout = 0
total = time.ticks_diff(time.ticks_us(), t0)
""" + BENCH_FAKES + r"""
a = time.ticks_us()
fakes_traffic(FAKEN)
fakes = time.ticks_diff(time.ticks_us(), a) * 1000 // FAKEN
print("RESULT", total // N, worst, fakes // 1000)
"""


EVAL_SCRIPT = r"""
import time
from firmware.table import parse_table
from firmware.evaluate import Evaluator
f = open("TABLE", "rb"); buf = f.read(); f.close()
ev = Evaluator(parse_table(buf))
n = len(ev.temps)
dyn = ev.kind == 4
if ev.table.ref_mode == 1:
    ev.latch_references()
N = NCYC
def run(N):
    for k in range(N):
        for i in range(n):
            ev.temps[i] = ev.table.ref[i] + (k * 37 + i * 11) % 3000
        if dyn:
            ev.set_spindle((k * 53) % 6000)
        ev.update()
        ev.step() if dyn else None
        ev.offset_at((k * 997) % 500000)
run(N)
t = [0, 0, 0]
for k in range(N):
    for i in range(n):
        ev.temps[i] = ev.table.ref[i] + (k * 37 + i * 11) % 3000
    a = time.ticks_us(); ev.update(); b = time.ticks_us()
    if dyn:
        ev.step()
    c = time.ticks_us(); ev.offset_at((k * 997) % 500000); d = time.ticks_us()
    t[0] += time.ticks_diff(b, a); t[1] += time.ticks_diff(c, b); t[2] += time.ticks_diff(d, c)
print("RESULT", t[0] * 1000 // N, t[1] * 1000 // N, t[2] * 1000 // N)
"""


def eval_tables(work):
    """(label, path) of the tables the evaluation-cost section measures."""
    import json
    from fwhelpers import dynamic_table, make_table
    from models_export import export_model
    names = ["T%d" % i for i in range(1, 12)]
    out = []
    with open(os.path.join(ROOT, "hil_tests", "fixtures", "dynamic_fl_thermal_ch1.json")) as fh:
        doc = json.load(fh)
    for label, table in (("poly_slope, 11 sensors", make_table(kind="poly_slope", sensors=names)),
                         ("dynamic, FL_THERMAL ch1 (7 filters, 3 sensors, 15 s step)", export_model(doc).table),
                         ("dynamic, 6 filters over 11 sensors (1 s step)", dynamic_table(names))):
        path = os.path.join(work, "eval%d.bin" % len(out))
        with open(path, "wb") as fh:
            fh.write(table)
        out.append((label, path))
    return out


def eval_cost(work, mpy, n, valgrind):
    for label, path in eval_tables(work):
        script = EVAL_SCRIPT.replace("TABLE", path)
        p = run_mp(work, mpy, n, script=script)
        upd, stp, off = [int(x) / 1000.0 for x in p.stdout.split("RESULT")[1].split()]
        line = "  %s: update %.1f us, step %.1f us, offset_at %.1f us (mean over %d calls)" % (label, upd, stp, off, n)
        if valgrind:
            a, b = 100, 600
            ir = []
            for k in (a, b):
                out = os.path.join(work, "cge.out")
                q = run_mp(work, mpy, k, ["valgrind", "--tool=callgrind", "--callgrind-out-file=" + out], script=script)
                m = re.search(r"Collected\s*:\s*(\d+)", q.stderr)
                if not m:
                    with open(out) as fh:
                        m = re.search(r"^summary:\s*(\d+)", fh.read(), re.M)
                ir.append(int(m.group(1)))
            # each run does N warm-up and N timed iterations: 2 (b - a) iterations apart
            line += "; %d instructions per update + step + offset_at (callgrind)" % ((ir[1] - ir[0]) // (2 * (b - a)))
        print(line)


def board_sizes(opt_args=None, **options):
    """[(path under firmware/, .mpy bytes)] of the board build (host/board/fwbuild.py, firmware/manifest.py
    with ``options``); ``opt_args``: the same files compiled with other mpy-cross options instead."""
    from host.board.fwbuild import build, load_manifest, mpy_cross
    if opt_args is None:
        return [(t[len("firmware/"):-4] + ".py", os.path.getsize(p)) for t, p in build(**options).files]
    out = []
    with tempfile.TemporaryDirectory() as d:
        for e in load_manifest(**options).entries:
            mpy = os.path.join(d, "x.mpy")
            subprocess.run([mpy_cross()] + list(opt_args) + ["-s", e.target, "-o", mpy, e.source], check=True)
            out.append((e.target[len("firmware/"):], os.path.getsize(mpy)))
    return out


def prepare(work):
    from fwhelpers import make_table
    names = ["T%d" % i for i in range(1, 12)]
    with open(os.path.join(work, "table_a.bin"), "wb") as f:
        f.write(make_table(kind="poly_slope", sensors=names))


def run_mp(work, mpy, n, wrapper=(), faken=None, script=None):
    env = dict(os.environ, MICROPYPATH=mpy)
    script = (script or SCRIPT).replace("NCYC", str(n)).replace("FAKEN", str(faken or n))
    p = subprocess.run(list(wrapper) + [MP, "-X", "heapsize=256K", "-c", script],
                       cwd=work, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit("MicroPython run failed:\n" + p.stdout + p.stderr)
    return p


LOADED = r"""
import sys, fwfakes
from firmware.app import App
board = fwfakes.make_rig(N_MAX, N_ADS, table_dir=".", serial_mode=MODE)
app = App(board)
for k in range(20):
    app.cycle(); board.clock.t += 100
print("LOADED", " ".join(sorted(m for m in sys.modules if m.startswith("firmware."))))
"""


def loaded_modules(work, mpy, n_max, n_ads, mode):
    """Firmware modules a booted board of this kind has imported (config is unloaded after boot).

    The board file itself imports firmware.board (``Board``, ``SystemClock``), so it counts too.
    """
    env = dict(os.environ, MICROPYPATH=mpy)
    script = LOADED.replace("N_MAX", str(n_max)).replace("N_ADS", str(n_ads)).replace("MODE", repr(mode))
    p = subprocess.run([MP, "-X", "heapsize=256K", "-c", script], cwd=work, env=env, capture_output=True,
                       text=True)
    if p.returncode != 0:
        raise SystemExit("MicroPython run failed:\n" + p.stdout + p.stderr)
    names = p.stdout.split("LOADED")[1].split()
    # main.py runs the app and bootcfg.py is imported at boot (then dropped): both are on flash
    return sorted(set(n.split(".", 1)[1].replace(".", "/") + ".py" for n in names)
                  | {"main.py", "bootcfg.py", "board.py"})


MODE_HEAP = r"""
import gc
gc.collect(); h0 = gc.mem_alloc()
import firmware.app, firmware.max31865, firmware.ads122c04
__import__("firmware.protocol" if MODE == "stream" else "firmware.modbus")
gc.collect(); h1 = gc.mem_alloc()
import fwfakes
board = fwfakes.make_rig(table_dir=".", serial_mode=MODE)
gc.collect(); h2 = gc.mem_alloc()
print("MODEHEAP", h1 - h0, h2 - h1)
"""


def mode_heap(work, mpy, mode):
    """Per serial mode on the unix port: heap of the loaded code, of the fakes, app data, and the
    smallest -X heapsize (kB) with which boot, warm-up and 50 cycles under heap_lock work."""
    from fwhelpers import HEAPLOCK_SCRIPT
    env = dict(os.environ, MICROPYPATH=mpy)
    f = os.path.join(work, "_mode_heap.py")
    with open(f, "w") as fh:
        fh.write("MODE = %r\n" % mode + MODE_HEAP)
    p = subprocess.run([MP, "-X", "heapsize=256K", f], cwd=work, env=env, capture_output=True, text=True)
    code, fakes = [int(x) for x in p.stdout.split("MODEHEAP")[1].split()]
    with open(f, "w") as fh:
        fh.write("MODE = %r\nN = 50\n" % mode + HEAPLOCK_SCRIPT)

    def run(k):
        p = subprocess.run([MP, "-X", "heapsize=%dK" % k, f], cwd=work, env=env, capture_output=True,
                           text=True)
        return p.stdout.split() if p.returncode == 0 and p.stdout.startswith("OK") else None

    lo, hi = 32, 256
    while hi - lo > 1:
        m = (lo + hi) // 2
        if run(m):
            hi = m
        else:
            lo = m
    out = run(256)
    return code, fakes, int(out[6]), int(out[7]), hi


def callgrind_ir(work, mpy, n):
    out = os.path.join(work, "cg.out")
    # the fakes-only loop runs a fixed number of times so that it cancels in the difference
    p = run_mp(work, mpy, n, ["valgrind", "--tool=callgrind", "--callgrind-out-file=" + out], faken=10)
    m = re.search(r"Collected\s*:\s*(\d+)", p.stderr)
    if not m:
        with open(out) as f:
            m = re.search(r"^summary:\s*(\d+)", f.read(), re.M)
    return int(m.group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--no-valgrind", action="store_true")
    ap.add_argument("--eval-only", action="store_true", help="only the evaluation cost per table kind")
    ap.add_argument("--interpreter", default=None, help="a kind (linux32, unix64) or a path; default TCOMP_MICROPYTHON")
    ap.add_argument("--heaps-only", action="store_true", help="only the heap figures")
    args = ap.parse_args()
    global MP
    from hil_tests.rig import interpreters
    it = interpreters.get(args.interpreter)
    try:
        MP = it.require().path
    except interpreters.InterpreterMissing as e:
        sys.exit(str(e))
    with tempfile.TemporaryDirectory() as work:
        from fwhelpers import compile_mpy
        mpy = compile_mpy(fakes=True)  # the board build plus the fakes (tests/firmware/manifest.py)
        prepare(work)
        if args.heaps_only:
            print_heaps(work, mpy, it)
            return
        valgrind = not args.no_valgrind and bool(shutil.which("valgrind"))
        print("evaluation cost per table kind (MicroPython %s %s, %d-bit, -O3 .mpy; timings are "
              "wall clock, so they vary with load):" % (_mp_version(), it.kind, it.bits))
        eval_cost(work, mpy, args.cycles, valgrind)
        if args.eval_only:
            return
        sizes = {0: board_sizes(["-O0"]), 3: board_sizes()}

        p = run_mp(work, mpy, args.cycles)
        mean_us, worst_us, fakes_us = [int(x) for x in p.stdout.split("RESULT")[1].split()]
        print("MicroPython %s %s (%d-bit), 11 channels, poly_slope table" % (_mp_version(), it.kind, it.bits))
        print("  cycle time: mean %d us, worst %d us over %d cycles (fakes' own share ~%d us)"
              % (mean_us, worst_us, args.cycles, fakes_us))
        if not args.no_valgrind and shutil.which("valgrind"):
            a, b = 50, 250
            ia = callgrind_ir(work, mpy, a)
            ib = callgrind_ir(work, mpy, b)
            print("  instructions per cycle (callgrind, steady state): %d" % ((ib - ia) // (b - a)))
        else:
            print("  instructions per cycle: skipped (valgrind not run)")
        from host.board.fwbuild import MPY_CROSS_ARGS
        print("board build sizes (firmware/manifest.py via host/board/fwbuild.py, mpy-cross %s as shipped; -O0 for"
              " comparison; = -march=armv6m bytes):" % " ".join(MPY_CROSS_ARGS))
        print("  %-24s %8s %8s" % ("module", "-O0", "-O3"))
        for (rel, s0), (_, s3) in zip(sizes[0], sizes[3]):
            print("  %-24s %6d B %6d B" % (rel, s0, s3))
        for opt in (0, 3):
            total = sum(s for _, s in sizes[opt])
            print("  -O%d total, every file tcomp flash ships (%d): %d B = %.1f kB (target < 24 kB): %s"
                  % (opt, len(sizes[opt]), total, total / 1024, "met" if total < 24 * 1024 else "NOT met"))
        for mode in ("stream", "modbus"):
            sub = board_sizes(serial=mode)
            total = sum(s for _, s in sub)
            print("  manifest serial=%r (both drivers, example board file): %d files, %d B = %.1f kB"
                  % (mode, len(sub), total, total / 1024))
        for label, args_ in (("stream board (9 MAX31865 + 2 ADS122C04, $TC stream)", (9, 2, "stream")),
                             ("stream board, MAX31865 channels only", (11, 0, "stream")),
                             ("modbus board (9 MAX31865 + 2 ADS122C04, Modbus RTU)", (9, 2, "modbus")),
                             ("modbus board, ADS122C04 channels only", (0, 11, "modbus"))):
            mods = loaded_modules(work, mpy, *args_)
            sub = [sum(dict(sizes[opt])[m] for m in mods) for opt in (0, 3)]
            print("  %s loads %d modules: -O0 %d B = %.1f kB, -O3 %d B = %.1f kB (target < 24 kB): %s"
                  % (label, len(mods), sub[0], sub[0] / 1024, sub[1], sub[1] / 1024,
                     "met" if sub[1] < 24 * 1024 else "NOT met"))
            print("    (%s, plus the board file)" % " ".join(m[:-3] for m in mods))
        print_heaps(work, mpy, it)
    print()
    import bench_qemu_board  # the same budgets on the emulated Cortex-M3 board (tools/bench_qemu_board.py)
    bench_qemu_board.main()


def print_heaps(work, mpy, it):
    print("heap per serial mode on %s (%d-bit%s; .mpy bytecode is copied into the heap), firmware from -O3 .mpy:"
          % (it.kind, it.bits, ": pointers and objects twice a 32-bit MCU's" if it.bits == 64 else ""))
    for mode in ("stream", "modbus"):
        code, fakes, data, peak, smallest = mode_heap(work, mpy, mode)
        print("  %s: code %d B, test fakes %d B, app data after warm-up %d B = %.1f kB (target < 16 kB):"
              " %s; largest live heap (code + fakes + data) %d B; smallest -X heapsize that runs boot, warm-up"
              " and 50 heap-locked cycles: %d kB"
              % (mode, code, fakes, data, data / 1024, "met" if data < 16 * 1024 else "NOT met", peak,
                 smallest))


def _mp_version():
    p = subprocess.run([MP, "-c", "import sys; print(sys.implementation.version[:3])"],
                       capture_output=True, text=True)
    return p.stdout.strip()


if __name__ == "__main__":
    main()
