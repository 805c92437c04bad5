"""The stripe profile: an object's stripes as a fixed-length, scale-free, ordered sequence.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``), the
features of Section IV (Eq. 1-3) kept in the stripes' scan order instead of being
summarised by one Gaussian per feature (Eq. 4-6).  The paper's own matcher is
`matching` / `database`; this module is a second matcher on the same stripes, for
object *classes* whose members differ in size, which the paper's Daily set does not
exercise.

Why (each step answers one cause found on real scanned meshes):

- Stripe count.  Eq. 4 trims the longer object to the shorter one's stripe count, so
  it compares the central part of a long object with the whole of a short one; the
  count itself is the object's length along the sweep divided by the laser step.  Here
  every object's stripe sequence is resampled to `ProfileConfig.samples` positions
  evenly spaced along the sweep (over the normalised stripe index ``t = i / (N - 1)``,
  each position the mean of its share of the length: `resample_profile`): position
  ``k`` of two objects is the same fraction of their length, whatever their size and
  the laser step, and nothing is trimmed.
- Size.  ``d`` (Eq. 1) is a mean log distance in pixels, so it measures the object's
  size.  Here the points of each stripe are divided by that stripe's point count ``H``
  and multiplied by `SCALE_FREE_WIDTH` before Eq. 1 (the unit is 1/100 of the
  stripe's own width: ``H`` is its width in pixel columns where the detector found
  the line in every column), so ``d`` measures the stripe's shape: how its
  points spread relative to its width (a straight stripe, an arc, a stripe broken by
  a cup's opening).  Dividing by the object's *mean* stripe width instead would keep
  ``d`` mostly a function of the stripe's relative width, which ``l`` (Eq. 3) already
  is (over the stripes of real scanned objects it follows ``log l`` closely; per
  stripe it hardly does), so the profile would count the footprint's width twice and
  the stripes' shape once.
- Orientation.  Eq. 2's angles of a nearly flat stripe sit at the 0 / pi boundary,
  so one pixel of tilt moves ``o`` from about 0 to about pi (box tops, flat bases).
  The profile replaces ``o`` by the *elevation* ``e``: the mean over the pairs
  ``i > m`` of ``atan(|dy| / |dx|)`` in ``[0, pi/2]`` (``dx, dy`` of ``p_i - p_m``),
  Eq. 2's angle folded onto the undirected, mirror-free slope: 0 for a flat stripe,
  growing with the stripe's height relative to its width, continuous everywhere.
- Order.  The Gaussian fits of Eq. 5 forget where along the object a stripe lies (a
  cup's rim, a ball's crown); the profile keeps it.  An object placed the other way
  round is swept in reverse order with each stripe mirrored; ``l``, ``d`` and ``e``
  do not change under the mirror, so the distance is the smaller of the profile
  against the other and against the other reversed.

Per stripe (rows of the profile before resampling): ``[l, d, e]`` with ``l`` as Eq. 3
(stripe point count over the object's mean), ``d`` as Eq. 1 on the stripe's points in
units of ``H / SCALE_FREE_WIDTH``, ``e`` the elevation (radians).  Stripes with fewer
than `ProfileConfig.min_points` points get ``d = e = 0`` (as the paper's descriptor).
``d`` and ``e`` use `ProfileConfig.points` sample points evenly spaced by index along
long stripes (as `descriptor.MAX_SAMPLES`).

Distance of two profiles ``P, Q`` (``(K, 3)`` each): per feature ``f`` the mean
absolute difference ``D_f = 1/K sum_k |P[k, f] - Q[k, f]|``.  The three features
have different units (unitless, log units, radians), and the paper's lambda weights
were learnt for the Gaussian distances of Eq. 6 on its Daily set, so they do not
carry over; nothing is fitted here either.  Instead, for one query against a
database, each feature's distances are divided by their median over the database
(the rule of `fusion.normalised`: 1 means "a typical object for this query and
feature"; by the mean when most of the database is the query itself), the three
are averaged, and the orientation (forward or reversed) with
the smaller average is kept.  `ProfileDatabase` does this for every object at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import DataError, UserError
from loopclosure.stripes.descriptor import (
    MAX_SAMPLES,
    MIN_POINTS,
    SCALE_FREE_WIDTH,
    flat_sampled_batches,
)

Array = NDArray[np.float64]

#: Profile length: positions along the sweep every object is resampled to.  Below the
#: stripe count of the smallest object the default scanner resolves (about 37 stripes
#: for 3 cm at 0.8 mm per frame), so no object is upsampled much, and enough for a
#: profile to show a cup's rim or a ball's crown.
PROFILE_SAMPLES = 32
#: Names of the profile's three features, in column order.
PROFILE_FEATURES: tuple[str, str, str] = ("l", "d", "e")


@dataclass(frozen=True, slots=True)
class ProfileConfig:
    """Parameters of the stripe profile.

    Attributes:
        samples: positions along the sweep (``K``).
        points: sample points per stripe for ``d`` and ``e`` (None: every point).
        min_points: stripes with fewer points get ``d = e = 0``.
    """

    samples: int = PROFILE_SAMPLES
    points: int | None = MAX_SAMPLES
    min_points: int = MIN_POINTS

    def __post_init__(self) -> None:
        if self.samples < 2:
            raise UserError(f"profile samples must be at least 2, got {self.samples}")
        if self.points is not None and self.points < 4:
            raise UserError(f"profile points must be at least 4 (or None), got {self.points}")
        if self.min_points < 2:
            raise UserError(f"min_points must be at least 2, got {self.min_points}")


@dataclass(frozen=True, slots=True)
class StripeProfile:
    """One object's stripe profile.

    Attributes:
        profile: ``(K, 3)`` float64, row k = ``[l, d, e]`` at the fraction
            ``k / (K - 1)`` of the object's length along the sweep.
        stripes: number of stripes the profile was resampled from.
        name: optional identifier used in messages.
    """

    profile: Array
    stripes: int
    name: str | None = None


def _distance_and_elevation(points: Array) -> tuple[Array, Array]:
    """Eq. 1's ``d`` and the elevation ``e`` of a batch ``(n, S, 2)`` of stripes.

    The pairs ``i > m`` (``numpy.tril_indices(S, k=-1)`` order) in float32, each
    coordinate gathered from its own contiguous ``(n, S)`` array by `numpy.take` (the
    same numbers as fancy indexing of the ``(n, S, 2)`` batch, several times faster).
    """
    s = points.shape[1]
    i, m = np.tril_indices(s, k=-1)
    p = np.asarray(points, dtype=np.float32)
    x, y = np.ascontiguousarray(p[..., 0]), np.ascontiguousarray(p[..., 1])
    dx = np.take(x, i, axis=1)
    dx -= np.take(x, m, axis=1)
    np.abs(dx, out=dx)
    dy = np.take(y, i, axis=1)
    dy -= np.take(y, m, axis=1)
    np.abs(dy, out=dy)
    n_pairs = len(i)
    d = np.log1p(np.hypot(dx, dy)).sum(axis=1, dtype=np.float64) / n_pairs
    e = np.arctan2(dy, dx).sum(axis=1, dtype=np.float64) / n_pairs  # atan2(0, 0) = 0
    return d, e


def stripe_shape(
    stripes: Sequence[ArrayLike], config: ProfileConfig | None = None
) -> tuple[Array, Array]:
    """``(d, e)`` of each stripe, each ``(N,)`` (module docstring); points ``(H, 2)``.

    Vectorised in batches of equal sample count (no loop over stripes or pairs).
    """
    arrays = [np.asarray(c, dtype=float).reshape(-1, 2) for c in stripes]
    if not arrays:
        return np.zeros(0), np.zeros(0)
    h = np.array([len(a) for a in arrays], dtype=np.int64)
    return _flat_stripe_shape(np.concatenate(arrays), h, config or ProfileConfig())


def _flat_stripe_shape(flat: Array, h: NDArray[np.int64], cfg: ProfileConfig
                       ) -> tuple[Array, Array]:
    """`stripe_shape` of stripes given as their points one after the other, `flat`
    ``(sum h, 2)``, and their point counts `h`."""
    d = np.zeros(len(h))
    e = np.zeros(len(h))
    for group, pts in flat_sampled_batches(flat, h, cfg.points, cfg.min_points):
        d[group], e[group] = _distance_and_elevation(pts)
    return d, e


def _clean(stripes: Sequence[ArrayLike], name: str | None) -> list[Array]:
    arrays = [np.asarray(c, dtype=float).reshape(-1, 2) for c in stripes]
    arrays = [a for a in arrays if len(a) > 0]
    if not arrays:
        raise DataError(name, "empty stripe set: the object has no stripe to describe")
    if not np.isfinite(np.concatenate(arrays)).all():
        raise DataError(name, "stripe points contain NaN or inf")
    return arrays


def _integral(t: Array, f: Array, x: Array) -> Array:
    """``F(x) = int_0^x f`` of the piecewise-linear ``f`` through ``(t, f)`` (``t`` increasing
    from 0 to 1), at the points ``x`` in ``[0, 1]``; ``f`` ``(N,)`` or ``(N, F)``, one
    function per column (each column's numbers as on its own)."""
    dt = np.diff(t)
    col = (slice(None),) + (None,) * (f.ndim - 1)  # (N,) arrays against f's columns
    knots = np.concatenate([np.zeros((1, *f.shape[1:])),
                            np.cumsum(0.5 * (f[1:] + f[:-1]) * dt[col], axis=0)])
    i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, len(t) - 2)
    u = (x - t[i])[col]
    slope = (f[i + 1] - f[i]) / dt[i][col]
    return knots[i] + f[i] * u + 0.5 * slope * u * u


