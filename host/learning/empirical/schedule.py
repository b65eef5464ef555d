"""The spindle schedule of a run as constant-speed segments and heating/cooling cycles.

A *segment* is a maximal interval of constant rpm. A *cycle* starts where the
spindle starts from standstill (rpm goes from 0 to > 0) and lasts until the next
such start (or the end of the log); the time before the first start belongs to
the first cycle. A cycle is *constant-speed* when it has one running speed, and
*mixed* otherwise. These give the time split of the real FL_THERMAL test
(train on the first constant-speed cycles, hold out the rest) and the
cross-validation blocks of single-run fits.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from numpy.typing import ArrayLike

import numpy as np

from host.learning.empirical import EmpiricalDataError

if TYPE_CHECKING:
    from host.data.runs import Run


def segments(run: Run) -> list[tuple[float, float, float]]:
    """[(t_start_s, t_end_s, rpm)] of constant speed, in time order."""
    sp = run.spindle
    if sp is None or sp.time_s.size < 2:
        raise EmpiricalDataError("%s: no spindle.csv (or a single sample); the schedule is unknown" % run.name)
    t, r = sp.time_s, sp.rpm
    change = np.flatnonzero(np.diff(r) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [t.size]])
    # a segment ends where the next one starts (the sample at which the speed changed)
    return [(float(t[a]), float(t[b]) if b < t.size else float(t[-1]), float(r[a])) for a, b in zip(starts, ends)]


def cycles(run: Run) -> list[dict[str, Any]]:
    """[{"t_start_s", "t_end_s", "speeds_rpm", "constant"}] from each start out of standstill."""
    segs = segments(run)
    starts = [i for i, s in enumerate(segs) if s[2] > 0 and (i == 0 or segs[i - 1][2] == 0)]
    if not starts:
        raise EmpiricalDataError("%s: the spindle never runs; no heating cycle" % run.name)
    out = []
    for k, i in enumerate(starts):
        j = starts[k + 1] if k + 1 < len(starts) else len(segs)
        t0 = segs[0][0] if k == 0 else segs[i][0]
        t1 = segs[j][0] if j < len(segs) else segs[-1][1]
        speeds = []
        for s in segs[i:j]:
            if s[2] > 0 and s[2] not in speeds:
                speeds.append(s[2])
        out.append({"t_start_s": t0, "t_end_s": t1, "speeds_rpm": speeds, "constant": len(speeds) == 1})
    return out


def block_labels(times: ArrayLike, edges: Sequence[float]) -> np.ndarray:
    """Index of the block each time falls in, blocks separated by ``edges`` (ascending)."""
    return np.searchsorted(np.asarray(edges, dtype=float), np.asarray(times, dtype=float), side="right")
