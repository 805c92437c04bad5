"""The point-context stripe descriptor ``[l, d, o]`` (stripes paper, Section IV, Eq. 1-3).

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``).

A stripe is an ordered 2D point path ``C = p_1 .. p_H`` (for camera stripes: image pixels,
``(column, row)``, row pointing down; for point-cloud stripes: the slice profile in
`extraction.stripes_from_points` units).  Per stripe:

- Eq. 1: ``E(i, m) = log(1 + ||p_i - p_m||)``; ``d`` = mean of the lower triangle of E.
- Eq. 2: ``Theta(i, m) = angle(p_i - p_m)`` in ``[-pi, pi]`` (``atan2`` of the y and x
  differences); ``o`` = mean of the triangular half (lower or upper) holding more
  positive values.
- Eq. 3: ``C = [l, d, o]``, ``l`` = ``H`` (the stripe's point count) divided by the mean
  ``H`` of all stripes of the object (paper footnote 2).

Choices where the paper is silent, and differences from it:

- Triangles are *strict* (``i > m``, the ``H(H-1)/2`` pairs of distinct points): the
  zero diagonal is not averaged in.  A tie between the halves (as many positive values
  in each) picks the half with the larger mean, so ``o`` does not change when a
  stripe's point order is reversed (the two halves swap).
- Sample points (Section VI.C: "the point context descriptor using sample points along
  the stripe path", cost ``O(H^2)``): a stripe longer than `max_samples` is described
  by `max_samples` of its points, evenly spaced by index (always keeping both ends).
  Both means are pair averages, so subsampling changes them little: the pairs at lags
  shorter than the sample stride are missing, which biases ``d`` slightly up (the more,
  the fewer the samples) and moves ``o`` slightly.
  ``max_samples=None`` uses every point (the exact definition).  ``l`` always uses the
  full count ``H``.
- Very short stripes: the authors' code zeroes the features of stripes of three
  pixels or fewer.  Here a stripe with fewer than `min_points` (default 4) points gets
  ``d = o = 0`` but keeps its ``l`` (its length is still real information); it still
  counts in the object's stripe set and in the mean length.  Empty stripes (no points)
  are dropped before describing, and an object without any stripe is an error.
- Stripe count and scale (options, off by default, where the paper is silent on how
  densely an object is swept and in which unit its points are): with `stripe_count`
  an object swept by more stripes keeps `stripe_count` of them, evenly spaced in scan
  order (both ends kept), before anything is computed, so every object is described
  by about the same number of stripes whatever its length along the sweep and the
  laser step; with `scale_free` the points of an object are divided by its mean
  stripe point count and multiplied by `SCALE_FREE_WIDTH`, so ``d`` measures the
  stripes' shape relative to the object's width instead of in pixels.  Both make
  the descriptor of a large object resemble that of a small one of the same shape
  (the trimming of Eq. 4 otherwise compares the central run of a long object with
  the whole of a short one); they drop the size cues an instance-level matcher wants.
- Units: ``d`` depends on the unit of the points (pixels here, as in the paper); ``o``
  is in radians; ``l`` is unitless.

- Known property of Eq. 2 (not a choice): pair angles of a nearly horizontal stripe
  (a flat surface: book covers) sit at the 0 / pi boundary, so one pixel of tilt moves
  ``o`` between about 0 and about pi; the paper's weak book class shows it too.

Everything is vectorised over all pairs of all stripes with the same sample count (pair
terms in float32, means accumulated in float64); the only Python loop is over the
distinct sample counts (at most `max_samples`), never over stripes, points or pairs.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import DataError, UserError

Array = NDArray[np.float64]

#: Paper footnote / authors' code: stripes of three points or fewer carry no shape.
MIN_POINTS = 4
#: Default number of sample points per stripe (Section VI.C); see the module docstring.
MAX_SAMPLES = 32
#: With ``scale_free``: the mean stripe of every object spans this many units (the
#: order of a stripe's width in the paper's 712-pixel images, so ``log(1 + x)`` of
#: Eq. 1 works in the same regime as on pixels).
SCALE_FREE_WIDTH = 100.0


@dataclass(frozen=True, slots=True)
class DescriptorConfig:
    """Parameters of the stripe descriptor.

    Attributes:
        max_samples: sample points per stripe for ``d`` and ``o`` (None: all points).
        min_points: stripes with fewer points get ``d = o = 0`` (authors: ``<= 3``).
        chunk_pairs: memory bound of one vectorised batch (stripes x pairs).
        stripe_count: keep at most this many stripes per object, evenly spaced in
            scan order (None: all stripes, the paper).
        scale_free: points in units of the object's mean stripe width / 100
            (False: the points' own unit, pixels as in the paper).
    """

    max_samples: int | None = MAX_SAMPLES
    min_points: int = MIN_POINTS
    chunk_pairs: int = 1_000_000
    stripe_count: int | None = None
    scale_free: bool = False

    def __post_init__(self) -> None:
        if self.stripe_count is not None and self.stripe_count < 2:
            raise UserError(f"stripe_count must be at least 2 (or None), got {self.stripe_count}")
        if self.max_samples is not None and self.max_samples < 4:
            raise UserError(f"max_samples must be at least 4 (or None), got {self.max_samples}")
        if self.min_points < 2:
            raise UserError(f"min_points must be at least 2, got {self.min_points}")


@dataclass(frozen=True, slots=True)
class StripeDescriptor:
    """One object's stripe set described as ``(N, 3)`` rows ``[l, d, o]`` in stripe order.

    Attributes:
        features: ``(N, 3)`` float64, row i = stripe i in scan order (the laser's
            moving direction for camera stripes, slice order for point clouds).
        lengths: ``(N,)`` point count ``H`` of each stripe.
        name: optional identifier (file, object id) used in messages.
    """

    features: Array
    lengths: NDArray[np.int64]
    name: str | None = None

    def __len__(self) -> int:
        return int(self.features.shape[0])

    @property
    def l(self) -> Array:  # noqa: E743 - the paper's name
        """Normalised stripe lengths (Eq. 3, first feature)."""
        return self.features[:, 0]

    @property
    def d(self) -> Array:
        """Mean log distances (Eq. 1)."""
        return self.features[:, 1]

    @property
    def o(self) -> Array:
        """Mean orientations [rad] (Eq. 2)."""
        return self.features[:, 2]


def _sample_indices(h: NDArray[np.int64], s: int) -> NDArray[np.int64]:
    """``(K, s)`` indices into each stripe: all points when ``h <= s``, else ``s`` evenly spaced.

    Rows of stripes shorter than `s` are padded with their last index (masked later).
    """
    k = np.arange(s)[None, :]
    hh = h[:, None]
    spaced = np.rint(k * (hh - 1) / max(s - 1, 1)).astype(np.int64)
    return np.where(hh > s, spaced, np.minimum(k, np.maximum(hh - 1, 0)))


def _pair_features(points: Array) -> tuple[Array, Array]:
    """``d`` and ``o`` of a batch ``(K, S, 2)`` of stripes with exactly ``S`` points each.

    Pair terms are computed in float32 (their means are accumulated in float64): the
    features are means of many terms, so single precision costs nothing measurable and
    halves the memory traffic of the ``K x S(S-1)/2`` pair arrays.
    """
    s = points.shape[1]
    i, m = np.tril_indices(s, k=-1)  # strict lower triangle: row i > column m
    p = points.astype(np.float32)
    dx = p[:, i, 0] - p[:, m, 0] + np.float32(0.0)  # p_i - p_m; + 0 turns -0.0 into +0.0
    dy = p[:, i, 1] - p[:, m, 1] + np.float32(0.0)
    n_pairs = len(i)
    d = np.log1p(np.hypot(dx, dy)).sum(axis=1, dtype=np.float64) / n_pairs  # Eq. 1
    lower = np.arctan2(dy, dx)  # Eq. 2, Theta(i, m) for i > m, in (-pi, pi]
    same = (dx == 0) & (dy == 0)  # coincident points: angle 0 both ways
    lower[same] = 0.0
    # The upper triangle holds Theta(m, i) = angle(p_m - p_i), the opposite vector:
    # lower - pi where lower > 0, lower + pi where lower <= 0 (0 for coincident points).
    pos_lower = (lower > 0).sum(axis=1)
    n_same = same.sum(axis=1)
    pos_upper = n_pairs - pos_lower - n_same
    sum_lower = lower.sum(axis=1, dtype=np.float64)
    sum_upper = sum_lower + np.pi * (pos_upper - pos_lower)
    mean_lower, mean_upper = sum_lower / n_pairs, sum_upper / n_pairs
    pick_upper = (pos_upper > pos_lower) | ((pos_upper == pos_lower) & (mean_upper > mean_lower))
    return d, np.where(pick_upper, mean_upper, mean_lower)


def point_context(
    stripes: Sequence[ArrayLike], config: DescriptorConfig | None = None
) -> tuple[Array, Array]:
    """``(d, o)`` of each stripe (Eq. 1-2), each ``(N,)``; stripes are ``(H, 2)`` point paths.

    Stripes with fewer than ``config.min_points`` points get ``d = o = 0``.  Stripes are
    batched by sample count (all stripes longer than `max_samples` form one batch), so
    there is no padding and no Python loop over stripes, points or pairs.
    """
    cfg = config or DescriptorConfig()
    d = np.zeros(len(stripes))
    o = np.zeros(len(stripes))
    for group, pts in sampled_batches(stripes, cfg.max_samples, cfg.min_points):
        s = pts.shape[1]
        per_chunk = max(1, cfg.chunk_pairs // max(s * (s - 1) // 2, 1))
        for start in range(0, len(group), per_chunk):
            g = slice(start, start + per_chunk)
            d[group[g]], o[group[g]] = _pair_features(pts[g])
    return d, o


def sampled_batches(
    stripes: Sequence[ArrayLike], max_samples: int | None, min_points: int
) -> Iterator[tuple[NDArray[np.intp], Array]]:
    """The stripes of at least `min_points` points in batches of equal sample count:
    ``(indices into stripes, (k, s, 2) points)``, each stripe's points all or
    `max_samples` evenly spaced (`_sample_indices`; None: the longest stripe's count)."""
    arrays = [np.asarray(c, dtype=float).reshape(-1, 2) for c in stripes]
    if not arrays:
        return
    h = np.array([len(a) for a in arrays], dtype=np.int64)
    yield from flat_sampled_batches(np.concatenate(arrays), h, max_samples, min_points)


def flat_sampled_batches(
    flat: Array, h: NDArray[np.int64], max_samples: int | None, min_points: int
) -> Iterator[tuple[NDArray[np.intp], Array]]:
    """`sampled_batches` of stripes given as their points one after the other, `flat`
    ``(sum h, 2)``, and their point counts `h` ``(N,)`` (no list of arrays to join)."""
    if len(h) == 0:
        return
    cap = int(h.max()) if max_samples is None else int(max_samples)
    samples = np.minimum(h, max(cap, 2))
    described = h >= max(min_points, 2)
    if not described.any():
        return
    offsets = np.concatenate([[0], np.cumsum(h)[:-1]])
    for s in np.unique(samples[described]):
        group = np.flatnonzero(described & (samples == s))
        idx = _sample_indices(h[group], int(s))
        yield group, flat[offsets[group, None] + idx]


def resample_stripes(arrays: Sequence[Array], count: int | None) -> list[Array]:
    """At most `count` stripes of an ordered set, evenly spaced by index, both ends kept.

    ``count=None`` or a set of at most `count` stripes: unchanged.
    """
    arrays = list(arrays)
    if count is None or len(arrays) <= count:
        return arrays
    idx = np.unique(np.rint(np.linspace(0, len(arrays) - 1, count)).astype(np.int64))
    return [arrays[i] for i in idx]


def _prepared(arrays: list[Array], cfg: DescriptorConfig) -> list[Array]:
    """An object's stripes after the `stripe_count` and `scale_free` options."""
    arrays = resample_stripes(arrays, cfg.stripe_count)
    if cfg.scale_free:
        unit = float(np.mean([len(a) for a in arrays])) / SCALE_FREE_WIDTH
        arrays = [a / unit for a in arrays]
    return arrays


def describe_stripes(
    stripes: Sequence[ArrayLike],
    config: DescriptorConfig | None = None,
    name: str | None = None,
) -> StripeDescriptor:
    """Descriptor ``[l, d, o]`` of one object's ordered stripe set (Eq. 3).

    Args:
        stripes: ordered stripes, each ``(H, 2)`` points (pixels for camera stripes).
            Empty stripes are dropped.
        config: descriptor parameters.
        name: object identifier used in error messages.

    Raises:
        DataError: the object has no non-empty stripe, or a stripe holds NaN/inf.
    """
    arrays = [np.asarray(c, dtype=float).reshape(-1, 2) for c in stripes]
    arrays = [a for a in arrays if len(a) > 0]
    if not arrays:
        raise DataError(name, "empty stripe set: the object has no stripe to describe")
    for a in arrays:
        if not np.isfinite(a).all():
            raise DataError(name, "stripe points contain NaN or inf")
    arrays = _prepared(arrays, config or DescriptorConfig())
    lengths = np.array([len(a) for a in arrays], dtype=np.int64)
    l = lengths / lengths.mean()  # noqa: E741 - the paper's name
    d, o = point_context(arrays, config)
    return StripeDescriptor(np.column_stack([l, d, o]), lengths, name)


def describe_many(
    objects: Sequence[Sequence[ArrayLike]],
    config: DescriptorConfig | None = None,
    names: Sequence[str] | None = None,
) -> list[StripeDescriptor]:
    """Descriptors of many objects with one vectorised pass over all their stripes.

    Same result as calling `describe_stripes` on each object, faster for many objects.
    """
    names = list(names) if names is not None else [None] * len(objects)
    sets: list[list[Array]] = []
    for obj, nm in zip(objects, names, strict=True):
        arrays = [np.asarray(c, dtype=float).reshape(-1, 2) for c in obj]
        arrays = [a for a in arrays if len(a) > 0]
        if not arrays:
            raise DataError(nm, "empty stripe set: the object has no stripe to describe")
        if not all(np.isfinite(a).all() for a in arrays):
            raise DataError(nm, "stripe points contain NaN or inf")
        sets.append(_prepared(arrays, config or DescriptorConfig()))
    flat = [a for s in sets for a in s]
    d, o = point_context(flat, config)
    out = []
    start = 0
    for arrays, nm in zip(sets, names, strict=True):
        n = len(arrays)
        lengths = np.array([len(a) for a in arrays], dtype=np.int64)
        l = lengths / lengths.mean()  # noqa: E741
        sl = slice(start, start + n)
        out.append(StripeDescriptor(np.column_stack([l, d[sl], o[sl]]), lengths, nm))
        start += n
    return out