def resample_profile(features: ArrayLike, samples: int) -> Array:
    """``(N, F)`` per-stripe features -> ``(samples, F)``, each row the mean of the features
    over its share of the object's length.

    The stripes sit at ``t_i = i / (N - 1)`` along the object, joined linearly; row
    ``k`` is the mean of that piecewise-linear function over the bin
    ``[c_k - h, c_k + h]`` around ``c_k = k / (samples - 1)``, ``h = 1 / (2 (samples -
    1))``, clipped to ``[0, 1]`` (the two end bins are half as wide): exact integrals,
    no sub-sampling.  Why a bin mean and not the value at ``c_k``: an object swept by
    many more stripes than `samples` would otherwise be described by one stripe in
    ``N / samples``, which of them depending on the laser's phase, with every stripe's
    own noise (gaps, speckle) kept; the mean over the bin is the anti-aliased
    resampling.  For ``N <= samples`` it differs from linear interpolation only by the
    averaging of the line over the bin.  One stripe: that row repeated.
    """
    f = np.asarray(features, dtype=float)
    if f.ndim != 2 or len(f) == 0:
        raise UserError(f"features must be a non-empty (N, F) array, got shape {f.shape}")
    if len(f) == 1:
        return np.repeat(f, samples, axis=0)
    t = np.linspace(0.0, 1.0, len(f))
    c = np.linspace(0.0, 1.0, samples)
    h = 0.5 / (samples - 1)
    lo, hi = np.clip(c - h, 0.0, 1.0), np.clip(c + h, 0.0, 1.0)
    return (_integral(t, f, hi) - _integral(t, f, lo)) / (hi - lo)[:, None]


