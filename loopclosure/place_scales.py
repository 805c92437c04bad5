"""Normalisation scales of the place database's stages (`loopclosure.place_database`).

A prefilter stage's scale is the median Euclidean distance of 256 random pairs of
stored keyframes; a verifier's the median of its `distances` over
``scale_pairs`` random stored pairs (sqrt(scale_pairs) anchors x as many others).
Both are estimated from the first m rows, m a power of two: the scales depend on the
stored descriptors only.  The first prefilter stage and then the verifiers draw
their pairs from one generator seeded by (``seed``, m); every further prefilter
stage i (i >= 1) from a generator of its own, seeded by (``seed``, m, i), so that
adding a prefilter stage leaves every other stage's scale as it was (a shared
stream would hand the verifiers other pairs).  A median of 0 falls back to the
mean, then to 1.  Units: each stage's own distance unit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from loopclosure.matchers.base import Matcher
from loopclosure.matchers.vector_search import VectorStore
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_match import Descriptors

Array = NDArray[np.float64]


def stage_scales(
    config: PlaceDatabaseConfig,
    stores: Mapping[str, VectorStore],
    matchers: Mapping[str, Matcher],
    descriptors: Sequence[Descriptors],
    m: int,
) -> Array:
    """``(S,)`` scale of every stage (`PlaceDatabaseConfig.stages` order) from the
    first `m` rows (m >= 2): prefilter stages from their vector stores, verifiers
    from the stored descriptors (each further prefilter stage's pairs from a
    generator of its own: module docstring)."""
    rng = np.random.default_rng([config.seed, m])
    scales = []
    for i, s in enumerate(config.prefilter):
        a, b = _random_pairs(rng if i == 0 else np.random.default_rng([config.seed, m, i]),
                             m, 256)
        store = stores[s]
        diff = store.matrix[a].astype(float) - store.matrix[b].astype(float)
        scales.append(_positive_median(np.sqrt(np.einsum("ij,ij->i", diff, diff))))
    for v in config.verifiers:
        matcher = matchers[v]
        descs = [d[v] for d in descriptors[:m]]
        n_anchor = max(1, int(np.sqrt(config.scale_pairs)))
        per = max(1, config.scale_pairs // n_anchor)
        values = []
        for i in rng.choice(m, size=min(n_anchor, m), replace=False):
            others = rng.choice(m - 1, size=min(per, m - 1), replace=False)
            others = others + (others >= i)  # skip the anchor itself
            stacked = matcher.stack([descs[j] for j in others])
            values.append(np.asarray(matcher.distances(descs[i], stacked), float))
        scales.append(_positive_median(np.concatenate(values)))
    return np.asarray(scales, float)


def _random_pairs(rng: np.random.Generator, m: int, n: int) -> tuple[NDArray, NDArray]:
    """`n` random pairs (a, b), a != b, of indices below `m` (m >= 2)."""
    a = rng.integers(0, m, size=n)
    b = rng.integers(0, m - 1, size=n)
    b = b + (b >= a)
    return a, b


def _positive_median(values: Array) -> float:
    """Median of the finite values, falling back to their mean / 1.0 when it is 0."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return 1.0
    med = float(np.median(v))
    if med > 0:
        return med
    mean = float(v.mean())
    return mean if mean > 0 else 1.0



__all__ = ["stage_scales"]
