"""Fused object matching: the stripe distance verified by silhouette matchers.

Paper: "Stripes-based Object Matching", Section VI.B ("a proper combination of shape
descriptors and the proposed stripe descriptor can improve the matching accuracy
over the individual descriptor"); the paper gives no rule, so the rule here is the
place cascade's idea without learnt weights, which keeps it free of any data set:

- every method ``k`` gives, for one query, distances ``D_k(j)`` to the database
  objects ``j`` (the stripes' Eq. 5, a silhouette matcher's own distance);
- each is made unitless, so methods with different units and spreads add up, by one
  of two rules (`fuse`'s ``scaling``):

  - ``"local"`` (local scaling, the self-tuning affinity of Zelnik-Manor & Perona,
    "Self-Tuning Spectral Clustering", NIPS 2004): ``D_k(q, j) / sqrt(s_k(q)
    s_k(j))``, where ``s_k(x)`` is object ``x``'s distance to its ``n``-th nearest
    neighbour in the database under method ``k`` (``n`` = `LOCAL_NEIGHBOUR`, 5;
    zero distances, i.e. the object itself when it is in the database, are not
    neighbours; `neighbour_scale`).  A score of 1 means "as far as the two objects'
    own typical near neighbours": an object in a dense part of a method's space
    (many look-alikes) needs a smaller distance to count as near than one in a
    sparse part, so no method's crowded regions dominate the sum (`local_scaled`);
  - ``"median"``: ``D_k(q, j) / median_j D_k(q, j)``, 1 being a typical object for
    this query and method (`normalised`); one scale per query, none per database
    object;

  both are invariant to multiplying one method's distances by a constant;
- the fused distance is a weighted mean of the scores (`fuse`'s ``mean``), equal
  weights by default:

  - ``"geometric"`` (the fused matcher's rule, `DEFAULT_MEAN`): ``exp(sum_k w_k
    log max(score_k, GEOMETRIC_FLOOR))``, 0 where every score is 0 (the object
    itself).  Each part counts by *ratios*: one part
    that finds the true object twice as near as a look-alike outweighs another that
    finds the look-alike twice as near, whatever the two parts' absolute spreads.
    Scaled scores of far objects spread much more in some parts than in others
    (shape context's outline distances, the relief's flat-top crowd), and in an
    arithmetic mean the part with the widest spread at the query's candidates decides
    alone (a rectangular can taken for a wooden block by the outline, against the
    profile, relief and surface context); the logarithm takes that leverage away.
    With local scaling the query's own ``s_k(q)`` is one factor per query and drops
    out of its ranking; the database objects' ``s_k(j)`` stay;
  - ``"arithmetic"``: ``sum_k w_k score_k`` (the earlier rule, `fuse`'s default).

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
locally scaled, their geometric mean with equal weights.  Each part reads what the others
miss: the profile where along its length the object is tall, round or flat (blind
to the outline once resampled); the relief how deep the surface falls below the top
(flat box tops against studded bricks, lids, domes and hollows); the surface context
how the parts lie relative to each other in 3D (a cup's rim over its bottom, a
bottle's cap over its shoulders); shape context the footprint's outline (blind to
height).  Give `reliefs` and `surfaces` for it; without them the fusion is the
profile and the verifiers.  FFT and ring projection (`FAST_VERIFIERS`) are the
microsecond alternative to shape context.  `canonical.CanonicalDatabase` (the
canonical profile: the height map cut into virtual stripes along the footprint's
long axis, independent of the scan direction, which the stripe profile is not) is a
further stripe-side part (``canonicals``).  The matcher that reads nothing but the
stripes (``fused-stripes`` in ``bench stripes``) is profile, relief, surface context
and canonical profile, locally scaled, without verifiers (``verifiers=()``).

Why local scaling: one median per query treats every database object alike, so a
part whose distances are small for a whole crowd of look-alikes (boxes under the
relief, round fruit under the outline) outvotes the others there; dividing by both
objects' own neighbour distances makes each part's "near" relative to the density
of its space around the two objects, as self-tuning spectral clustering does.

Local scaling needs each database object's own ``s_k(j)``: `FusedObjectDatabase`
computes every part's distances among its objects once, when it is built (all pairs:
quadratic in the database, the cost of one full distance matrix per part).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.matchers import get_matcher
from loopclosure.polygon import Polygon
from loopclosure.stripes.canonical import CanonicalDatabase, CanonicalProfile
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
#: Rules that make each part's distances unitless before the fusion (module docstring).
SCALINGS: tuple[str, ...] = ("local", "median")
#: The fused matcher's rule.
DEFAULT_SCALING = "local"
#: How the unitless parts are averaged (module docstring).
MEANS: tuple[str, ...] = ("arithmetic", "geometric")
#: The fused matcher's mean.
DEFAULT_MEAN = "geometric"
#: Smallest score the geometric mean takes the logarithm of [unitless]: one part's
#: evidence is at most a factor 100 nearer than a typical neighbour, so two
#: descriptions equal in one part (flat tops under the relief) do not zero the product
#: whatever the other parts say.
GEOMETRIC_FLOOR = 0.01
#: Neighbour rank ``n`` of local scaling: ``s(x)`` is the distance to the n-th nearest.
LOCAL_NEIGHBOUR = 5
#: A distance at most this fraction of its row's largest finite distance is zero (the
#: object itself; float noise of a matcher that compares an outline with itself).
ZERO_FRACTION = 1e-9


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


def _finite_or_twice_top(d: Array) -> Array:
    """Infinite (or NaN) entries -> twice the largest finite value of their row (1 if none)."""
    top = np.max(np.where(np.isfinite(d), d, -np.inf), axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 1.0)
    return np.where(np.isfinite(d), d, 2.0 * top)


def neighbour_scale(distances: ArrayLike, neighbour: int = LOCAL_NEIGHBOUR) -> Array:
    """``s``: each row's distance to its `neighbour`-th nearest neighbour (local scaling).

    `distances` ``(..., M)``: one row per object (a query against the database, or a
    database object against all of them), in the method's own unit; ``s`` has the
    row's unit, shape ``(...,)``.  Distances of at most `ZERO_FRACTION` times the row's
    largest finite distance (the object itself when it is in the database) and
    infinite ones are not neighbours; when fewer than `neighbour` remain, the largest
    of them; when none remain, 1.

    Raises:
        UserError: `neighbour` below 1, a negative distance, no distance at all.
    """
    if neighbour < 1:
        raise UserError(f"local scaling's neighbour must be at least 1, got {neighbour}")
    d = np.array(distances, dtype=float)
    if d.ndim == 0 or d.shape[-1] == 0:
        raise UserError("neighbour_scale needs at least one distance per object")
    if np.any(d < 0):
        raise UserError("distances must be non-negative")
    finite = np.isfinite(d)
    top = np.max(np.where(finite, d, 0.0), axis=-1, keepdims=True)
    ok = finite & (d > ZERO_FRACTION * top)
    cand = np.where(ok, d, np.inf)
    k = min(neighbour, d.shape[-1]) - 1
    s = np.partition(cand, k, axis=-1)[..., k]
    largest = np.max(np.where(ok, d, -np.inf), axis=-1)
    s = np.where(np.isfinite(s), s, largest)
    return np.where(np.isfinite(s) & (s > 0), s, 1.0)


def database_scales(pairwise: ArrayLike, neighbour: int = LOCAL_NEIGHBOUR) -> Array:
    """``(M,)`` `neighbour_scale` of every database object from the database's ``(M, M)``
    distances (row j = object j against all; the diagonal, j itself, is skipped)."""
    d = np.array(pairwise, dtype=float)
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise UserError(f"a database's own distances must be square, got shape {d.shape}")
    np.fill_diagonal(d, 0.0)
    return neighbour_scale(d, neighbour)


def local_scaled(
    distances: ArrayLike, database_scale: ArrayLike, neighbour: int = LOCAL_NEIGHBOUR
) -> Array:
    """``D(q, j) / sqrt(s(q) s(j))`` (module docstring), unitless, >= 0, finite.

    Args:
        distances: ``(M,)`` one query's, or ``(R, M)`` R queries', distances to the M
            database objects, in the method's unit.
        database_scale: ``(M,)`` the database objects' ``s(j)`` (`database_scales`).
        neighbour: ``n`` of ``s(q)`` (`neighbour_scale` of each query's row).

    Infinite distances become twice the row's largest finite score.
    """
    d = np.array(distances, dtype=float)
    sj = np.asarray(database_scale, dtype=float)
    if d.ndim == 0 or d.shape[-1] != sj.shape[-1] or sj.ndim != 1:
        raise UserError(f"distances of shape {d.shape} do not fit {sj.shape} database scales")
    sq = neighbour_scale(d, neighbour)
    return _finite_or_twice_top(d / np.sqrt(sq[..., None] * sj))


def scaled(
    distances: ArrayLike, scaling: str = "median", database: ArrayLike | None = None,
    neighbour: int = LOCAL_NEIGHBOUR,
) -> Array:
    """One method's distances made unitless by `scaling` (``"local"`` or ``"median"``).

    For ``"local"``, `database` is the database's own ``(M, M)`` distances under the
    same method (the scales ``s(j)``); None when `distances` is that matrix itself
    (every database object as a query: the benchmark's all-pairs case).
    """
    if scaling == "median":
        return normalised(distances)
    if scaling != "local":
        raise UserError(f"unknown scaling {scaling!r}; known: {', '.join(SCALINGS)}")
    d = np.asarray(distances, dtype=float)
    own = d if database is None else np.asarray(database, dtype=float)
    if own.ndim != 2 or own.shape[0] != own.shape[1]:
        raise UserError("local scaling needs the database's own (M, M) distances")
    return local_scaled(d, database_scales(own, neighbour), neighbour)


def fuse(
    parts: Sequence[ArrayLike], weights: Sequence[float] | None = None,
    scaling: str = "median", databases: Sequence[ArrayLike | None] | None = None,
    neighbour: int = LOCAL_NEIGHBOUR, mean: str = "arithmetic",
) -> Array:
    """Weighted `mean` (``"arithmetic"`` or ``"geometric"``, `combine`) of several
    methods' distances (same shape each), each made unitless by `scaling` (`scaled`;
    ``"median"``: `normalised`; ``"local"``: `local_scaled`, with `databases` the
    database's own distances per method, or None when the parts are the database's
    all-pairs matrices themselves)."""
    if not parts:
        raise UserError("fuse needs at least one method's distances")
    if scaling not in SCALINGS:
        raise UserError(f"unknown scaling {scaling!r}; known: {', '.join(SCALINGS)}")
    _check_mean(mean)
    shapes = [np.shape(p) for p in parts]
    if any(sh != shapes[0] for sh in shapes):
        raise UserError(f"every method's distances must have one shape, got {shapes}")
    own = [None] * len(parts) if databases is None else list(databases)
    if len(own) != len(parts):
        raise UserError(f"databases must hold one matrix per method: {len(own)} for "
                        f"{len(parts)}")
    arrays = [scaled(p, scaling, o, neighbour) for p, o in zip(parts, own, strict=True)]
    return combine(arrays, _fusion_weights(weights, len(arrays)), mean)


def _check_mean(mean: str) -> None:
    if mean not in MEANS:
        raise UserError(f"unknown mean {mean!r}; known: {', '.join(MEANS)}")


def combine(scores: Sequence[Array], weights: Array, mean: str = DEFAULT_MEAN) -> Array:
    """The weighted `mean` of unitless scores (same shape each; `weights` summing to 1):
    ``"arithmetic"``: ``sum_k w_k score_k``; ``"geometric"``: ``exp(sum_k w_k log
    max(score_k, GEOMETRIC_FLOOR))``, 0 where every score is 0 (module docstring)."""
    _check_mean(mean)
    if mean == "arithmetic":
        return sum(wi * a for wi, a in zip(weights, scores, strict=True))
    logs = sum(wi * np.log(np.maximum(a, GEOMETRIC_FLOOR))
               for wi, a in zip(weights, scores, strict=True))
    zero = np.logical_and.reduce([np.asarray(a) == 0 for a in scores])
    return np.where(zero, 0.0, np.exp(logs))


def _fusion_weights(weights: Sequence[float] | None, parts: int) -> Array:
    """`weights` (None: equal) checked and divided by their sum."""
    w = np.ones(parts) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (parts,) or np.any(w < 0) or not w.sum() > 0:
        raise UserError(f"weights must be {parts} non-negative values, not all zero")
    return w / w.sum()


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
            given), the surface context (when `surfaces` is given), the canonical
            profile (when `canonicals` is given), then each verifier (None: equal).
        stripe_weights: Eq. 5 weights of the stripe distance (`StripeDescriptor`s only).
        reliefs: one `StripeRelief` per object (same order), or None: no relief part.
        surfaces: one `StripeSurface` per object (same order), or None: no surface part.
        canonicals: one `CanonicalProfile` per object (same order), or None: no
            canonical-profile part.
        scaling: ``"local"`` (default) or ``"median"`` (module docstring).
        neighbour: ``n`` of local scaling (`LOCAL_NEIGHBOUR`).
        mean: ``"geometric"`` (default) or ``"arithmetic"`` (module docstring).

    With ``scaling="local"`` the constructor computes every part's distances among the
    objects (all pairs, once) for the database scales ``s_k(j)``.
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
        canonicals: Sequence[CanonicalProfile] | None = None,
        scaling: str = DEFAULT_SCALING,
        neighbour: int = LOCAL_NEIGHBOUR,
        mean: str = DEFAULT_MEAN,
    ) -> None:
        if len(descriptors) != len(silhouettes):
            raise UserError(f"silhouettes must hold one polygon per object: {len(silhouettes)} "
                            f"for {len(descriptors)} descriptors")
        for what, items in (("reliefs", reliefs), ("surfaces", surfaces),
                            ("canonicals", canonicals)):
            if items is not None and len(items) != len(descriptors):
                raise UserError(f"{what} must hold one per object: {len(items)} "
                                f"for {len(descriptors)} descriptors")
        if scaling not in SCALINGS:
            raise UserError(f"unknown scaling {scaling!r}; known: {', '.join(SCALINGS)}")
        if neighbour < 1:
            raise UserError(f"local scaling's neighbour must be at least 1, got {neighbour}")
        _check_mean(mean)
        parts = (1 + (reliefs is not None) + (surfaces is not None) + (canonicals is not None)
                 + len(verifiers))
        if weights is not None and len(weights) != parts:
            raise UserError(f"weights need {parts} values (stripes, "
                            f"{'the relief, ' if reliefs is not None else ''}"
                            f"{'the surface context, ' if surfaces is not None else ''}"
                            f"{'the canonical profile, ' if canonicals is not None else ''}"
                            f"then each verifier), got {len(weights)}")
        self.stripes: ProfileDatabase | StripeDatabase
        if descriptors and all(isinstance(d, StripeProfile) for d in descriptors):
            if stripe_weights is not None:
                raise UserError("stripe_weights apply to StripeDescriptors, not profiles")
            self.stripes = ProfileDatabase(descriptors)  # type: ignore[arg-type]
        else:
            self.stripes = (StripeDatabase(descriptors) if stripe_weights is None  # type: ignore[arg-type]
                            else StripeDatabase(descriptors, stripe_weights))  # type: ignore[arg-type]
        self.weights = None if weights is None else tuple(float(w) for w in weights)
        self._w = _fusion_weights(weights, parts)
        self.reliefs = None if reliefs is None else ReliefDatabase(reliefs)
        self.surfaces = None if surfaces is None else SurfaceDatabase(surfaces)
        self.canonicals = None if canonicals is None else CanonicalDatabase(canonicals)
        self.matchers = [verifier(n) for n in verifiers]
        self.verifier_names = tuple(verifiers)
        self.scaling = scaling
        self.neighbour = int(neighbour)
        self.mean = mean
        described = [[m.describe(p) for p in silhouettes] for m in self.matchers]
        self.stacks = [m.stack(ds) for m, ds in zip(self.matchers, described, strict=True)]
        #: ``s_k(j)`` per part (module docstring), None with median scaling.
        self.scales: list[Array] | None = None
        if scaling == "local" and len(self) > 0:
            own = [self.stripes.pairwise()]
            own += [db.pairwise() for db in (self.reliefs, self.surfaces, self.canonicals)
                    if db is not None]
            own += [np.asarray(m.pairwise(ds), dtype=float)
                    for m, ds in zip(self.matchers, described, strict=True)]
            self.scales = [database_scales(d, self.neighbour) for d in own]

    def __len__(self) -> int:
        return len(self.stripes)

    def method_distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
        canonical: CanonicalProfile | None = None,
    ) -> list[Array]:
        """``(K,)`` distances of the stripes, the relief, the surface context, the
        canonical profile (each when the database holds them: then the query's is
        required), then each verifier, to every object; each in its method's unit."""
        for what, mine, theirs in (("relief", relief, self.reliefs),
                                   ("surface context", surface, self.surfaces),
                                   ("canonical profile", canonical, self.canonicals)):
            if (mine is None) != (theirs is None):
                raise UserError(f"give the query's {what} exactly when the database holds "
                                f"{what}s" if theirs is not None else
                                f"this database holds no {what}s; query without one")
        out = [self.stripes.distances(descriptor)]  # type: ignore[arg-type]
        if self.reliefs is not None and relief is not None:
            out.append(self.reliefs.distances(relief))
        if self.surfaces is not None and surface is not None:
            out.append(self.surfaces.distances(surface))
        if self.canonicals is not None and canonical is not None:
            out.append(self.canonicals.distances(canonical))
        for m, st in zip(self.matchers, self.stacks, strict=True):
            out.append(np.asarray(m.distances(m.describe(silhouette), st), dtype=float))
        return out

    def scaled_distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
        canonical: CanonicalProfile | None = None,
    ) -> list[Array]:
        """`method_distances` made unitless by the database's `scaling` (module
        docstring): the parts the fusion averages."""
        parts = self.method_distances(descriptor, silhouette, relief, surface, canonical)
        if self.scales is None:
            return [normalised(p) for p in parts]
        return [local_scaled(p, s, self.neighbour)
                for p, s in zip(parts, self.scales, strict=True)]

    def distances(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
        canonical: CanonicalProfile | None = None,
    ) -> Array:
        """``(K,)`` fused distances of the query to every object (module docstring)."""
        parts = self.scaled_distances(descriptor, silhouette, relief, surface, canonical)
        return combine(parts, self._w, self.mean)

    def query(
        self, descriptor: StripeProfile | StripeDescriptor, silhouette: Polygon, k: int = 10,
        relief: StripeRelief | None = None, surface: StripeSurface | None = None,
        canonical: CanonicalProfile | None = None,
    ) -> tuple[NDArray[np.int64], Array]:
        """Indices and fused distances of the `k` nearest objects, nearest first."""
        d = self.distances(descriptor, silhouette, relief, surface, canonical)
        order = np.argsort(d, kind="stable")[:k]
        return order, d[order]
