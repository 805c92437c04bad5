"""Ring projection matcher: how much of each circle around the centroid lies inside.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for
place recognition" (``papers/shape-matching-place-recognition.txt``), Section II.A.6
("Ring Projection"), after its reference [19] (ring-projection transform; Tang, Cheng &
Suen, "Transformation-ring-projection (TRP) algorithm and its VLSI implementation",
1991).

Equations (plain text)
----------------------
With the origin moved to the polygon's area centroid and p(x, y) = 1 inside the
polygon, 0 outside, the ring projection of radius gamma is

    f(gamma) = integral_0^{2 pi} p(gamma cos theta, gamma sin theta) d theta     [rad]

(the paper's formula; its implementation sums arc lengths, gamma * f(gamma) [m]).
It is sampled on R rings

    gamma_i = (i + 1/2) * Delta,   Delta = max_radius / R,   i = 0 .. R-1,

and the descriptor is the vector of arc lengths (gamma_i f(gamma_i)), i = 0 .. R-1 [m]
(default, the paper's implementation), or with ``arc_length=False`` the fractions
f(gamma_i) / (2 pi) of each circle inside the polygon (dimensionless, in [0, 1]).
Two descriptors are compared with the Euclidean distance s(D_i, D_j) = ||D_i - D_j||_2
(default) or the L1 distance sum_i |D_i - D_j| (``norm="l1"``).  The paper gives no
distance for the ring projection (L1 is the one of its other region profile, scan
line).  L1 suits places within a few metres of the sensor: two views of one place
differ mostly in a few rings (those that cut the open space at the range cap, or a
door open in one view), a difference that L2 squares into the largest term.  When the
centroid itself moves between two views (far-reaching scans whose open space differs),
their difference is a radial shift of the profile, spread thinly over many rings,
which L2 forgives more.  The place database's ring stage is Euclidean (its vector
store), so the default stays L2.

Exact computation, vectorised.  The paper orders the intersections of each circle with
the polygon by angle and tests the midpoint of every arc.  We avoid the point-in-polygon
tests: where the boundary (counter-clockwise, interior on its left) crosses the circle
going outwards, the circle (traversed counter-clockwise) enters the polygon; going
inwards, it leaves it.  Hence

    f(gamma) = (sum over exits of theta - sum over entries of theta)  mod 2 pi

with theta in [0, 2 pi) the angle of each crossing; a circle without crossings is
wholly inside (f = 2 pi, when the centroid is inside the polygon and gamma is below its
distance to the boundary) or wholly outside (f = 0).  An edge p + u e, u in [0, 1),
meets the circle |x| = gamma where |e|^2 u^2 + 2 (p.e) u + |p|^2 - gamma^2 = 0; the root
u+ = (-p.e + sqrt(disc)) / |e|^2 is the outward crossing (entry), u- the inward one
(exit).  Only the (edge, ring) pairs whose radius lies between the edge's nearest and
farthest distance from the centroid are solved (``np.repeat`` over the rings each edge
spans), so the cost is O(N + crossings), not O(R N), and there is no sampling error.

Parameters (`RingConfig`)
-------------------------
- ``n_rings`` R = 32: number of circles (0.625 m apart for max_radius 20 m; a place
  within 5 m of the sensor then spans only about 9 of them, and 64, about the
  displacement between two views of one place apart, resolve it better); a query costs
  O(R) per stored profile.
- ``max_radius`` = 20.0 m: radius of the outermost ring (places; rooms 2-30 m, the scan
  polygon is capped at 30 m, and the far field is the least repeatable part of a scan
  taken from a displaced position).  Unused when scale invariant, which pixel-unit
  shape sets such as MPEG-7 need.
- ``scale_invariant`` = False: when True the rings span the polygon's own extent,
  max_radius = the largest centroid-to-vertex distance, and arc lengths are divided by
  it (so the descriptor does not change with scale); for MPEG-7.
- ``norm`` = "l2": Euclidean distance, because ring projection is a prefilter: a query
  against the whole database is one float32 matrix-vector product with precomputed
  norms (||q||^2 + ||x||^2 - 2 q.x).  "l1" (see above) needs a full |x - q| pass over
  the database instead.
- ``arc_length`` = True: the profile is the arc length gamma * f(gamma) [m] (the
  paper's implementation); False gives the fraction f / (2 pi), which weighs every ring
  equally.  Arc lengths weigh the outer rings more.
- ``near_radius`` = None [m]: when set, the profile is that of the polygon as seen
  within this distance of the sensor origin (`loopclosure.polygon.polygon_within`:
  every farther vertex pulled in along its ray), its centroid included.  On 30 m
  virtual scans the far field (open space at the cap, walls seen from only some of the
  local maps' paths) dominates the area: the centroid moves metres between two views
  of one place, a radial shift of the whole profile.  Within a few metres of the
  sensor it moves centimetres, and the rings beyond the near field are all zero (the
  fraction then weighs the near rings' differences as much as the arc length would
  the outer ones').  Unused when scale invariant.

Departures from the paper
-------------------------
- Crossings are combined by the entry/exit angle sum above instead of midpoint
  point-in-polygon tests; the result is the same measure, exactly.
- Rotation invariance is exact: a rotation (about any point) moves the centroid with
  the polygon and leaves each f(gamma) unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.matchers.vector_search import VectorStack, stack_distances, stack_vectors
from loopclosure.polygon import Polygon, polygon_within

Array = NDArray[np.float64]

_TWO_PI = 2.0 * np.pi


@dataclass(slots=True, frozen=True)
class RingConfig:
    """Parameters of the ring projection matcher (see module docstring).

    Attributes:
        n_rings: number R of circles.
        max_radius: radius of the outermost circle [m] (ignored when scale invariant).
        scale_invariant: rings span the polygon's largest centroid distance.
        arc_length: profile in metres of arc (gamma f) instead of the fraction inside.
        norm: ``"l2"`` (Euclidean, default) or ``"l1"``.
        near_radius: describe the polygon within this distance of the sensor [m]
            (None: the whole polygon).
    """

    n_rings: int = 32
    max_radius: float = 20.0
    scale_invariant: bool = False
    arc_length: bool = True
    norm: str = "l2"
    near_radius: float | None = None

    def __post_init__(self) -> None:
        if self.near_radius is not None and not (
            np.isfinite(self.near_radius) and self.near_radius > 0
        ):
            raise UserError(f"near_radius must be a positive length [m], got {self.near_radius}")
        if self.norm not in ("l1", "l2"):
            raise UserError(f"norm must be 'l1' or 'l2', got {self.norm!r}")
        if self.n_rings < 1:
            raise UserError(f"n_rings must be >= 1, got {self.n_rings}")
        if not (np.isfinite(self.max_radius) and self.max_radius > 0):
            raise UserError(f"max_radius must be a positive length [m], got {self.max_radius}")


RingStack = VectorStack
"""Ring profiles packed for `RingProjectionMatcher.distances`: ``matrix`` ``(M, R)``
float32 profiles and ``sqnorms`` ``(M,)`` their squared norms (`vector_search.VectorStack`)."""


def ring_profile(vertices: Array, centre: Array, radii_step: float, n_rings: int) -> Array:
    """``(n_rings,)`` angle [rad] of each circle ``gamma_i = (i + 1/2) radii_step`` inside.

    `vertices` ``(N, 2)`` is a counter-clockwise polygon [m], `centre` ``(2,)`` the circles'
    centre [m].  Exact up to floating point (see module docstring).
    """
    v = np.asarray(vertices, dtype=float)
    closed = np.concatenate([v, v[:1]]) - centre
    return _profile_closed(closed, float(radii_step), int(n_rings))


def _profile_closed(closed: Array, step: float, n_rings: int) -> Array:
    p = closed[:-1]
    e = closed[1:] - p
    px, py, ex, ey = p[:, 0], p[:, 1], e[:, 0], e[:, 1]
    ee = ex * ex + ey * ey
    pe = px * ex + py * ey
    pp = px * px + py * py
    # Nearest and farthest distance of each edge (segment) from the centre.
    u_near = np.clip(-pe / ee, 0.0, 1.0)
    dmin = np.sqrt(np.maximum(pp + u_near * (2.0 * pe + u_near * ee), 0.0))
    dmax = np.sqrt(np.maximum(pp, pp + 2.0 * pe + ee))
    # Rings each edge can cross: gamma_i in [dmin, dmax].
    lo = np.maximum(np.ceil(dmin * (1.0 / step) - 0.5), 0.0).astype(np.int64)
    hi = np.minimum(np.floor(dmax * (1.0 / step) - 0.5), n_rings - 1).astype(np.int64)
    counts = np.maximum(hi - lo + 1, 0)
    total = int(counts.sum())
    f = np.zeros(n_rings)
    if total:
        edge = np.arange(len(p)).repeat(counts)
        ring = np.arange(total) - (counts.cumsum() - counts - lo).repeat(counts)
        g = (ring + 0.5) * step
        inv = 1.0 / ee[edge]
        mid = -pe[edge] * inv
        # Half-chord in u; 0 where the line misses the circle: both "roots" then fall on
        # the same point with opposite signs and cancel, as tangent contacts do.
        half = np.sqrt(np.maximum(mid * mid - (pp[edge] - g * g) * inv, 0.0))
        u = np.stack([mid + half, mid - half])  # row 0: outward (entry), row 1: inward (exit)
        side, j = np.nonzero((u >= 0.0) & (u < 1.0))
        k = edge[j]
        uj = u[side, j]
        theta = np.arctan2(py[k] + uj * ey[k], px[k] + uj * ex[k])
        # Exits add their angle, entries subtract it; any 2 pi branch cancels in the mod.
        f = np.bincount(ring[j], theta * (2.0 * side - 1.0), n_rings) % _TWO_PI
    # Rings below the nearest or beyond the farthest boundary point cross nothing: they
    # are wholly inside (centre inside the polygon) or wholly outside.
    gam = (np.arange(n_rings) + 0.5) * step
    below = gam < dmin.min()
    if below.any():
        phi = np.arctan2(closed[:, 1], closed[:, 0])
        sweep = phi[1:] - phi[:-1]
        sweep -= _TWO_PI * np.rint(sweep / _TWO_PI)
        f[below] = _TWO_PI if abs(sweep.sum()) > np.pi else 0.0
    f[gam > dmax.max()] = 0.0
    return f


class RingProjectionMatcher(Matcher):
    """Fraction of each circle around the centroid inside the polygon; Euclidean distance."""

    name = "ring"
    rotation_invariant = True

    def __init__(self, config: RingConfig | None = None, **overrides: Any) -> None:
        cfg = config or RingConfig()
        known = {f.name for f in fields(RingConfig)}
        unknown = set(overrides) - known
        if unknown:
            raise UserError(
                f"unknown RingConfig fields: {', '.join(sorted(unknown))} "
                f"(known: {', '.join(sorted(known))})"
            )
        self.config = replace(cfg, **overrides)

    def describe(self, polygon: Polygon) -> NDArray[np.float32]:
        """``(R,)`` float32 ring profile (fraction inside, or arc length [m])."""
        cfg = self.config
        if cfg.near_radius is not None and not cfg.scale_invariant:
            polygon = polygon_within(polygon, cfg.near_radius)
        v = polygon.vertices
        closed = np.concatenate([v, v[:1]])
        x0, y0, x1, y1 = closed[:-1, 0], closed[:-1, 1], closed[1:, 0], closed[1:, 1]
        cross = x0 * y1 - x1 * y0
        centre = np.array([(x0 + x1) @ cross, (y0 + y1) @ cross]) / (3.0 * cross.sum())
        closed -= centre
        if cfg.scale_invariant:
            extent = float(np.sqrt((closed * closed).sum(axis=1).max()))
            step = extent / cfg.n_rings
        else:
            step = cfg.max_radius / cfg.n_rings
        f = _profile_closed(closed, step, cfg.n_rings)
        if cfg.arc_length:
            prof = f * ((np.arange(cfg.n_rings) + 0.5) * step)
            if cfg.scale_invariant:
                prof /= step * cfg.n_rings
        else:
            prof = f * (1.0 / _TWO_PI)
        return prof.astype(np.float32)

    def stack(self, descriptors: Sequence[NDArray[np.float32]]) -> RingStack:
        """``(M, R)`` float32 matrix of profiles and its row norms."""
        return stack_vectors(descriptors, self.config.n_rings)

    def distances(self, query: NDArray[np.float32], stacked: RingStack) -> Array:
        """``(M,)`` Euclidean (or L1) distances of the query profile to every stacked profile."""
        q = np.asarray(query, np.float32)
        if self.config.norm == "l1":
            diff = stacked.matrix.astype(np.float64)
            diff -= q
            return np.abs(diff, out=diff).sum(axis=1)
        return stack_distances(q, stacked)

    def distance(self, a: NDArray[np.float32], b: NDArray[np.float32]) -> float:
        """Distance of two profiles (same arithmetic as `distances`)."""
        return float(self.distances(a, self.stack([b]))[0])
