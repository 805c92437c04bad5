"""Fused object matching: the stripe distance verified by silhouette matchers.

Paper: "Stripes-based Object Matching", Section VI.B ("a proper combination of shape
descriptors and the proposed stripe descriptor can improve the matching accuracy
over the individual descriptor"); the paper gives no rule, so the rule here is the
place cascade's idea without learnt weights, which keeps it free of any data set:

- every method ``k`` gives, for one query, distances ``D_k(j)`` to the database
  objects ``j`` (the stripes' Eq. 5, a silhouette matcher's own distance);
- each is divided by its median over the database, ``D_k(j) / median_j D_k(j)``:
  a unitless score where 1 is a typical object for this query and method, so
  methods with different units and spreads add up (`normalised`);
- the fused distance is the weighted mean of the scores (`fuse`), equal weights by
  default.

The stripe side of the fusion is the stripe profile (`profile.ProfileDatabase`:
every object resampled to 32 positions along the sweep, scale-free, order kept), the
stripe matcher for classes whose members differ in size and length; the silhouette
verifiers add the footprint's outline, which the profile sees only along the sweep.
`FusedObjectDatabase` also accepts the paper's `StripeDescriptor`s; then
`FUSED_DESCRIPTOR` (32 evenly spaced stripes per object, `descriptor.resample_stripes`)
is the description that avoids Eq. 4's trimming of objects swept by different
stripe counts.

`FusedObjectDatabase` holds one `ProfileDatabase` (or `StripeDatabase`), optionally
a `relief.ReliefDatabase` (the objects' reliefs: depth below the top, ring by ring,
read from the same stripes as heights) and a `surface.SurfaceDatabase` (the surface
context: distances and elevations of pairs of the object's 3D surface points, Eq.
1-2 over the whole object), and, per verifier, the silhouette descriptors of the same
objects; a query is the object's stripe profile (or descriptor), its relief and
surface context when the database holds them, and its silhouette polygon (the
scanned footprint in the table plane, millimetres).

The default matcher (``fused`` in ``bench stripes``) is all four parts: profile,
relief, surface context and shape context on 50 points (`DEFAULT_VERIFIERS`), each
divided by its per-query median, equal weights.  Each part reads what the others
miss: the profile where along its length the object is tall, round or flat (blind
to the outline once resampled); the relief how deep the surface falls below the top
(flat box tops against studded bricks, lids, domes and hollows); the surface context
how the parts lie relative to each other in 3D (a cup's rim over its bottom, a
bottle's cap over its shoulders); shape context the footprint's outline (blind to
height).  Give `reliefs` and `surfaces` for it; without them the fusion is the
profile and the verifiers.  FFT and ring projection (`FAST_VERIFIERS`) are the
microsecond alternative to shape context.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.matchers import get_matcher
from loopclosure.polygon import Polygon
from loopclosure.stripes.database import StripeDatabase
from loopclosure.stripes.descriptor import DescriptorConfig, StripeDescriptor
from loopclosure.stripes.profile import ProfileDatabase, StripeProfile
from loopclosure.stripes.relief import ReliefDatabase, StripeRelief
from loopclosure.stripes.surface import StripeSurface, SurfaceDatabase

Array = NDArray[np.float64]

#: Verifier names that stand for a matcher with options: name -> (matcher, options).
#: ``shape-context-50``: shape context on 50 boundary points (instead of 100) with the
#: compiled kernel (`loopclosure.matchers.shape_context_kernel`); the assignment is
#: cubic in the points, so halving them cuts its cost about eightfold.
VERIFIER_PRESETS: dict[str, tuple[str, dict[str, Any]]] = {
    "shape-context-50": ("shape-context", {"n_points": 50, "kernel": "numba"}),
}
#: The shape-context verifier: the profile's complement (the footprint's outline, which
#: the resampled profile drops), at shape context's all-pairs point-matching cost.
SC_VERIFIERS: tuple[str, ...] = ("shape-context-50",)
#: Silhouette matchers fused with the stripes by default (module docstring).
DEFAULT_VERIFIERS: tuple[str, ...] = SC_VERIFIERS
#: The cheap verifiers: global summaries of the outline at microseconds per pair.
FAST_VERIFIERS: tuple[str, ...] = ("fft", "ring")
#: Stripes per object when the fusion's stripe side is the paper's descriptor.
FUSED_STRIPE_COUNT = 32
#: Descriptor parameters for `StripeDescriptor`s in the fusion (module docstring).
FUSED_DESCRIPTOR = DescriptorConfig(stripe_count=FUSED_STRIPE_COUNT)


def normalised(distances: ArrayLike) -> Array:
    """Distances divided by their median over the last axis (per query), >= 0, finite.

    A row whose median is 0 (most objects identical to the query) is divided by its
    mean instead, and by 1 when that is 0 too; infinite distances become the largest
    finite score of the row times two.
    """
    d = np.array(distances, dtype=float)
    if d.ndim == 0 or d.shape[-1] == 0:
        raise UserError("normalised needs at least one distance per query")
    if np.any(d < 0):
        raise UserError("distances must be non-negative")
    finite = np.where(np.isfinite(d), d, np.nan)
    med = np.nanmedian(finite, axis=-1, keepdims=True)
    mean = np.nanmean(finite, axis=-1, keepdims=True)
    med = np.where(np.isfinite(med) & (med > 0), med,
                   np.where(np.isfinite(mean) & (mean > 0), mean, 1.0))
    out = finite / med
    top = np.nanmax(np.where(np.isfinite(out), out, np.nan), axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 1.0)
    return np.where(np.isfinite(out), out, 2.0 * top)


def fuse(parts: Sequence[ArrayLike], weights: Sequence[float] | None = None) -> Array:
    """Weighted mean of the `normalised` distances of several methods (same shape each)."""
    if not parts:
        raise UserError("fuse needs at least one method's distances")
    arrays = [normalised(p) for p in parts]
    shape = arrays[0].shape
    if any(a.shape != shape for a in arrays):
        raise UserError(f"every method's distances must have one shape, got "
                        f"{[a.shape for a in arrays]}")
    w = np.ones(len(arrays)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(arrays),) or np.any(w < 0) or not w.sum() > 0:
        raise UserError(f"weights must be {len(arrays)} non-negative values, not all zero")
    return sum(wi * a for wi, a in zip(w / w.sum(), arrays, strict=True))


def verifier_options(name: str) -> tuple[str, dict[str, Any]]:
    """The matcher name and options behind verifier `name` (`VERIFIER_PRESETS`, or a
    matcher name with no options)."""
    base, options = VERIFIER_PRESETS.get(name, (name, {}))
    return base, dict(options)


def verifier(name: str) -> Any:
    """A silhouette matcher by name or preset, scale invariant when it has the option."""
    base, options = verifier_options(name)
    try:
        return get_matcher(base, scale_invariant=True, **options)
    except UserError:
        return get_matcher(base, **options)


class FusedObjectDatabase:
    """Objects as stripe descriptors and silhouettes, queried with the fused distance.

    Args:
        descriptors: one `StripeProfile` per object (the module's rule), or one
            `StripeDescriptor` (made with `FUSED_DESCRIPTOR`); queries must be
            described the same way.
        silhouettes: one silhouette `Polygon` per object (same order).
        verifiers: silhouette matcher names (`loopclosure.matchers`, or a preset of
            `VERIFIER_PRESETS`); default shape context on 50 points.
        weights: fusion weights, stripes first, then the relief (when `reliefs` is
            given), the surface context (when `surfaces` is given), then each
            verifier (None: equal).
        stripe_weights: Eq. 5 weights of the stripe distance (`StripeDescriptor`s only).
        reliefs: one `StripeRelief` per object (same order), or None: no relief part.
        surfaces: one `StripeSurface` per object (same order), or None: no surface part.
    """

    def __init__(
        self,
        descriptors: Sequence[StripeProfile] | Sequence[StripeDescriptor],
        silhouettes: Sequence[Polygon],
        verifiers: Sequence[str] = DEFAULT_VERIFIERS,
        weights: Sequence[float] | None = None,
        stripe_weights: Sequence[float] | None = None,
        reliefs: Sequence[StripeRelief] | None = None,
        surfaces: Sequence[StripeSurface] | None = None,
    ) -> None:
        if len(descriptors) != len(silhouettes):
            raise UserError(f"silhouettes must hold one polygon per object: {len(silhouettes)} "
                            f"for {len(descriptors)} descriptors")
        for what, items in (("reliefs", reliefs), ("surfaces", surfaces)):
            if items is not None and len(items) != len(descriptors):
                raise UserError(f"{what} must hold one per object: {len(items)} "
                                f"for {len(descriptors)} descriptors")
        parts = 1 + (reliefs is not None) + (surfaces is not None) + len(verifiers)
        if weights is not None and len(weights) != parts:
            raise UserError(f"weights need {parts} values (stripes, "
                            f"{'the relief, ' if reliefs is not None else ''}"
                            f"{'the surface context, ' if surfaces is not None else ''}then "
                            f"each verifier), got {len(weights)}")
        self.stripes: ProfileDatabase | StripeDatabase
        if descriptors and all(isinstance(d, StripeProfile) for d in descriptors):
            if stripe_weights is not None:
                raise UserError("stripe_weights apply to StripeDescriptors, not profiles")
            self.stripes = ProfileDatabase(descriptors)  # type: ignore[arg-type]
        else:
            self.stripes = (StripeDatabase(descriptors) if stripe_weights is None  # type: ignore[arg-type]
                            else StripeDatabase(descriptors, stripe_weights))  # type: ignore[arg-type]
        self.weights = None if weights is None else tuple(float(w) for w in weights)
        self.reliefs = None if reliefs is None else ReliefDatabase(reliefs)
        self.surfaces = None if surfaces is None else SurfaceDatabase(surfaces)
        self.matchers = [verifier(n) for n in verifiers]
        self.verifier_names = tuple(verifiers)
        self.stacks = [m.stack([m.describe(p) for p in silhouettes]) for m in self.matchers]

    def __len__(self) -> int:
        return len(self.stripes)

    def method_distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
    ) -> list[Array]:
        """``(K,)`` distances of the stripes, the relief, the surface context (each when
        the database holds them: then the query's is required), then each verifier, to
        every object."""
        for what, mine, theirs in (("relief", relief, self.reliefs),
                                   ("surface context", surface, self.surfaces)):
            if (mine is None) != (theirs is None):
                raise UserError(f"give the query's {what} exactly when the database holds "
                                f"{what}s" if theirs is not None else
                                f"this database holds no {what}s; query without one")
        out = [self.stripes.distances(descriptor)]  # type: ignore[arg-type]
        if self.reliefs is not None and relief is not None:
            out.append(self.reliefs.distances(relief))
        if self.surfaces is not None and surface is not None:
            out.append(self.surfaces.distances(surface))
        for m, st in zip(self.matchers, self.stacks, strict=True):
            out.append(np.asarray(m.distances(m.describe(silhouette), st), dtype=float))
        return out

    def distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
    ) -> Array:
        """``(K,)`` fused distances of the query to every object (module docstring)."""
        return fuse(self.method_distances(descriptor, silhouette, relief, surface),
                    self.weights)

    def query(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon, k: int = 10,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
    ) -> tuple[NDArray[np.int64], Array]:
        """Indices and fused distances of the `k` nearest objects, nearest first."""
        d = self.distances(descriptor, silhouette, relief, surface)
        order = np.argsort(d, kind="stable")[:k]
        return order, d[order]
