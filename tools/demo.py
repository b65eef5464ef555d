"""The main job on the bundled data, as `make demo` runs it.

simulate -> validate -> fit (empirical and screw) -> compare -> export -> run the
real firmware on the HIL rig -> compare the firmware's offsets with the host model.
Each step is a `tcomp` command line, printed before it runs, so a user can repeat
any of them by hand.
"""
import argparse
import glob
import os
import shlex
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from host.cli import _verbs, main as tcomp  # noqa: E402


def step(title, argv):
    print("\n== %s\n$ tcomp %s" % (title, " ".join(shlex.quote(a) for a in argv)), flush=True)
    t0 = time.perf_counter()
    rc = tcomp(argv)
    print("   (%.1f s, exit %d)" % (time.perf_counter() - t0, rc), flush=True)
    if rc not in (0, None):
        raise SystemExit("demo step failed: %s" % title)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="out/demo")
    args = ap.parse_args()
    out = args.out
    os.makedirs(out, exist_ok=True)
    verbs = _verbs()
    demo_runs = sorted(d for d in glob.glob(os.path.join(ROOT, "data", "demo", "*")) if os.path.isdir(d))
    real = os.path.join(ROOT, "data", "fl_thermal")
    step("check the bundled runs", ["validate"] + demo_runs + [real])
    missing = [v for v in ("simulate", "fit", "compare", "export", "hil") if v not in verbs]
    if missing:
        print("\n(verbs not built yet, skipped: %s)" % ", ".join(missing))
    if "simulate" in verbs:
        step("digital twin: one more run with a hidden effect", ["simulate", "--out", os.path.join(out, "twin"), "--seed", "7", "--effects", "bearing_heat"])
    if not demo_runs:
        return 0
    train = demo_runs[0]
    if "compare" in verbs:
        step("empirical models and sensor selectors, fitted on one run, predicting the others",
             ["compare"] + demo_runs + ["--json", os.path.join(out, "compare.json")])
    step("fit a polynomial-plus-slope MLR model", ["fit", "--model", "mlr", train, "--out", os.path.join(out, "mlr.json")])
    step("fit the screw heat-transfer model", ["fit", "--model", "screw", train, "--out", os.path.join(out, "screw.json")])
    for other in demo_runs[1:2]:
        step("predict another run with the screw model", ["predict", os.path.join(out, "screw.json"), other, "--out", os.path.join(out, "screw_pred.csv")])
    if "export" in verbs:
        step("export the MLR model to an integer table", ["export", os.path.join(out, "mlr.json"), "--out", os.path.join(out, "mlr.bin"),
                                                          "--report", os.path.join(out, "mlr_report.json")])
        step("export the screw model to an integer table", ["export", os.path.join(out, "screw.json"), "--out", os.path.join(out, "screw.bin"),
                                                            "--report", os.path.join(out, "screw_report.json")])
    if "hil" in verbs:
        step("run the real firmware (MicroPython) on simulated Pt100 chips", ["hil", "--run", demo_runs[1], "--table", os.path.join(out, "screw.bin"),
                                                                               "--interpreter", "micropython", "--json", os.path.join(out, "hil.json")])
    print("\ndemo outputs in %s" % out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
