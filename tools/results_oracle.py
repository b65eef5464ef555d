"""How far the dynamic model's choice is from the best structure it could have chosen (issue 21; an experiment).

    .venv/bin/python tools/results_oracle.py --split-h H [--split-h H ...] [--channels ch2,...] [--option KEY=VALUE ...]
        [--json OUT]

The held-out RMSE that tools/results_forward.py reports, (a), comes from a structure chosen by forward chaining on
the training span t < H. Here the same search (`tcomp fit` defaults, ``--option`` as there) is scored on the held-out
span itself: the whole run is given, and its forward-chaining blocks are t < H - 2 h, [H - 2 h, H) and t >= H. The
last block is scored exactly as (a) is, a board switched on at H with coefficients fitted on t < H (the worse of the
two starts with the defaults), and it holds most of the pooled score; the 2 h block is there because forward
chaining needs two scored blocks. The candidates are the time constants a fit on t < H may use (its lag bound).

This is an **upper bound** of what any choice could reach, not a result a user can get: the structure is picked on
the data it is scored on, over hundreds of candidate terms, so its score is optimistic. It answers one question: is
the model family (<= 5 sensors, the lag grid, linear) what stops a channel-split from reaching 0.8 x MLR-16, or the
choice made on the past. Every number printed comes from this run.
"""
import argparse
import contextlib
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from host.data.runs import load_run  # noqa: E402
from host.learning.empirical import forward  # noqa: E402
from host.learning.empirical.dynamic import TAU_MAX_FRACTION, TAUS_S  # noqa: E402
from host.learning.empirical.fitting import fit_model  # noqa: E402
from host.learning.empirical.forward import block_residuals  # noqa: E402
from host.learning.empirical.schedule import block_labels  # noqa: E402
from host.options import parse_options  # noqa: E402
from results_forward import write_json  # noqa: E402  (tools/ is the script's directory)

LAST_TRAINING_BLOCK_S = 7200.0  # >= fitting.SWITCHED_ON_MIN_S (90 min), so it is scored switched on like the held-out block


@contextlib.contextmanager
def blocks_at(split_s):
    """forward.forward_blocks replaced, for the dynamic fit only, by three blocks cut at split - 2 h and split."""
    original = forward.forward_blocks

    def three_blocks(runs, arrays, forward_blocks=None):
        t = list(arrays)[0].time_s
        labels = block_labels(t, [split_s - LAST_TRAINING_BLOCK_S, split_s]).astype(int)
        return labels, [{"block": k, "run": 0, "t_start_s": float(t[labels == k].min()), "t_end_s": float(t[labels == k].max())}
                        for k in range(3)]

    forward.forward_blocks = three_blocks
    try:
        yield
    finally:
        forward.forward_blocks = original


def oracle(run, split_s, channel, options):
    held = {"block": 1, "run": 0, "t_start_s": split_s, "t_end_s": float(run.errors.time_s.max())}
    mlr = fit_model([run], "mlr", "direct", channel, window=(None, split_s), reference="fixed")
    m, p = block_residuals(mlr, run, held)
    mlr16 = float(np.sqrt(np.mean((m - p) ** 2)))
    span = split_s - float(run.temperatures.time_s[0])
    taus = [tau for tau in TAUS_S if tau <= TAU_MAX_FRACTION * span]  # what a fit on t < split may use
    t0 = time.perf_counter()
    with blocks_at(split_s):
        dyn = fit_model([run], "dynamic", "direct", channel, **{"taus_s": taus, **options})
    scored = [f for f in dyn.statistics["forward_chaining"]["scored"] if f["block"] == 2][0]
    worse = max(scored["rmse_um"], scored.get("without_record_rmse_um", 0.0))
    return {"mlr16_um": mlr16, "held_out_um": scored["rmse_um"], "held_out_without_record_um": scored.get("without_record_rmse_um"),
            "ratio": scored["rmse_um"] / mlr16, "ratio_worse_start": worse / mlr16, "fit_s": time.perf_counter() - t0,
            "terms": [[n, tau, float(c)] for (n, tau), c in zip(dyn.terms, dyn.term_coefficients)]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default=os.path.join(ROOT, "data", "fl_thermal"))
    ap.add_argument("--split-h", type=float, action="append", required=True, help="split time in hours")
    ap.add_argument("--channels", default="ch1,ch2,ch3,ch4,ch5")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="a dynamic setting (JSON value)")
    ap.add_argument("--json", help="write every figure as JSON")
    args = ap.parse_args(argv)
    options = parse_options(args.option)
    run = load_run(args.run)
    report = {"run": args.run, "dynamic_options": options, "splits": {}}
    print("| split | channel | MLR-16 µm | oracle held-out µm (with / without the record) | ratio to MLR-16 (worse start) | terms |")
    print("|---|---|---|---|---|---|")
    for h in args.split_h:
        split_s = round(h * 3600 / 15) * 15.0  # on the 15 s sample grid, as results_forward.py
        for ch in args.channels.split(","):
            r = report["splits"].setdefault("%.2f" % h, {})[ch] = oracle(run, split_s, ch, options)
            nr = r["held_out_without_record_um"]
            print("| %.2f h | %s | %.2f | %.2f / %s | %.2f | %s |" % (
                h, ch, r["mlr16_um"], r["held_out_um"], "-" if nr is None else "%.2f" % nr, r["ratio_worse_start"],
                ", ".join("%s %g %.3g" % tuple(t) for t in r["terms"])), flush=True)
    if args.json:
        write_json(args.json, args.run, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
