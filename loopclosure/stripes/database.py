"""A database of stripe descriptors answering a query against every object at once.

Paper: "Stripes-based Object Matching", Section V (Eq. 4-6), vectorised over objects.

Why the query can be vectorised although trimming depends on the pair: trimming only
removes stripes from the two ends of the longer set, so what is compared is always a
*contiguous run* of one object's stripes and the whole of the other.  The Gaussian fit
of a contiguous run ``[start, stop)`` comes in O(1) from prefix sums of the features
and of their squares.  At build time each object stores those prefix sums (of its
features centred on the object's own means, for numerical accuracy) in one flat array
(no padding: ``sum(M_k + 1)`` rows).  A query with ``N`` stripes then computes its own
prefix sums once and, for every database object ``k`` with ``M_k`` stripes:

- ``M_k >= N``: the database object's run ``trim_range(M_k, N)`` against the whole query;
- ``M_k <  N``: the whole database object against the query's run ``trim_range(N, M_k)``;

all as array gathers over the object axis.  ``l`` is normalised over the whole,
untrimmed object (see `matching`), so nothing else depends on the partner.
The result equals `matching.stripe_distance` object by object (tested).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.stripes.descriptor import StripeDescriptor
from loopclosure.stripes.matching import (
    LAMBDA_PAPER,
    VAR_FLOOR,
    bhattacharyya,
    combine,
    trim_range,
)

Array = NDArray[np.float64]


def _prefix(features: Array) -> tuple[Array, Array, Array]:
    """Centre (per feature mean), and prefix sums of values and squares, ``(M + 1, 3)``."""
    centre = features.mean(axis=0)
    x = features - centre
    zero = np.zeros((1, features.shape[1]))
    s1 = np.concatenate([zero, np.cumsum(x, axis=0)])
    s2 = np.concatenate([zero, np.cumsum(x * x, axis=0)])
    return centre, s1, s2


def _run_stats(
    s1: Array, s2: Array, centre: Array, lo: NDArray[np.int64], hi: NDArray[np.int64]
) -> tuple[Array, Array]:
    """Mean and ML variance of rows ``[lo, hi)`` from flat prefix sums (rows index s1/s2)."""
    n = (hi - lo)[:, None].astype(float)
    a = (s1[hi] - s1[lo]) / n
    var = np.maximum((s2[hi] - s2[lo]) / n - a * a, 0.0)
    return centre + a, var


class StripeDatabase:
    """Many objects' stripe descriptors, queried in one vectorised pass.

    Args:
        descriptors: one `StripeDescriptor` per object (each with at least one stripe).
        weights: Eq. 5 weights for ``(l, d, o)``.
        var_floor: variance floor of the Gaussian fits.
    """

    def __init__(
        self,
        descriptors: Sequence[StripeDescriptor],
        weights: Sequence[float] = LAMBDA_PAPER,
        var_floor: float = VAR_FLOOR,
    ) -> None:
        self.descriptors = list(descriptors)
        self.weights = tuple(float(w) for w in weights)
        self.var_floor = float(var_floor)
        if len(self.weights) != 3:
            raise UserError(
                f"stripe weights need three values (l, d, o), got {len(self.weights)}"
            )
        counts = np.array([len(d) for d in self.descriptors], dtype=np.int64)
        if np.any(counts == 0):
            bad = next(d for d in self.descriptors if len(d) == 0)
            raise UserError(f"empty stripe set in the database ({bad.name or 'unnamed'})")
        self.counts = counts
        k = len(self.descriptors)
        self.offsets = np.concatenate([[0], np.cumsum(counts + 1)[:-1]]).astype(np.int64)
        if k:
            parts = [_prefix(d.features) for d in self.descriptors]
            self.centres = np.stack([p[0] for p in parts])
            self.s1 = np.concatenate([p[1] for p in parts])
            self.s2 = np.concatenate([p[2] for p in parts])
        else:
            self.centres = np.zeros((0, 3))
            self.s1 = self.s2 = np.zeros((0, 3))

    def __len__(self) -> int:
        return len(self.descriptors)

    def feature_distances(self, query: StripeDescriptor) -> Array:
        """``(K, 3)`` Bhattacharyya distances of ``l, d, o`` from `query` to every object."""
        n = len(query)
        if n == 0:
            raise UserError(f"empty stripe set in the query ({query.name or 'unnamed'})")
        m = self.counts
        if len(m) == 0:
            return np.zeros((0, 3))
        q_centre, q1, q2 = _prefix(query.features)
        db_longer = m >= n
        # Database side: run [start, stop) of each object (whole object when it is shorter).
        start, stop = trim_range(np.maximum(m, n), np.minimum(m, n))
        db_lo = self.offsets + np.where(db_longer, start, 0)
        db_hi = self.offsets + np.where(db_longer, stop, m)
        mu_db, var_db = _run_stats(self.s1, self.s2, self.centres, db_lo, db_hi)
        # Query side: whole query, or its run when the database object is shorter.
        q_lo = np.where(db_longer, 0, start)
        q_hi = np.where(db_longer, n, stop)
        mu_q, var_q = _run_stats(q1, q2, q_centre[None, :], q_lo, q_hi)
        return bhattacharyya(mu_q, var_q, mu_db, var_db, self.var_floor)

    def distances(self, query: StripeDescriptor) -> Array:
        """``(K,)`` distances ``s(query, object_k)`` of Eq. 5 (>= 0, finite)."""
        return combine(self.feature_distances(query), self.weights)

    def query(self, query: StripeDescriptor, k: int = 10) -> tuple[NDArray[np.int64], Array]:
        """Indices and distances of the `k` nearest objects, nearest first (stable ties)."""
        d = self.distances(query)
        order = np.argsort(d, kind="stable")[:k]
        return order, d[order]

    def pairwise_features(self) -> Array:
        """``(K, K, 3)`` per-feature distances of every object to every object."""
        return np.stack([self.feature_distances(q) for q in self.descriptors])

    def pairwise(self) -> Array:
        """``(K, K)`` distance matrix (row i: object i as query), symmetric, zero diagonal."""
        return combine(self.pairwise_features(), self.weights)
