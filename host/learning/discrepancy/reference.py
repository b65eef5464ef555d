"""Does the runs' declared error reference fit their errors? (issue 19 §2, docs/discrepancy.md)

A wrong or missing ``error_reference`` in meta.json (docs/data-format.md) is the commonest disagreement
between a model and real laser data: raw errors declared as corrected to a sensor, or a laser's
material-temperature compensation left undeclared. The two conventions differ by α·(T_R − T_R,0)·P, an
expansion proportional to the position that a catalog effect (``ambient_expansion``) would happily absorb.
So before the catalog is searched, the base model is fitted held-out (the workflow's folds) under the
declared reference and under each other candidate; a candidate that beats the declaration by the same rules
an effect must pass (held-out RMSE gain ≥ MIN_GAIN, one-sided Diebold–Mariano p, Holm over the candidates,
below ALPHA) is suggested, and the caller names no effect on these runs.

Candidates: ``"start"`` and every sensor with role ``ambient`` or ``base`` that all runs log (where a laser's
material probe sits: the air by the axis or the machine's base). Other sensors are not tried: a wrong
reference to, say, the motor flange is not a convention any laser software offers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import math

from host.data.runs import START, common_error_reference
from host.learning.discrepancy import stats, workflow

if TYPE_CHECKING:
    from host.data.runs import Run

PROBE_ROLES = ("ambient", "base")


def candidates(runs: Sequence[Run]) -> list[str]:
    """The references worth trying on ``runs``: "start" and the ambient/base sensors every run logs."""
    out = [START]
    for role in PROBE_ROLES:
        for name in runs[0].sensors_with_role(role):
            if name not in out and all(name in r.temperatures.names for r in runs):
                out.append(name)
    return out


def check_declaration(runs: Sequence[Run], make_family: Callable[[str | None], Any], alpha: float = workflow.ALPHA, min_gain: float = workflow.MIN_GAIN, jobs: int | None = None, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Held-out base-model RMSE under the declared reference and each other candidate.

    ``make_family(error_reference)`` returns the base model family fitting under that reference (None: the runs'
    declaration). Returns {"declared", "rmse_um": {reference: held-out RMSE}, "p_value": {reference: Holm p},
    "suggested": a reference or None}."""
    log = log or (lambda msg: None)
    declared = common_error_reference(runs)
    folds = workflow.make_folds(runs)
    jobs = jobs or 1
    held = {}
    for ref in [declared] + [c for c in candidates(runs) if c != declared]:
        pool = workflow._Pool(make_family(ref), runs, folds, jobs)
        try:
            ho, err = workflow._assemble(runs, folds, (), pool.map([((), k, None) for k in range(len(folds))]))
        finally:
            pool.close()
        if ho is None:
            log("error reference %s: the base model could not be fitted (%s)" % (ref, err))
            continue
        held[ref] = ho
    if declared not in held:
        raise RuntimeError("the base model could not be fitted under the declared error reference %r" % declared)
    base = held[declared]
    loss0 = workflow._losses(runs, base.residuals)
    others = [r for r in held if r != declared]
    raw = [stats.dm_test(loss0, workflow._losses(runs, held[r].residuals), log=workflow.LOG_LOSS)["p_value"] for r in others]
    p = dict(zip(others, (float(v) for v in stats.holm_adjust(raw)))) if others else {}
    rmse = {r: float(h.rmse()) for r, h in held.items()}
    passing = [r for r in others if 1.0 - rmse[r] / rmse[declared] >= min_gain and p[r] < alpha]
    suggested = min(passing, key=lambda r: rmse[r], default=None)
    out = {"declared": declared, "rmse_um": rmse, "p_value": p, "suggested": suggested}
    log(report_line(out))
    return out


def json_fields(check: dict[str, Any] | None) -> dict[str, Any]:
    """The discrepancy JSON's fields: ``error_reference_suggested`` only when the declaration does not fit."""
    if check is None:
        return {}
    out = {"error_reference_check": {"declared": check["declared"], "heldout_rmse_um": check["rmse_um"],
                                     "p_value": check["p_value"]}}
    if check["suggested"] is not None:
        out["error_reference_suggested"] = check["suggested"]
    return out


def _name(ref):
    return "start (raw)" if ref == START else "sensor %s" % ref


def report_line(check: dict[str, Any]) -> str:
    """One line: the held-out RMSE under the declared reference and the best other, and the verdict."""
    declared, rmse = check["declared"], check["rmse_um"]
    others = sorted((r for r in rmse if r != declared), key=lambda r: rmse[r])
    if not others:
        return "error reference %s: no other convention to compare with" % _name(declared)
    best = check["suggested"] or others[0]
    text = "error reference: held-out RMSE %.3f um as declared (%s), %.3f um as %s" % (
        rmse[declared], _name(declared), rmse[best], _name(best))
    if check["suggested"] is not None:
        return text + ": the errors behave as %s; set meta.json \"error_reference\": \"%s\" (docs/data-format.md); " \
                      "no catalog effect is named on a wrong declaration" % (_name(best), best)
    pv = check["p_value"].get(best, 1.0)
    return text + ": the declaration fits%s" % ("" if not math.isfinite(pv) else " (p %.2g)" % pv)