def describe_profiles(
    objects: Sequence[Sequence[ArrayLike]],
    config: ProfileConfig | None = None,
    names: Sequence[str | None] | None = None,
) -> list[StripeProfile]:
    """Stripe profiles of many objects (each an ordered stripe set of ``(H, 2)`` points,
    pixels for camera stripes), with one vectorised pass over all their stripes.

    Raises:
        DataError: an object has no non-empty stripe, or a stripe holds NaN/inf.
    """
    cfg = config or ProfileConfig()
    names = list(names) if names is not None else [None] * len(objects)
    sets: list[list[Array]] = []
    for obj, nm in zip(objects, names, strict=True):
        sets.append(_clean(obj, nm))
    # Each stripe in units of its own width / SCALE_FREE_WIDTH (module docstring): every
    # point times SCALE_FREE_WIDTH / (its stripe's point count), all stripes at once.
    h = np.array([len(a) for s in sets for a in s], dtype=np.int64)
    flat = np.concatenate([a for s in sets for a in s])
    flat = flat * np.repeat(SCALE_FREE_WIDTH / h, h)[:, None]
    d, e = _flat_stripe_shape(flat, h, cfg)
    out = []
    start = 0
    for arrays, nm in zip(sets, names, strict=True):
        n = len(arrays)
        hs = h[start:start + n].astype(float)
        sl = slice(start, start + n)
        rows = np.column_stack([hs / hs.mean(), d[sl], e[sl]])
        out.append(StripeProfile(resample_profile(rows, cfg.samples), n, nm))
        start += n
    return out


