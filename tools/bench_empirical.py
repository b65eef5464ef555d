"""Benchmark: wall time of the full `tcomp compare` on the bundled runs (budget: < 30 s on 2 cores).

    .venv/bin/python tools/bench_empirical.py [--runs data/demo/*] [--repeat 3] [--plots]

Runs the real command line in a fresh process (interpreter start and imports
included), as a user would, and prints the wall time of each repetition, the
best and the median, plus the time each method took inside the comparison
(from the JSON it writes) and the same for `--train all` (every run in turn).
Then the wall time of `tcomp fit --model ann|dynamic` on the real FL_THERMAL
record (channel ch1, 11 115 samples, 16 candidate sensors), the two fits whose
cost grows with the data (training epochs; the lag-filter search).
"""
import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUDGET_S = 30.0


def timed(argv):
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "host"] + argv, cwd=ROOT, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit("tcomp %s failed (exit %d):\n%s" % (" ".join(argv), proc.returncode, proc.stderr))
    return dt


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="*", help="run folders (default: every folder in data/demo)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--plots", action="store_true", help="also write the plots (part of the timed work)")
    args = ap.parse_args(argv)
    runs = args.runs or sorted(d for d in glob.glob(os.path.join(ROOT, "data", "demo", "*")) if os.path.isdir(d))
    if len(runs) < 2:
        raise SystemExit("need at least 2 runs (data/demo is empty?)")
    print("tcomp compare on %d runs: %s" % (len(runs), ", ".join(os.path.basename(r) for r in runs)))
    print("cpu count %s; budget %.0f s" % (os.cpu_count(), BUDGET_S))
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "cmp.json")
        for label, extra in (("train on run 0, predict the others", []), ("--train all (each run in turn)", ["--train", "all"])):
            cmd = ["compare"] + runs + ["--json", out] + extra + (["--plots", os.path.join(tmp, "plots")] if args.plots else [])
            times = [timed(cmd) for _ in range(args.repeat)]
            doc = json.load(open(out))
            per = {}
            for r in doc["results"]:
                per[r["method"]] = per.get(r["method"], 0.0) + r.get("seconds", 0.0)
            print("\n%s%s" % (label, " with plots" if args.plots else ""))
            print("  wall time per run of the command: %s s" % ", ".join("%.2f" % t for t in times))
            print("  best %.2f s, median %.2f s -> %s the %.0f s budget" % (
                min(times), statistics.median(times), "within" if statistics.median(times) < BUDGET_S else "OVER", BUDGET_S))
            print("  time inside the comparison per method (last repetition): " + ", ".join("%s %.2f s" % kv for kv in per.items()))
        fl = os.path.join(ROOT, "data", "fl_thermal")
        if os.path.isdir(fl):
            print("\nreal record %s, channel ch1" % os.path.relpath(fl, ROOT))
            for model in ("ann", "dynamic"):
                t = timed(["fit", "--model", model, "--direct", "--channel", "ch1", fl, "--out", os.path.join(tmp, model + ".json")])
                print("  tcomp fit --model %s: %.2f s wall" % (model, t))
    return 0


if __name__ == "__main__":
    sys.exit(main())
