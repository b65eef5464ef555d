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

from host.cli import main as tcomp  # noqa: E402


def step(title, argv):
    print("\n== %s\n$ tcomp %s" % (title, " ".join(shlex.quote(a) for a in argv)), flush=True)
    t0 = time.perf_counter()
    rc = tcomp(argv)
    print("   (%.1f s, exit %d)" % (time.perf_counter() - t0, rc), flush=True)
    if rc not in (0, None):
        raise SystemExit("demo step failed: %s" % title)


def _rmse(a):
    import numpy as np

    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def summarise(run_dir, pred_csv, hil_json, certified_um):
    """Measured error vs host float model vs firmware integer offsets, on one run."""
    import csv
    import json

    import numpy as np

    from host.data.runs import load_run

    run = load_run(run_dir)
    with open(pred_csv) as fh:
        host = np.array([float(r["predicted_um"]) for r in csv.DictReader(fh)])
    with open(hil_json) as fh:
        answers = json.load(fh)["answers"]
    fw = np.array([a["offset_um"] for a in answers], dtype=float)
    measured = run.errors.error_um
    print("\n== result on %s (%d laser points; the firmware never saw the errors)" % (os.path.basename(run_dir), measured.size))
    print("   measured thermal+geometric error, RMS              %7.3f um" % _rmse(measured))
    print("   residual after host model (float)  RMS             %7.3f um" % _rmse(measured - host))
    print("   residual after firmware offsets    RMS             %7.3f um" % _rmse(measured - fw))
    print("   firmware vs host model: max |diff| %.4f um, RMS %.4f um" % (np.nanmax(np.abs(fw - host)), _rmse(fw - host)))
    clamped = sum(1 for a in answers if int(a["status"], 16) & (1 << 16))
    print("   answers with an input clamped to the table's envelope (status bit 16): %d of %d" % (clamped, len(answers)))
    print("   (of the firmware-vs-host difference, the integer arithmetic accounts for at most %.4f um, the exporter's"
          " certificate; the rest is what separates the firmware's inputs and model from the host's: the reduced"
          " 12-segment recurrence on a 10 s step, feed/range motion reports instead of the exact nut path, and the"
          " simulated RTD chain. hil_tests/test_hil_e2e.py checks the firmware against the reduced model on the"
          " same travel within the certificate plus the RTD bound.)" % certified_um)


def main():
    import json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="out/demo")
    args = ap.parse_args()
    out = args.out
    os.makedirs(out, exist_ok=True)
    demo = os.path.join(ROOT, "data", "demo")
    demo_runs = sorted(d for d in glob.glob(os.path.join(demo, "*")) if os.path.isdir(d))
    real = os.path.join(ROOT, "data", "fl_thermal")
    train = os.path.join(demo, "v8000_r210_490")
    test = os.path.join(demo, "v15000_r210_490")
    o = lambda name: os.path.join(out, name)  # noqa: E731
    step("check the bundled runs", ["validate"] + demo_runs + [real])
    step("digital twin: a new run with a hidden bearing-heat effect", ["simulate", "--out", o("twin"), "--seed", "7", "--effects", "bearing_heat"])
    step("empirical models and sensor selectors: fit on one moving state, predict the others",
         ["compare"] + demo_runs + ["--json", o("compare.json")])
    step("fit the screw heat-transfer model on one moving state (8000 mm/min over 210-490 mm)",
         ["fit", "--model", "screw", train, "--out", o("screw.json"), "--json", o("screw_fit.json"),
          # the exported envelope must cover every feed the machine will run, not only the training feed
          "--option", "feed_max_mm_min=20000"])
    step("predict an unseen moving state (15000 mm/min) with the host model", ["predict", o("screw.json"), test, "--out", o("screw_pred.csv")])
    step("which physical effect is the base screw model missing? (held out, leave-one-run-out)",
         ["discrepancy", os.path.join(demo, "v6500_r210_490"), test, os.path.join(demo, "mixed"), "--json", o("discrepancy.json"), "--report", o("discrepancy")])
    step("export the screw model to a certified integer table", ["export", o("screw.json"), "--out", o("screw.bin"), "--report", o("screw_report.json")])
    step("run the real firmware (32-bit MicroPython, ports/linux32, or TCOMP_MICROPYTHON) on simulated MAX31865/ADS122C04 chips, read over a pty",
         ["hil", "--run", test, "--table", o("screw.bin"), "--interpreter", "micropython", "--json", o("hil.json"), "--print-every", "120"])
    with open(o("screw_report.json")) as fh:
        certified = json.load(fh)["max_error_um"]
    summarise(test, o("screw_pred.csv"), o("hil.json"), certified)
    print("\ndemo outputs in %s" % out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
