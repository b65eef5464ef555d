"""Agglomerative clustering of sensor series on D = a*D_e + (1 - a)*D_r.

D_e is the Euclidean distance between two series, min-max normalised over all
sensor pairs of the data (so it lies in [0, 1] like D_r); D_r = 1 - |r|. Each
merge joins the closest pair and represents the new cluster by the mean series
of its members; its distances to the other clusters are recomputed from that
mean with the same normalisation constants, so D_e keeps one scale through the
whole agglomeration.
"""
from dataclasses import dataclass

import numpy as np


def _corr_abs(A, B):
    """|r| between every column of A (n, a) and every column of B (n, b)."""
    A = A - A.mean(axis=0)
    B = B - B.mean(axis=0)
    na = np.sqrt((A * A).sum(axis=0))
    nb = np.sqrt((B * B).sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (A.T @ B) / np.outer(na, nb)
    # a mean series can be constant (two mirrored sensors): no correlation information
    return np.nan_to_num(np.abs(np.clip(r, -1.0, 1.0)), nan=0.0)


def _euclid(A, B):
    d2 = (A * A).sum(axis=0)[:, None] + (B * B).sum(axis=0)[None, :] - 2.0 * (A.T @ B)
    return np.sqrt(np.maximum(d2, 0.0))


@dataclass
class Agglomeration:
    alpha: float
    merges: list  # [(members_a, members_b, distance)] in merge order, members as index tuples
    p: int

    def partition(self, k):
        """k clusters (lists of column indices, sorted; clusters by first member)."""
        if not 1 <= k <= self.p:
            raise ValueError("number of clusters must be in 1..%d, got %d" % (self.p, k))
        label = list(range(self.p))
        groups = {i: [i] for i in range(self.p)}
        for a, b, _ in self.merges[: self.p - k]:
            ga, gb = label[a[0]], label[b[0]]
            groups[ga].extend(groups.pop(gb))
            for i in groups[ga]:
                label[i] = ga
        return sorted((sorted(g) for g in groups.values()), key=lambda g: g[0])

    def linkage(self):
        """scipy-style linkage matrix (heights = merge distances, not necessarily monotone)."""
        ids = {(i,): i for i in range(self.p)}
        rows = []
        for a, b, d in self.merges:
            ia, ib = ids[tuple(sorted(a))], ids[tuple(sorted(b))]
            rows.append([min(ia, ib), max(ia, ib), d, len(a) + len(b)])
            ids[tuple(sorted(a + b))] = self.p + len(rows) - 1
        return np.asarray(rows, dtype=float).reshape(-1, 4)


def agglomerate(X, alpha):
    """Cluster the columns of X (n, p) on the combined distance with weight ``alpha`` on D_e."""
    X = np.asarray(X, dtype=float)
    n, p = X.shape
    De = _euclid(X, X)
    off = De[~np.eye(p, dtype=bool)]
    lo, hi = (float(off.min()), float(off.max())) if off.size else (0.0, 1.0)
    span = hi - lo if hi > lo else 1.0

    def dist(A, B):
        return alpha * (_euclid(A, B) - lo) / span + (1.0 - alpha) * (1.0 - _corr_abs(A, B))

    members = [(i,) for i in range(p)]
    means = X.copy()
    D = dist(means, means)
    np.fill_diagonal(D, np.inf)
    active = list(range(p))
    merges = []
    while len(active) > 1:
        sub = D[np.ix_(active, active)]
        flat = int(np.argmin(sub))  # first minimum: ties resolve by column order
        ia, ib = divmod(flat, len(active))
        a, b = active[ia], active[ib]
        a, b = min(a, b), max(a, b)
        merges.append((members[a], members[b], float(D[a, b])))
        members[a] = members[a] + members[b]
        means[:, a] = X[:, list(members[a])].mean(axis=1)
        active.remove(b)
        D[b, :] = D[:, b] = np.inf
        others = [j for j in active if j != a]
        if others:
            d = dist(means[:, [a]], means[:, others])[0]
            D[a, others] = d
            D[others, a] = d
    return Agglomeration(float(alpha), merges, p)
