"""Stripe-set matching: trimming, Bhattacharyya distance, weighted sum, lambda search.

Paper: "Stripes-based Object Matching", Section V (Eq. 4-6).

Two objects with ``N <= M`` stripes:

1. Trimming (Eq. 4): the longer set loses ``M - N`` stripes from its two ends so both
   have ``N``.  The paper says "the rounding number (M - N)/2 from two ends"; removing
   ``round((M - N)/2)`` from *each* end would not leave ``N`` when ``M - N`` is odd, so
   here ``k = round_half_up((M - N)/2)`` go from the front and ``M - N - k`` from the
   back (`trim_range`).  Stripes stay in scan order.
2. Each feature ``l, d, o`` of each (trimmed) set is fitted with a Gaussian: its mean
   and its maximum-likelihood variance (``ddof = 0``).  Variances are floored at
   `VAR_FLOOR` so a constant feature (e.g. all-zero ``d`` of very short stripes) never
   divides by zero: identical constant features give distance 0, different constants a
   large finite distance.  Nothing is ever NaN.
3. Bhattacharyya distance (Eq. 6, ``sigma^2`` = variance)::

       D_B = 1/4 ln(1/4 (v1/v2 + v2/v1 + 2)) + 1/4 (mu1 - mu2)^2 / (v1 + v2)

4. Weighted sum (Eq. 5): ``s = 1/3 sum_t lambda_t D_B,t`` with
   ``lambda = (0.6, 0.3, 0.1)`` for ``(l, d, o)`` (`LAMBDA_PAPER`).

Lambda search (Section V): gradient hill climbing with simulated annealing on a
training split only (`search_weights`); the fitness is the mean retrieval precision of
the training objects among the training objects (`retrieval_fitness`).

Note on ``l``: the normalisation by the mean stripe length uses the whole (untrimmed)
object, so an object's ``l`` values do not depend on the object it is compared with;
this is what lets `database.StripeDatabase` precompute everything per object.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.stripes.descriptor import StripeDescriptor

Array = NDArray[np.float64]

#: Eq. 5 weights for ``(l, d, o)`` as published.
LAMBDA_PAPER: tuple[float, float, float] = (0.6, 0.3, 0.1)
#: Floor on every feature variance (features are O(1): l ~ 1, d ~ 2-6, o in radians).
VAR_FLOOR = 1e-6


def round_half_up(x: ArrayLike) -> NDArray[np.int64]:
    """Matlab-style rounding of non-negative values (0.5 -> 1, 1.5 -> 2, 2.5 -> 3)."""
    return np.floor(np.asarray(x, dtype=float) + 0.5).astype(np.int64)


def trim_range(m: ArrayLike, n: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``(start, stop)`` of the stripes kept when a set of ``m`` is trimmed to ``n <= m``.

    ``start = round_half_up((m - n) / 2)`` stripes leave from the front, the remaining
    ``m - n - start`` from the back.  Vectorised over arrays of ``m`` and ``n``.
    """
    m = np.asarray(m, dtype=np.int64)
    n = np.asarray(n, dtype=np.int64)
    if np.any(n > m) or np.any(n < 0):
        got = f"m={int(m)}, n={int(n)}" if m.ndim == n.ndim == 0 else "n outside 0..m"
        raise UserError(
            f"trim_range needs 0 <= n <= m (n: stripes kept, m: stripes in the set), got {got}"
        )
    start = round_half_up((m - n) / 2.0)
    return start, start + n


def trim_pair(a: Array, b: Array) -> tuple[Array, Array]:
    """Trim the longer of two ``(N, F)`` stripe-feature arrays to the shorter's length."""
    n, m = len(a), len(b)
    if n > m:
        b2, a2 = trim_pair(b, a)
        return a2, b2
    start, stop = trim_range(m, n)
    return a, b[int(start) : int(stop)]


def gaussian_fit(features: Array, var_floor: float = VAR_FLOOR) -> tuple[Array, Array]:
    """Per-feature mean and floored ML variance of an ``(N, F)`` array (``N >= 1``)."""
    f = np.asarray(features, dtype=float)
    if f.shape[0] == 0:
        raise UserError("cannot fit a Gaussian to an empty stripe set")
    return f.mean(axis=0), np.maximum(f.var(axis=0), var_floor)


def bhattacharyya(
    mu1: ArrayLike,
    var1: ArrayLike,
    mu2: ArrayLike,
    var2: ArrayLike,
    var_floor: float = VAR_FLOOR,
) -> NDArray[np.float64]:
    """Eq. 6: Bhattacharyya distance between 1D Gaussians given means and *variances*.

    Broadcasts over arrays; variances are floored at `var_floor` (finite for any input).
    """
    v1 = np.maximum(np.asarray(var1, dtype=float), var_floor)
    v2 = np.maximum(np.asarray(var2, dtype=float), var_floor)
    dm = np.asarray(mu1, dtype=float) - np.asarray(mu2, dtype=float)
    return 0.25 * np.log(0.25 * (v1 / v2 + v2 / v1 + 2.0)) + 0.25 * dm * dm / (v1 + v2)


def feature_distances(
    a: StripeDescriptor, b: StripeDescriptor, var_floor: float = VAR_FLOOR
) -> Array:
    """``(3,)`` Bhattacharyya distances of ``l, d, o`` after trimming (Eq. 4 and 6)."""
    if len(a) == 0 or len(b) == 0:
        raise UserError("empty stripe set: nothing to match")
    fa, fb = trim_pair(a.features, b.features)
    mu1, v1 = gaussian_fit(fa, var_floor)
    mu2, v2 = gaussian_fit(fb, var_floor)
    return bhattacharyya(mu1, v1, mu2, v2, var_floor)


