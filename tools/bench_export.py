"""Benchmark of the exporter and the firmware's integer evaluation. Prints figures; asserts nothing.

    .venv/bin/python tools/bench_export.py [--repeat N]

Export: wall time of export_model per model kind (sample documents from
hil_tests.fixtures.samples), table size, certified error. Evaluation: microseconds
per call of update / offset_at / ref_offset+slope / step on CPython and on the
MicroPython TCOMP_MICROPYTHON chooses (the firmware's board build, host/board/fwbuild.py, 64 kB heap),
instructions per call under valgrind/callgrind (stable on a loaded machine),
best of several repetitions (the machine may be shared),
and the .mpy size of the three firmware modules as shipped (the board build: -O3, bytecode
only, the same bytes as -march=armv6m for an RP2040).
"""
import argparse
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from firmware.evaluate import Evaluator  # noqa: E402
from firmware.table import parse_table  # noqa: E402
from models_export import export_model  # noqa: E402
from hil_tests.fixtures.samples import linear_direct_doc, poly_slope_doc, screw_doc  # noqa: E402

BIN = REPO / ".venv" / "bin"
from hil_tests.rig import interpreters  # noqa: E402
MICROPYTHON = Path(interpreters.get().path)  # the one TCOMP_MICROPYTHON chooses (default: the 32-bit port)

MP_SCRIPT = """
import time
from firmware.table import parse_table
from firmware.evaluate import Evaluator
f = open(%(path)r, 'rb')
ev = Evaluator(parse_table(f.read()))
f.close()
N = %(n)d
screw = %(screw)s
def bench(ev, N):
    t0 = time.ticks_us()
    for k in range(N):
        ev.update()
    t1 = time.ticks_us()
    for k in range(N):
        ev.offset_at(%(pos)d + k)
    t2 = time.ticks_us()
    for k in range(N):
        ev.ref_offset()
        ev.slope()
    t3 = time.ticks_us()
    t4 = t3
    if screw:
        for k in range(N // 10 + 1):
            ev.advance_position(%(pos)d + (k %% 7) * 1000)
            ev.step()
        t4 = time.ticks_us()
    t5 = time.ticks_us()
    for k in range(N):
        pass
    t6 = time.ticks_us()
    return (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t6 - t5)
r = bench(ev, N)
print(' '.join(str(x) for x in r))
"""


