"""Free-space consistency of two submaps at a relative pose: partial views are not punished.

Two passes through a place in different directions share only part of their
submaps: the overlap fraction of a true revisit can be as low as that of a wrong
place.  What tells them apart is where the points that do *not* overlap fall.  A
laser sees the space between its sensor and each return as free; a point of one
submap that lands in space the other submap observed as free contradicts the
match, one that lands where the other never looked (behind its walls, beyond its
range, outside its field of view) says nothing.

Free-space model (`RangeImage`): the submap's points, in its sensor frame [m] (the
keyframe's sensor at the origin), binned by bearing into `bins` sectors about the
origin; ``r(b)`` = the smallest range in sector b, then the minimum over the
``2 spread + 1`` neighbouring sectors that hold points (a wall seen at a grazing
angle, a sector edge, and a sector left empty between the points of a distant
wall), 0 when none does (nothing observed).  A point at range rho, bearing in sector b, lies in
observed free space when

    rho < r(b) - margin                                                            (1)

The smallest range of a submap merged from several scans is at most the keyframe's
own return in that direction, so (1) errs towards "not observed" (neutral).  But a
point another scan of the submap saw from elsewhere was observed along *that* scan's
ray, not along the ray from the keyframe's origin: (1) then also invents free space
(behind a corner or a door frame from the origin's side) and misses the free space
the other scans' rays crossed.  The per-scan model (`ScanFreeSpace`) keeps each scan
of the submap with its sensor pose ``s_k`` in the submap's frame, each scan's
`RangeImage` ``r_k`` made about its own origin from its own returns, and a point p
(submap frame) is in observed free space when some scan saw through it:

    exists k:  rho_k < r_k(b_k) - margin,   (rho_k, b_k) = polar (s_k^-1 p)      (1')

The margin of (1') is taken along the ray.  Where the ray meets the surface at an
incidence alpha from its normal, a point a distance d in front of the surface *across*
it lies d / cos(alpha) in front of it along the ray: two passes' walls a few
centimetres apart sideways are far apart along an oblique ray.  The surface margin
(`ScanFreeSpace` with ``surface_cap > 1``) measures the margin across the scan's local
surface instead.  In polar form ``r(theta)`` about the scan's origin the surface has

    1 / cos(alpha) = sqrt(1 + (r' / r)^2),   r' = dr / dtheta                    (3)

with r' the smaller of the two one-sided slopes of the sector ranges over
`SURFACE_STEP` sectors (a depth jump at an edge is not a slope; the continuous side
holds the surface), and (1') becomes

    rho_k < r_k(b_k) - margin min(cap, sqrt(1 + (r'_k / r_k)^2))                  (1'')

the cap bounding the along-ray margin of a surface seen at grazing incidence.

A point may also lie near a scan's returns without lying near the surface its ray
hits: the ray passes by a wall end, a door frame or a corner that the neighbouring
beams of the same scan saw.  The returns margin (`ScanFreeSpace` with
``return_window > 0``) keeps a point out of scan k's free space when it lies within
`margin`, in any direction, of a return of scan k in the `return_window` sectors
either side of its own:

    rho_k < r_k(b_k) - margin  and  min_{|j - b_k| <= w} |q_k - x_k(j)| >= margin   (4)

with ``q_k = s_k^-1 p`` and ``x_k(j)`` the point at range ``r_k(j)`` on the bearing
of sector j's centre (sectors that observed nothing hold none); with a surface cap
the first term is (1'')'s.  Only the scan's own
returns count, not the other scans' of its submap: a point is excused by the rays
that ended beside it, not by a surface some other scan saw.

The confirmed model (`ConfirmedFreeSpace`) asks both: a point is in observed free
space when (1) calls it free *and* some scan of the submap saw through it, (1') or
its variants (1''), (4):

    (1) and (1')                                                                   (5)

(1) alone invents free space along rays from the keyframe's origin that no scan cast
(behind a corner, a door frame, from the origin's side); (1') alone reaches as far
as every scan's longest ray, metres past the surfaces the keyframe itself saw, where
two passes' walls a few centimetres apart, seen obliquely, and the changes between
passes (a door, a person) lie.  (5) keeps the free space both agree on: the
keyframe's own neighbourhood up to the nearest surface of the merged submap in each
direction, and of it only what a real ray crossed.

Consistency (`consistency`) of the query submap Q (query frame) and the candidate
submap P (candidate frame) at the pose T of the query in the candidate's frame:
a point of Q is a *hit* when ``T q`` is within `tolerance` [m] of a point of P, a
*conflict* when it is no hit and ``T q`` lies in P's free space (1); the same for
the points of P at ``T^-1 p`` against Q.  Then

    consistency = hits / (hits + conflicts)                                        (2)

over both directions: the overlap normalised by the mutually visible part (points
neither submap could have seen count in neither term), and
``conflict_ratio = conflicts / (|Q| + |P|)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from data import se2

Array = NDArray[np.float64]
SURFACE_STEP = 4
"""Sectors over which (3) takes a one-sided slope of a scan's free ranges: twice the
default ``spread``.  A beam's return fills up to ``2 spread + 1`` sectors (the nearest
of the neighbouring sectors' returns), so an oblique wall's ranges are a staircase
whose neighbouring sectors often repeat one beam's range: a shorter step reads a
zero slope there."""
SCAN_FREE_SPACE = "scan_free_space"
"""Key of a registration target's ``derived`` cache holding its submap's
`ScanFreeSpace` (set by the loop detector's keyframe store)."""


class RangeImage:
    """The free space a submap observed, about its sensor origin (module docstring (1)).

    Attributes:
        ranges: ``(bins,)`` free range per bearing sector [m] (0: nothing observed);
            sector k covers bearings ``[-pi + k 2 pi / bins, -pi + (k + 1) 2 pi / bins)``.
    """

    __slots__ = ("bins", "ranges")

    def __init__(self, points: ArrayLike, bins: int = 720, spread: int = 2) -> None:
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        self.bins = int(bins)
        r = np.full(self.bins, np.inf)
        if len(pts):
            np.minimum.at(r, self._sector(pts), np.hypot(pts[:, 0], pts[:, 1]))
        out = r.copy()
        for k in range(1, spread + 1):
            out = np.minimum(out, np.minimum(np.roll(r, k), np.roll(r, -k)))
        out[~np.isfinite(out)] = 0.0
        self.ranges = out

    def _sector(self, pts: Array) -> NDArray[np.intp]:
        bearing = np.arctan2(pts[:, 1], pts[:, 0])
        return ((bearing + np.pi) * (self.bins / (2 * np.pi))).astype(np.intp) % self.bins

    def free(self, points: ArrayLike, margin: float) -> NDArray[np.bool_]:
        """``(N,)`` True where a point [m] (this submap's frame) lies in observed free
        space: closer than the sector's free range minus `margin` [m] (1)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(pts) == 0:
            return np.zeros(0, bool)
        return np.hypot(pts[:, 0], pts[:, 1]) < self.ranges[self._sector(pts)] - margin


class ScanFreeSpace:
    """The free space the scans of a submap observed, each about its own origin (1').

    Attributes:
        poses: ``(K, 3)`` sensor pose of each scan in the submap's frame [m, m, rad].
        ranges: ``(K, bins)`` each scan's free range per bearing sector about its own
            origin [m] (`RangeImage.ranges` of its returns in its sensor frame; 0:
            nothing observed), float32.
        bins: bearing sectors (`RangeImage`'s convention).
    """

    __slots__ = ("_secant", "bins", "poses", "ranges", "return_window", "surface_cap")

    def __init__(self, poses: ArrayLike, ranges: ArrayLike, surface_cap: float = 1.0,
                 return_window: int = 0) -> None:
        """`surface_cap`: 1, the margin along the ray (1'); above 1, across the scan's
        surface (1''), the along-ray margin at most `surface_cap` times `margin`.
        `return_window`: 0, off; else the sectors either side of a point's whose
        returns keep it out of that scan's free space within `margin` (4)."""
        self.poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        self.ranges = np.atleast_2d(np.asarray(ranges, dtype=np.float32))
        if len(self.ranges) != len(self.poses):
            raise ValueError(f"{len(self.poses)} scan poses but {len(self.ranges)} range rows")
        if not surface_cap >= 1.0:
            raise ValueError(f"surface_cap must be at least 1, got {surface_cap}")
        self.bins = self.ranges.shape[1]
        self.surface_cap = float(surface_cap)
        self.return_window = int(return_window)
        if self.return_window < 0:
            raise ValueError(f"return_window must be at least 0, got {return_window}")
        self._secant: NDArray[np.float32] | None = None

    @classmethod
    def of(cls, poses: ArrayLike, scans: list[ArrayLike], bins: int = 720,
           spread: int = 2) -> ScanFreeSpace:
        """From each scan's ``(M_k, 2)`` returns [m] (its own sensor frame) and its
        sensor pose ``(3,)`` in the submap's frame."""
        return cls(poses, np.array([RangeImage(s, bins, spread).ranges for s in scans],
                                   dtype=np.float32).reshape(-1, bins))

    @property
    def secant(self) -> NDArray[np.float32]:
        """``(K, bins)`` the factor of (1''): ``min(surface_cap, 1 / cos(alpha))`` by (3)
        per scan and sector; 1 where a sector or both its neighbours at `SURFACE_STEP`
        saw nothing (no surface to measure across)."""
        if self._secant is None:
            self._secant = surface_secant(self.ranges, self.surface_cap)
        return self._secant

    def free(self, points: ArrayLike, margin: float) -> NDArray[np.bool_]:
        """``(N,)`` True where a point [m] (the submap's frame) lies in the observed
        free space of any scan (1'), or (1'') with a `surface_cap` above 1: every
        scan's test at once, ``(K, N)``."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(pts) == 0 or len(self.poses) == 0:
            return np.zeros(len(pts), bool)
        x, y, th = self.poses.T
        c, s = np.cos(th)[:, None], np.sin(th)[:, None]
        dx = pts[None, :, 0] - x[:, None]
        dy = pts[None, :, 1] - y[:, None]
        u, v = c * dx + s * dy, c * dy - s * dx  # s_k^-1 p, (K, N)
        sector = ((np.arctan2(v, u) + np.pi) * (self.bins / (2 * np.pi))).astype(np.intp)
        sector %= self.bins
        free_range = np.take_along_axis(self.ranges, sector, axis=1)
        if self.surface_cap > 1.0:
            free_range = free_range - (margin * np.take_along_axis(self.secant, sector, axis=1))
            free = np.hypot(u, v) < free_range
        else:
            free = np.hypot(u, v) < free_range - margin
        if self.return_window > 0:
            self._beside_returns(free, u, v, sector, margin)
        return free.any(axis=0)

    def _beside_returns(self, free: NDArray[np.bool_], u: Array, v: Array,
                        sector: NDArray[np.intp], margin: float) -> None:
        """(4): clear ``free[k, n]`` where point n lies within `margin` [m] of a return
        of scan k in the `return_window` sectors either side of its own (in place)."""
        kk, nn = np.nonzero(free)
        if len(kk) == 0:
            return
        offsets = np.arange(-self.return_window, self.return_window + 1)
        near_sectors = (sector[kk, nn][:, None] + offsets) % self.bins  # (M, 2w + 1)
        r = self.ranges[kk[:, None], near_sectors].astype(float)
        bearing = -np.pi + (near_sectors + 0.5) * (2 * np.pi / self.bins)
        dx = r * np.cos(bearing) - u[kk, nn][:, None]
        dy = r * np.sin(bearing) - v[kk, nn][:, None]
        beside = ((dx * dx + dy * dy < margin * margin) & (r > 0)).any(axis=1)
        free[kk[beside], nn[beside]] = False

    @property
    def nbytes(self) -> int:
        """Memory held [bytes]."""
        return self.poses.nbytes + self.ranges.nbytes


class ConfirmedFreeSpace:
    """Free space both about the keyframe (1) and about some scan of the submap (1'):
    (5).  `image` and `scans` describe the same submap (its sensor frame)."""

    __slots__ = ("image", "scans")

    def __init__(self, image: RangeImage, scans: ScanFreeSpace) -> None:
        self.image = image
        self.scans = scans

    def free(self, points: ArrayLike, margin: float) -> NDArray[np.bool_]:
        """``(N,)`` True where a point [m] (the submap's frame) is free under (1) and
        under the scans' model; the scans' test runs on the points (1) calls free only."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        out = self.image.free(pts, margin)
        idx = np.flatnonzero(out)
        if len(idx):
            out[idx] = self.scans.free(pts[idx], margin)
        return out


def surface_secant(ranges: ArrayLike, cap: float, step: int = SURFACE_STEP) -> NDArray[np.float32]:
    """(3): ``min(cap, sqrt(1 + (r' / r)^2))`` for ``(K, bins)`` free ranges [m] per
    bearing sector (0: nothing observed), r' [m/rad] the smaller magnitude of the
    slopes to the sectors `step` before and after (a sector with nothing observed gives
    no slope; 1 where neither side gives one or the sector itself observed nothing)."""
    r = np.atleast_2d(np.asarray(ranges, dtype=np.float64))
    if r.size == 0:
        return np.ones(r.shape, np.float32)
    dtheta = step * 2 * np.pi / r.shape[1]
    slopes = []
    for side in (step, -step):
        other = np.roll(r, side, axis=1)
        slope = np.abs(r - other) / dtheta
        slopes.append(np.where(other > 0, slope, np.inf))
    slope = np.minimum(*slopes)
    seen = (r > 0) & np.isfinite(slope)
    out = np.ones(r.shape)
    out[seen] = np.minimum(cap, np.sqrt(1.0 + (slope[seen] / r[seen]) ** 2))
    return out.astype(np.float32)


@dataclass(slots=True)
class Consistency:
    """Figures of (2) at one pose.

    Attributes:
        consistency: hits / (hits + conflicts), both directions (0 with neither).
        conflict_ratio: conflicts / all points of both submaps.
        hits, conflicts: counts over both directions.
    """

    consistency: float
    conflict_ratio: float
    hits: int
    conflicts: int


class SubmapPoints(np.ndarray):
    """``(N, 2)`` points of a submap [m] (its sensor frame) carrying its scans' free
    space (1') as `free_space` (None: not known), so that the free space travels
    with the points to the check.  Views keep it; `numpy.asarray` drops it."""

    free_space: ScanFreeSpace | None

    def __new__(cls, points: ArrayLike, free_space: ScanFreeSpace | None) -> SubmapPoints:
        out = np.asarray(points, dtype=float).reshape(-1, 2).view(cls)
        out.free_space = free_space
        return out

    def __array_finalize__(self, obj: object) -> None:
        self.free_space = getattr(obj, "free_space", None)


@dataclass(slots=True)
class Submap:
    """A submap prepared for (2): points [m] in its sensor frame, KD-tree, free space
    ((1) about the sensor origin, or its scans' (1'))."""

    points: Array
    tree: cKDTree | None
    image: RangeImage | ScanFreeSpace | ConfirmedFreeSpace

    @classmethod
    def of(cls, points: ArrayLike, bins: int = 720, spread: int = 2,
           scans: ScanFreeSpace | None = None, confirm: bool = False) -> Submap:
        """Prepare ``(N, 2)`` points (its sensor frame [m]); free space (1) about the
        origin, or `scans`' (1') when given, or with `confirm` and `scans` both (5)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        image: RangeImage | ScanFreeSpace | ConfirmedFreeSpace
        if scans is None:
            image = RangeImage(pts, bins, spread)
        elif confirm:
            image = ConfirmedFreeSpace(RangeImage(pts, bins, spread), scans)
        else:
            image = scans
        return cls(pts, cKDTree(pts) if len(pts) else None, image)


def _one_way(moved: Array, other: Submap, tolerance: float, margin: float) -> tuple[int, int]:
    """Hits and conflicts of points `moved` into `other`'s frame."""
    if len(moved) == 0:
        return 0, 0
    if other.tree is None:
        return 0, 0
    dist, _ = other.tree.query(moved, k=1, distance_upper_bound=tolerance)
    hit = np.isfinite(dist)
    conflict = ~hit & other.image.free(moved, margin)
    return int(hit.sum()), int(conflict.sum())


def consistency(
    query: Submap, candidate: Submap, pose: ArrayLike, tolerance: float = 0.1,
    margin: float = 0.3,
) -> Consistency:
    """(2) for the pose ``(x, y, theta)`` [m, m, rad] of the query in the candidate's frame.

    Args:
        query: the query submap (query frame).
        candidate: the candidate submap (candidate frame).
        pose: the relative pose.
        tolerance: a point within this of the other submap's points is a hit [m].
        margin: free space ends this far before the observed range [m] (1).
    """
    t = np.asarray(pose, dtype=float).reshape(3)
    h1, c1 = _one_way(se2.transform_points(t, query.points), candidate, tolerance, margin)
    h2, c2 = _one_way(se2.transform_points(se2.inverse(t), candidate.points), query,
                      tolerance, margin)
    hits, conflicts = h1 + h2, c1 + c2
    total = len(query.points) + len(candidate.points)
    return Consistency(
        consistency=hits / (hits + conflicts) if hits + conflicts else 0.0,
        conflict_ratio=conflicts / total if total else 0.0,
        hits=hits, conflicts=conflicts,
    )