def combine(feature_dists: ArrayLike, weights: Sequence[float] = LAMBDA_PAPER) -> Array:
    """Eq. 5: ``1/3 sum_t lambda_t D_t`` over the last axis of `feature_dists` (size 3)."""
    w = np.asarray(weights, dtype=float)
    return np.tensordot(np.asarray(feature_dists, dtype=float), w, axes=([-1], [0])) / 3.0


def stripe_distance(
    a: StripeDescriptor,
    b: StripeDescriptor,
    weights: Sequence[float] = LAMBDA_PAPER,
    var_floor: float = VAR_FLOOR,
) -> float:
    """Distance ``s(O1, O2)`` of two objects (Eq. 5); >= 0, finite, symmetric."""
    return float(combine(feature_distances(a, b, var_floor), weights))


# --------------------------------------------------------------------------- lambda search


def stratified_split(
    labels: Sequence[str], train_fraction: float = 0.5, seed: int = 0
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Indices ``(train, test)``: each class split at `train_fraction` (at least one each side
    when the class has two or more members)."""
    lab = np.asarray(labels)
    rng = np.random.default_rng(seed)
    train: list[int] = []
    for c in np.unique(lab):
        idx = rng.permutation(np.flatnonzero(lab == c))
        k = round(train_fraction * len(idx))
        if len(idx) >= 2:
            k = min(max(k, 1), len(idx) - 1)
        train.extend(idx[:k].tolist())
    tr = np.sort(np.array(train, dtype=np.int64))
    te = np.setdiff1d(np.arange(len(lab)), tr)
    return tr, te


def retrieval_fitness(distances: Array, labels: Sequence[str], k: int = 10) -> float:
    """Mean fraction of same-class objects among each query's ``k`` nearest *others*.

    ``k`` is capped by each query's class size minus one (R-precision for small
    classes), so a perfect ranking scores 1.
    """
    d = np.array(distances, dtype=float)
    lab = np.asarray(labels)
    n = len(lab)
    np.fill_diagonal(d, np.inf)
    order = np.argsort(d, axis=1, kind="stable")[:, : max(n - 1, 1)]
    same = lab[order] == lab[:, None]
    sizes = (lab[:, None] == lab[None, :]).sum(axis=1) - 1
    kk = np.minimum(k, sizes)
    rank = np.arange(order.shape[1])[None, :]
    hits = (same & (rank < kk[:, None])).sum(axis=1)
    ok = kk > 0
    return float(np.mean(hits[ok] / kk[ok])) if ok.any() else 0.0


@dataclass(slots=True)
class WeightSearch:
    """Result of `search_weights`: best weights (sum 1), their fitness, and the history."""

    weights: tuple[float, float, float]
    fitness: float
    history: list[float] = field(default_factory=list)


def search_weights(
    feature_dists: Array,
    labels: Sequence[str],
    train: ArrayLike,
    iterations: int = 300,
    step0: float = 0.3,
    temperature0: float = 0.02,
    seed: int = 0,
    k: int = 10,
) -> WeightSearch:
    """Search ``lambda`` by gradient hill climbing with simulated annealing (Section V).

    Args:
        feature_dists: ``(M, M, 3)`` per-feature distances of all objects (row = query).
        labels: ``(M,)`` classes.
        train: indices of the training objects; only their rows and columns are used.
        iterations: number of single-parameter moves.
        step0: initial size of a move; it shrinks linearly to 0 (annealed changes).
        temperature0: initial temperature of the acceptance rule, cooling linearly.
        seed: random start point and moves are drawn from this seed.
        k: `retrieval_fitness` depth.

    Each iteration picks one weight at random, evaluates moving it by ``+step`` and
    ``-step`` (the numerical gradient along that coordinate), takes the better move and
    accepts it if it improves the fitness, or otherwise with probability
    ``exp(delta / T)``.  Weights stay non-negative and are renormalised to sum 1 (the
    ranking does not depend on their scale).  The best weights seen are returned.
    """
    tr = np.asarray(train, dtype=np.int64)
    if len(tr) < 2:
        raise UserError("the lambda search needs at least two training objects")
    fd = np.asarray(feature_dists, dtype=float)[np.ix_(tr, tr)]
    lab = np.asarray(labels)[tr]
    rng = np.random.default_rng(seed)

    def fitness(w: Array) -> float:
        return retrieval_fitness(combine(fd, w), lab, k)

    w = rng.dirichlet(np.ones(3))
    f = fitness(w)
    best_w, best_f = w.copy(), f
    history = [f]
    for it in range(iterations):
        frac = 1.0 - it / max(iterations, 1)
        step = step0 * frac
        temp = max(temperature0 * frac, 1e-12)
        t = int(rng.integers(3))
        candidates = []
        for sign in (1.0, -1.0):
            c = w.copy()
            c[t] = max(c[t] + sign * step * rng.uniform(0.5, 1.0), 0.0)
            if c.sum() <= 0:
                continue
            c /= c.sum()
            candidates.append((fitness(c), c))
        if not candidates:
            continue
        fc, c = max(candidates, key=lambda x: x[0])
        if fc >= f or rng.random() < np.exp((fc - f) / temp):
            w, f = c, fc
        if f > best_f:
            best_w, best_f = w.copy(), f
        history.append(f)
    return WeightSearch(tuple(float(x) for x in best_w), float(best_f), history)
