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
read from the same stripes as heights), and, per verifier, the silhouette
descriptors of the same objects; a query is the object's stripe profile (or
descriptor), its relief when the database holds reliefs, and its silhouette polygon
(the scanned footprint in the table plane, millimetres).  Profile, relief and
shape context (`SC_VERIFIERS`) together are the ``fused-relief`` matcher of
``bench stripes``: the relief says how deep the surface falls below the top, which
neither the profile (each stripe in units of its own width) nor the outline sees.  The
default verifiers are FFT and ring projection (`loopclosure.matchers`), scale
invariant: both cost microseconds per pair, so the fused matcher keeps the stripes'
speed.
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

Array = NDArray[np.float64]

#: Silhouette matchers fused with the stripes by default.
DEFAULT_VERIFIERS: tuple[str, ...] = ("fft", "ring")
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
        verifiers: silhouette matcher names (`loopclosure.matchers`).
        weights: fusion weights, stripes first, then the relief (when `reliefs` is
            given), then each verifier (None: equal).
        stripe_weights: Eq. 5 weights of the stripe distance (`StripeDescriptor`s only).
        reliefs: one `StripeRelief` per object (same order), or None: no relief part.
    """

    def __init__(
        self,
        descriptors: Sequence[StripeProfile] | Sequence[StripeDescriptor],
        silhouettes: Sequence[Polygon],
        verifiers: Sequence[str] = DEFAULT_VERIFIERS,
        weights: Sequence[float] | None = None,
        stripe_weights: Sequence[float] | None = None,
        reliefs: Sequence[StripeRelief] | None = None,
    ) -> None:
        if len(descriptors) != len(silhouettes):
            raise UserError(f"silhouettes must hold one polygon per object: {len(silhouettes)} "
                            f"for {len(descriptors)} descriptors")
        if reliefs is not None and len(reliefs) != len(descriptors):
            raise UserError(f"reliefs must hold one relief per object: {len(reliefs)} "
                            f"for {len(descriptors)} descriptors")
        parts = 1 + (reliefs is not None) + len(verifiers)
        if weights is not None and len(weights) != parts:
            raise UserError(f"weights need {parts} values (stripes, "
                            f"{'the relief, ' if reliefs is not None else ''}then each "
                            f"verifier), got {len(weights)}")
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
        self.matchers = [verifier(n) for n in verifiers]
        self.verifier_names = tuple(verifiers)
        self.stacks = [m.stack([m.describe(p) for p in silhouettes]) for m in self.matchers]

    def __len__(self) -> int:
        return len(self.stripes)

    def method_distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None,
    ) -> list[Array]:
        """``(K,)`` distances of the stripes, the relief (when the database holds
        reliefs: then the query's `relief` is required), then each verifier, to every
        object."""
        if (relief is None) != (self.reliefs is None):
            raise UserError("give the query's relief exactly when the database holds "
                            "reliefs" if self.reliefs is not None else
                            "this database holds no reliefs; query without a relief")
        out = [self.stripes.distances(descriptor)]  # type: ignore[arg-type]
        if self.reliefs is not None and relief is not None:
            out.append(self.reliefs.distances(relief))
        for m, st in zip(self.matchers, self.stacks, strict=True):
            out.append(np.asarray(m.distances(m.describe(silhouette), st), dtype=float))
        return out

    def distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None,
    ) -> Array:
        """``(K,)`` fused distances of the query to every object (module docstring)."""
        return fuse(self.method_distances(descriptor, silhouette, relief), self.weights)

    def query(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon, k: int = 10,
        relief: StripeRelief | None = None,
    ) -> tuple[NDArray[np.int64], Array]:
        """Indices and fused distances of the `k` nearest objects, nearest first."""
        d = self.distances(descriptor, silhouette, relief)
        order = np.argsort(d, kind="stable")[:k]
        return order, d[order]