def cpython_bench(ev, n, pos, screw, repeat=5):
    """Best-of-``repeat`` microseconds per call (the machine may be shared: the minimum is the stable figure)."""
    import timeit

    g = {"ev": ev, "pos": pos}
    stmts = ["ev.update()", "ev.offset_at(pos)", "ev.ref_offset(); ev.slope()"]
    out = [min(timeit.repeat(s, globals=g, number=n, repeat=repeat)) / n * 1e6 for s in stmts]
    if screw:
        ns = max(1, n // 10)
        out.append(min(timeit.repeat("ev.advance_position(pos); ev.step()", globals=g, number=ns, repeat=repeat)) / ns * 1e6)
    else:
        out.append(float("nan"))
    return out


CG_SCRIPT = """
from firmware.table import parse_table
from firmware.evaluate import Evaluator
f = open(%(path)r, 'rb')
ev = Evaluator(parse_table(f.read()))
f.close()
def run(ev, n):
    for k in range(n):
        %(stmt)s
run(ev, %(n)d)
"""


def callgrind_per_call(tmp, mpypath, table_path, stmt, n1=50, n2=250):
    """Instructions per call on the MicroPython unix port: (Ir(n2) - Ir(n1)) / (n2 - n1), stable under load."""
    irs = []
    for n in (n1, n2):
        script = tmp / "cg.py"
        script.write_text(CG_SCRIPT % dict(path=str(table_path), stmt=stmt, n=n))
        out = tmp / "cg.out"
        proc = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=%s" % out, str(MICROPYTHON),
                               "-X", "heapsize=64K", str(script)], capture_output=True, text=True,
                              env=dict(os.environ, MICROPYPATH=mpypath))
        if proc.returncode != 0:
            return None
        summary = [line for line in out.read_text().splitlines() if line.startswith("summary:") or line.startswith("totals:")]
        irs.append(int(summary[0].split()[1]))
    return (irs[1] - irs[0]) / (n2 - n1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="exports per model for the timing")
    ap.add_argument("--n", type=int, default=2000, help="evaluations per timing loop")
    ap.add_argument("--no-valgrind", action="store_true", help="skip the callgrind instruction counts")
    args = ap.parse_args()
    cases = [
        ("poly_slope, 11 sensors, degree 3", poly_slope_doc(random.Random(1), n_sensors=11, degree=3)),
        ("linear_direct, 11 sensors", linear_direct_doc(random.Random(2), n_sensors=11)),
        ("screw, 12 segments, base sensor", screw_doc(random.Random(3), segments=12, dt_s=10.0, degree=2)),
        ("screw, 16 segments, dt 1 s", screw_doc(random.Random(4), segments=16, dt_s=1.0, degree=2)),
    ]
    mp_ok = MICROPYTHON.exists() and (BIN / "mpy-cross").exists()
    tmp = Path(tempfile.mkdtemp(prefix="bench_export_"))
    if mp_ok:
        from host.board.fwbuild import build
        board = build()
        mpypath = "%s:%s" % (tmp, board.root)  # the firmware as tcomp flash ships it
    print("export (CPython %s)" % sys.version.split()[0])
    print("  %-36s %9s %7s %11s %9s %6s" % ("model", "export ms", "bytes", "max err um", "headroom", "limbs"))
    tables = []
    for label, doc in cases:
        t0 = time.perf_counter()
        for _ in range(args.repeat):
            ex = export_model(doc)
        dt = (time.perf_counter() - t0) / args.repeat
        r = ex.report
        limbs = r.get("screw", {}).get("state_limbs", "-")
        print("  %-36s %9.1f %7d %11.5f %9.2f %6s" % (label, dt * 1e3, r["table_bytes"], r["max_error_um"], r["min_headroom_bits"], limbs))
        tables.append((label, ex))
    print("\nevaluation, us per call: update | offset_at | ref_offset+slope | advance_position+step")
    for label, ex in tables:
        t = parse_table(ex.table)
        ev = Evaluator(t)
        pos = (t.pos_lo + t.pos_hi) // 2
        screw = t.kind == "screw_reduced"
        cp = cpython_bench(ev, args.n, pos, screw)
        print("  %-36s CPython     %7.2f | %7.2f | %7.2f | %8.1f" % (label, *cp))
        if mp_ok:
            path = tmp / "table.bin"
            path.write_bytes(ex.table)
            script = tmp / "bench.py"
            script.write_text(MP_SCRIPT % dict(path=str(path), n=args.n, screw=screw, pos=pos))
            runs = []
            for _ in range(3):  # best of three runs, as for CPython
                out = subprocess.run([str(MICROPYTHON), "-X", "heapsize=64K", str(script)], capture_output=True, text=True,
                                     env=dict(os.environ, MICROPYPATH=mpypath), check=True).stdout.split()
                runs.append([int(v) for v in out])
            us = [min(col) for col in zip(*runs)]
            loop = us[4] / args.n
            ns = args.n // 10 + 1
            vals = [us[0] / args.n - loop, us[1] / args.n - loop, us[2] / args.n - loop, us[3] / ns if screw else float("nan")]
            print("  %-36s MicroPython %7.2f | %7.2f | %7.2f | %8.1f" % ("", *vals))
    if mp_ok and not args.no_valgrind and shutil.which("valgrind"):
        it = interpreters.get()
        print("\ninstructions per call on MicroPython %s (%d-bit; valgrind --tool=callgrind):" % (it.kind, it.bits))
        for label, ex in tables:
            t = parse_table(ex.table)
            path = tmp / "table.bin"
            path.write_bytes(ex.table)
            pos = (t.pos_lo + t.pos_hi) // 2
            stmts = [("update", "ev.update()"), ("offset_at", "ev.offset_at(%d)" % pos)]
            if t.kind == "screw_reduced":
                stmts.append(("advance_position+step", "ev.advance_position(%d + (k %% 5) * 1000); ev.step()" % pos))
            figs = []
            for name, stmt in stmts:
                ir = callgrind_per_call(tmp, mpypath, path, stmt)
                figs.append("%s %s" % (name, "%.0f" % ir if ir is not None else "n/a"))
            print("  %-36s %s" % (label, " | ".join(figs)))
    if mp_ok:
        print("\n.mpy size as shipped (board build, host/board/fwbuild.py):")
        total = 0
        sizes = {t: os.path.getsize(p) for t, p in board.files}
        for name in ("crc32", "table", "evaluate"):
            total += sizes["firmware/%s.mpy" % name]
            print("  firmware/%-12s %6d bytes" % (name + ".mpy", sizes["firmware/%s.mpy" % name]))
        print("  %-22s %6d bytes" % ("total", total))


if __name__ == "__main__":
    main()
