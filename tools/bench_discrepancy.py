"""Benchmark of `tcomp discrepancy`: false-discovery rate, detection rate and speed over many seeds.

For every seed the digital twin writes a set of runs (the literature's moving
states 1, 2, 3 and 5, in a drifting shop air) with
  - no effect hidden (the null): anything named is a false discovery;
  - each catalog effect hidden at a random realistic magnitude (0.5-1.5 x the
    twin's default): the effect must be named first and the held-out RMSE at
    least halved;
  - two effects hidden at once (a pair from PAIRS, rotating with the seed): both
    must be named;
at a random laser noise level (0.3-1.0 um). Every other null seed writes
bidirectional sweeps with a zero reversal value, so ``reversal_error`` is tested
on the null too. On the null it also prints the base model's held-out RMSE over
the laser noise (budget <= 1.25) and the residual diagnostic's strongest
|partial r| (host/learning/discrepancy/unexplained.py: its threshold is set above what the
null reaches). Prints the rates and wall times (budget: 60 s on four runs, 2 cores).
Every scenario is run under each error reference of --references (issue 19: the
twin writes raw errors, "start", or errors corrected to its air sensor T3 by a
laser's material-temperature compensation, and meta.json declares it); the last
lines are one table row per reference.

    .venv/bin/python tools/bench_discrepancy.py [--seeds 40] [--first-seed 1000] [--jobs 2] [--references start,T3]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from host.learning.discrepancy import unexplained
from host.learning.discrepancy.report import residual_diagnostic
from host.learning.discrepancy.family import ScrewFamily
from host.learning.discrepancy.workflow import discover
from host.twin import EFFECTS, simulate_run

PROTOCOLS = ("v8000_r210_490", "v6500_r210_490", "v15000_r210_490", "v8000_r0_700")  # literature states 1, 2, 3, 5
PAIRS = (("ambient_expansion", "moving_convection"), ("bearing_heat", "reversal_error"),
         ("speed_dependent_heat", "ambient_expansion"), ("moving_convection", "bearing_heat"))
# raw errors, and errors corrected to the twin's air sensor by the laser's material-temperature compensation
REFERENCES = ("start", "T3")
CATALOG_EFFECTS = ("ambient_expansion", "speed_dependent_heat", "bearing_heat", "moving_convection", "reversal_error")


def scenario(seed, effects, noise, protocols=PROTOCOLS, reference="start"):
    return [simulate_run(p, effects=effects, seed=seed, noise_um=noise, error_reference=reference) for p in protocols]


def _cpu_s():
    """CPU seconds of this process and its reaped children (discover's worker pool is shut down before it returns)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def timed_discover(runs, family, jobs, times, cpu):
    """One workflow on already simulated runs; appends its wall and CPU seconds (the twin's own time excluded)."""
    t0, c0 = time.perf_counter(), _cpu_s()
    res = discover(runs, family, jobs=jobs)
    times.append(time.perf_counter() - t0)
    cpu.append(_cpu_s() - c0)
    return res


class Tally:
    """One reference's figures over the seeds."""

    def __init__(self, effects):
        self.pair_hits = self.pair_n = 0
        self.null_false, self.null_times, self.null_gains = 0, [], []
        self.null_ratio, self.null_r, self.null_flagged = [], [], 0
        self.hits = {e: [0, 0] for e in effects}  # named first, halved
        self.floor = {e: [] for e in effects}  # held-out RMSE after / laser noise
        self.times, self.cpu = [], []


def run_seed(k, seed, reference, effects, protocols, jobs, pairs, tally):
    """Every scenario of one seed under one error reference; returns the seed's line."""
    tl = tally
    rng = np.random.default_rng(seed)
    noise = float(rng.uniform(0.3, 1.0))
    null_effects = {"reversal_error": 0.0} if k % 2 else None
    fam = ScrewFamily()
    res = timed_discover(scenario(seed, null_effects, noise, protocols, reference), fam, jobs, tl.null_times, tl.cpu)
    tl.null_false += bool(res.effects)
    tl.null_ratio.append(res.before.rmse() / noise)
    diag = residual_diagnostic(res, fam)
    tl.null_r.append(max((abs(d["partial_r"]) for d in diag), default=0.0))
    tl.null_flagged += bool(unexplained.summary(diag))
    best = max((c.score for c in res.rounds[0].candidates if np.isfinite(c.score)), default=float("nan"))
    tl.null_gains.append(best)
    line = ["[%s] seed %d noise %.2f: null%s -> %s (best gain %+.1f%%, base RMSE/noise %.2f, max |partial r| %.2f)" % (
        reference, seed, noise, " (bidirectional)" if null_effects else "", ",".join(res.effects) or "-", 100 * best,
        tl.null_ratio[-1], tl.null_r[-1])]
    for e in effects:
        mag = EFFECTS[e].default * float(rng.uniform(0.5, 1.5))
        res = timed_discover(scenario(seed, {e: mag}, noise, protocols, reference), ScrewFamily(), jobs, tl.times, tl.cpu)
        tl.hits[e][0] += res.effects[:1] == [e]
        tl.hits[e][1] += res.after.rmse() <= 0.5 * res.before.rmse()
        tl.floor[e].append(res.after.rmse() / noise)
        line.append("%s(%.2g): %s %.2f->%.2f" % (e, mag, ",".join(res.effects) or "-", res.before.rmse(), res.after.rmse()))
    if pairs:
        pair = PAIRS[k % len(PAIRS)]
        mags = {e: EFFECTS[e].default * float(rng.uniform(0.7, 1.3)) for e in pair}
        res = timed_discover(scenario(seed, mags, noise, protocols, reference), ScrewFamily(), jobs, tl.times, tl.cpu)
        tl.pair_n += 1
        tl.pair_hits += set(res.effects) >= set(pair)
        line.append("pair %s: %s %.2f->%.2f" % ("+".join(pair), ",".join(res.effects) or "-", res.before.rmse(), res.after.rmse()))
    return "; ".join(line)


def report(reference, tl, n, effects, protocols, jobs):
    print()
    print("--- error reference %s ---" % reference)
    print("null (no effect hidden): %d false discoveries in %d seeds = %.3f (target <= 0.05)" % (tl.null_false, n, tl.null_false / n))
    print("null best candidate gain: median %+.1f%%, 95th percentile %+.1f%%, max %+.1f%%" % tuple(100 * np.nanpercentile(tl.null_gains, [50, 95, 100])))
    print("null base model held-out RMSE / laser noise: median %.3f, max %.3f (budget <= 1.25)" % (np.median(tl.null_ratio), np.max(tl.null_ratio)))
    print("null residual diagnostic: strongest |partial r| median %.3f, max %.3f (threshold %.2f); seeds with a signal "
          "reported: %d/%d" % (np.median(tl.null_r), np.max(tl.null_r), unexplained.MIN_PARTIAL_R, tl.null_flagged, n))
    for e in effects:
        print("%-22s named first %d/%d, held-out RMSE halved %d/%d, RMSE after / laser noise: median %.3f, max %.3f"
              % (e, tl.hits[e][0], n, tl.hits[e][1], n, np.median(tl.floor[e]), np.max(tl.floor[e])))
    if tl.pair_n:
        print("two effects hidden: both named %d/%d" % (tl.pair_hits, tl.pair_n))
    allt = np.array(tl.null_times + tl.times)
    print("workflow wall time on %d runs (jobs=%d): median %.2f s, max %.2f s (budget 60 s)" % (len(protocols), jobs, np.median(allt), allt.max()))
    # CPU seconds (all processes) hardly grow with other jobs on a shared machine, wall seconds do: on idle
    # cores the wall time lies between CPU / jobs (all of it parallel) and CPU (none of it)
    allc = np.array(tl.cpu)
    print("workflow CPU time on %d runs (all processes): median %.2f s, max %.2f s; / %d cores: median %.2f s, max %.2f s; "
          "load average %.1f at the end" % (len(protocols), np.median(allc), allc.max(), jobs,
                                           np.median(allc) / jobs, allc.max() / jobs, os.getloadavg()[0]))


def table(tallies, n, effects):
    """One row per reference: named first per effect, both of a pair, false discoveries on the null, speed."""
    print()
    short = {"ambient_expansion": "amb", "speed_dependent_heat": "speed", "bearing_heat": "bearing",
             "moving_convection": "conv", "reversal_error": "rev"}
    head = ["reference"] + ["%s 1st" % short.get(e, e) for e in effects] + ["pair both", "null false", "null RMSE/noise max",
                                                                          "median s"]
    print(" | ".join(head))
    print(" | ".join("---" for _ in head))
    for ref, tl in tallies.items():
        cells = [ref] + ["%d/%d" % (tl.hits[e][0], n) for e in effects]
        cells.append("%d/%d" % (tl.pair_hits, tl.pair_n) if tl.pair_n else "-")
        cells.append("%d/%d" % (tl.null_false, n))
        cells.append("%.2f" % max(tl.null_ratio))
        cells.append("%.1f" % float(np.median(tl.null_times + tl.times)))
        print(" | ".join(cells))


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=1000)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--effects", default=",".join(CATALOG_EFFECTS), help="hidden effects to test (comma list, '' = null only)")
    ap.add_argument("--no-pairs", action="store_true", help="skip the two-effect scenarios")
    ap.add_argument("--protocols", default=",".join(PROTOCOLS), help="twin protocols of one scenario's runs")
    ap.add_argument("--references", default=",".join(REFERENCES),
                    help="error references the twin writes (and meta.json declares) the runs in, comma list")
    args = ap.parse_args(argv)
    effects = [e for e in args.effects.split(",") if e]
    protocols = [p for p in args.protocols.split(",") if p]
    references = [r for r in args.references.split(",") if r]
    if not references:
        ap.error("--references: give at least one (start or a sensor id)")
    tallies = {ref: Tally(effects) for ref in references}
    for k in range(args.seeds):
        for ref in references:
            print(run_seed(k, args.first_seed + k, ref, effects, protocols, args.jobs, not args.no_pairs, tallies[ref]), flush=True)
    for ref in references:
        report(ref, tallies[ref], args.seeds, effects, protocols, args.jobs)
    table(tallies, args.seeds, effects)


if __name__ == "__main__":
    main()
