"""Agglomerative clustering of sensor series on D = a*D_e + (1 - a)*D_r.

D_e is the Euclidean distance between two series, normalised over all sensor
pairs of the data so it lies in [0, 1] like D_r: divided by the largest pair
distance (``normalisation="max"``, Eq. 5 of the paper as we read it: zero
distance stays zero) or min-max (``"minmax"``, this project's earlier form);
D_r = 1 - |r|. Each
merge joins the closest pair and represents the new cluster by the mean series
of its members; its distances to the other clusters are recomputed from that
mean with the same normalisation constants, so D_e keeps one scale through the
whole agglomeration.
"""

from __future__ import annotations


from dataclasses import dataclass

import numpy as np


class Moments:
    """Second moments of the sensor series: everything the agglomeration needs.

    A cluster's mean series is X @ w (w = 1/|cluster| on its members), so the
    Euclidean distance and correlation between any two mean series follow from
    M = X'X and the covariance C = Xc'Xc as quadratic forms in the weights. One
    O(n p^2) pass over the data, then every agglomeration is O(p^3) whatever n.
    """

    def __init__(self, X: np.ndarray) -> None:
        X = np.asarray(X, dtype=float)
        self.p = X.shape[1]
        # raw moments about a common origin (the grand mean) keep M well scaled
        Xo = X - X.mean()
        self.M = Xo.T @ Xo
        Xc = X - X.mean(axis=0)
        self.C = Xc.T @ Xc


def _pair_terms(mom, w, W):
    """Euclidean distance and |r| between mean series w (p,) and each row of W (m, p)."""
    eu2 = w @ mom.M @ w + np.einsum("mp,pq,mq->m", W, mom.M, W) - 2.0 * (W @ (mom.M @ w))
    cov = W @ (mom.C @ w)
    var = (w @ mom.C @ w) * np.einsum("mp,pq,mq->m", W, mom.C, W)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / np.sqrt(var)
    # a mean series can be constant (two mirrored sensors): no correlation information
    return np.sqrt(np.maximum(eu2, 0.0)), np.nan_to_num(np.abs(np.clip(r, -1.0, 1.0)), nan=0.0)


@dataclass
class Agglomeration:
    alpha: float
    merges: list  # [(members_a, members_b, distance)] in merge order, members as index tuples
    p: int

    def partition(self, k: int) -> list[list[int]]:
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

    def linkage(self) -> np.ndarray:
        """scipy-style linkage matrix (heights = merge distances, not necessarily monotone)."""
        ids = {(i,): i for i in range(self.p)}
        rows = []
        for a, b, d in self.merges:
            ia, ib = ids[tuple(sorted(a))], ids[tuple(sorted(b))]
            rows.append([min(ia, ib), max(ia, ib), d, len(a) + len(b)])
            ids[tuple(sorted(a + b))] = self.p + len(rows) - 1
        return np.asarray(rows, dtype=float).reshape(-1, 4)


NORMALISATIONS = ("max", "minmax")


def agglomerate(X: np.ndarray, alpha: float, moments: Moments | None = None, normalisation: str = "max") -> Agglomeration:
    """Cluster the columns of X (n, p) on the combined distance with weight ``alpha`` on D_e.

    ``moments``: a precomputed :class:`Moments` of X (reused across alphas by the GA).
    ``normalisation``: D_e / max over pairs ("max") or (D_e − min) / (max − min) ("minmax").
    """
    if normalisation not in NORMALISATIONS:
        raise ValueError("normalisation must be one of %s, got %r" % (", ".join(NORMALISATIONS), normalisation))
    mom = moments if moments is not None else Moments(X)
    p = mom.p
    dM = np.diag(mom.M)
    De = np.sqrt(np.maximum(dM[:, None] + dM[None, :] - 2.0 * mom.M, 0.0))
    dC = np.diag(mom.C)
    with np.errstate(invalid="ignore", divide="ignore"):
        R = np.nan_to_num(np.abs(np.clip(mom.C / np.sqrt(np.outer(dC, dC)), -1.0, 1.0)), nan=0.0)
    off = De[~np.eye(p, dtype=bool)]
    lo, hi = (float(off.min()), float(off.max())) if off.size else (0.0, 1.0)
    if normalisation == "max":
        lo = 0.0
    span = hi - lo if hi > lo else 1.0
    D = alpha * (De - lo) / span + (1.0 - alpha) * (1.0 - R)
    np.fill_diagonal(D, np.inf)
    members: list[tuple[int, ...]] = [(i,) for i in range(p)]  # each cluster's variables, grown by the merges
    W = np.eye(p)
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
        W[a] = 0.0
        W[a, list(members[a])] = 1.0 / len(members[a])
        active.remove(b)
        D[b, :] = D[:, b] = np.inf
        others = [j for j in active if j != a]
        if others:
            eu, r = _pair_terms(mom, W[a], W[others])
            d = alpha * (eu - lo) / span + (1.0 - alpha) * (1.0 - r)
            D[a, others] = d
            D[others, a] = d
    return Agglomeration(float(alpha), merges, p)
