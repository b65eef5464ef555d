"""Run every benchmark script and print their figures (`make bench`).

Each tools/bench_*.py prints its own figures; this runs them one after another
with the project's interpreter so one command gives the whole picture. Pass
names to run a subset: `python tools/bench.py firmware export`.
"""
import glob
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
# The false-discovery-rate sweep is long; `make bench` runs a short form of it.
ARGS = {"discrepancy": ["--seeds", "3", "--jobs", "2"]}


def main(argv):
    names = sorted(os.path.basename(p)[6:-3] for p in glob.glob(os.path.join(HERE, "bench_*.py")))
    wanted = argv or names
    unknown = [n for n in wanted if n not in names]
    if unknown:
        print("unknown benchmark(s): %s (have: %s)" % (", ".join(unknown), ", ".join(names)), file=sys.stderr)
        return 2
    failed = []
    for name in wanted:
        print("\n===== bench_%s =====" % name, flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, os.path.join(HERE, "bench_%s.py" % name)] + ARGS.get(name, []))
        print("----- bench_%s: exit %d, %.1f s" % (name, rc, time.perf_counter() - t0), flush=True)
        if rc:
            failed.append(name)
    if failed:
        print("failed: %s" % ", ".join(failed), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