def describe_profile(
    stripes: Sequence[ArrayLike], config: ProfileConfig | None = None, name: str | None = None
) -> StripeProfile:
    """The stripe profile of one object's ordered stripe set (module docstring)."""
    return describe_profiles([stripes], config, [name])[0]


#: A median below this fraction of the mean is float noise (most of the database is
#: the query itself): the mean is used instead.
MEDIAN_FLOOR = 1e-3


def _median_scale(d: Array) -> Array:
    """Per-query, per-feature median over the database (last-but-one axis), never 0.

    When the median is below `MEDIAN_FLOOR` times the mean (most objects identical to
    the query), the mean; when the mean is 0 too (every object identical), 1.
    """
    med = np.median(d, axis=-2, keepdims=True)
    mean = np.mean(d, axis=-2, keepdims=True)
    return np.where(med > MEDIAN_FLOOR * mean, med, np.where(mean > 0, mean, 1.0))


class ProfileDatabase:
    """Many objects' stripe profiles, queried in one vectorised pass (module docstring).

    Args:
        profiles: one `StripeProfile` per object, all with the same length ``K``.
    """

    #: ``(K, F)`` of the empty database's stack.
    EMPTY_SHAPE: tuple[int, int] = (PROFILE_SAMPLES, 3)

    def __init__(self, profiles: Sequence[StripeProfile]) -> None:
        self.profiles = list(profiles)
        shapes = {p.profile.shape for p in self.profiles}
        if len(shapes) > 1:
            raise UserError(f"every profile must have one shape, got {sorted(shapes)}")
        self.stack = (np.stack([p.profile for p in self.profiles]) if self.profiles
                      else np.zeros((0, *self.EMPTY_SHAPE)))

    def __len__(self) -> int:
        return len(self.profiles)

    def feature_distances(self, query: StripeProfile) -> tuple[Array, Array]:
        """``(M, F)`` mean absolute differences per feature, forward and reversed query."""
        q = np.asarray(query.profile, dtype=float)
        if q.shape != self.stack.shape[1:]:
            raise UserError(f"query profile has shape {q.shape}, the database "
                            f"{self.stack.shape[1:]}")
        forward = np.abs(self.stack - q[None]).mean(axis=1)
        reverse = np.abs(self.stack - q[None, ::-1]).mean(axis=1)
        return forward, reverse

    def distances(self, query: StripeProfile) -> Array:
        """``(M,)`` distances of the query to every object (>= 0, finite)."""
        if len(self) == 0:
            return np.zeros(0)
        forward, reverse = self.feature_distances(query)
        scale = _median_scale(np.minimum(forward, reverse))
        return np.minimum((forward / scale).mean(axis=1), (reverse / scale).mean(axis=1))

    def query(self, query: StripeProfile, k: int = 10) -> tuple[NDArray[np.int64], Array]:
        """Indices and distances of the `k` nearest objects, nearest first (stable ties)."""
        d = self.distances(query)
        order = np.argsort(d, kind="stable")[:k]
        return order, d[order]

    def pairwise(self) -> Array:
        """``(M, M)`` distances, row i = object i as query (zero diagonal, not symmetric:
        each row has its own medians)."""
        if len(self) == 0:
            return np.zeros((0, 0))
        s = self.stack
        forward = np.abs(s[:, None] - s[None]).mean(axis=2)  # (M, M, F)
        reverse = np.abs(s[:, None, ::-1] - s[None]).mean(axis=2)
        scale = _median_scale(np.minimum(forward, reverse))
        return np.minimum((forward / scale).mean(axis=2), (reverse / scale).mean(axis=2))
