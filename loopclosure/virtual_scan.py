"""360-degree virtual scans of a local map, for keyframes of sensors that see less.

A place recogniser compares full-circle polygons (`loopclosure.polygon`), but a SICK
LMS sees 180 degrees.  The SLAM pipeline therefore describes each keyframe by a
*virtual* scan: the scan a 360-degree sensor at the keyframe pose would have read
in the local map (the keyframe's scan plus its neighbours' scans, registered).

Frames and units: the keyframe's sensor frame, x forward, counter-clockwise
angles [rad], metres.  Beams: ``N`` bearings from ``-pi`` to ``pi - 2 pi / N`` in
steps of ``2 pi / N`` (the 360-degree layout of `data.raycast.LaserModel`).
Output: a `data.types.Scan` with ``max_range`` as the no-return reading, so
`loopclosure.polygon.polygon_from_scan` closes it without the origin vertex.

From map points (`virtual_scan`)
--------------------------------
Map points ``(M, 2)`` in the keyframe's sensor frame; points closer than
`min_range`, at or beyond `max_range`, or not finite are dropped.

1. **Candidates.**  A point at range ``r`` and bearing ``phi`` is a candidate of
   beam ``j`` (bearing ``a_j``) when it lies in the beam's angular bin
   (``|a_j - phi| <= step / 2``) *or* within `lateral_tol` of the beam's ray
   (``r |sin(a_j - phi)| <= lateral_tol``): the bin catches sparse far points, the
   tolerance the dense near ones.  Its distance along the beam is
   ``r cos(a_j - phi)``.
2. **Front-most surface.**  On each side of the beam (counter-clockwise /
   clockwise of it) the candidate with the smallest along-beam distance is kept.
3. **Range.**  When both sides have one and the two points are at most
   `link_dist` apart, they are taken to lie on one surface and the range is where
   the beam crosses the segment joining them (exact for a planar wall).  When they
   are farther apart they belong to two surfaces and the beam passes the edge of
   one of them: the point nearer to the beam in bearing gives the range (its
   along-beam distance).  With one side only, that side's point gives it.
4. **Gaps.**  A beam without candidates between two beams with returns is filled
   when the angular gap is at most `max_gap_deg` and the two neighbouring end
   points are at most `link_dist` apart: its range is where it crosses the segment
   joining them.  Larger gaps (or depth jumps) are no-return beams (`max_range`).

Everything is vectorised: points are expanded to their candidate beams with
`np.repeat`, the per-(beam, side) minimum found with one `np.lexsort`.

From the scans themselves (`virtual_scan_from_scans`)
-----------------------------------------------------
When the local map is still a set of scans, each scan's consecutive returns
(neighbouring beams, both valid) at most `link_dist` apart are joined into wall
segments, and the virtual beams are ray-cast exactly against all segments
(`data.raycast.trace`, vectorised); segments passing within `min_range` of the
virtual sensor are dropped.  Returns without a linked neighbour (mostly samples
of surfaces seen at grazing incidence, whose range along a nearby beam is
ill-defined) are left out.  This blocks the view through sparse surfaces and
keeps object edges where the scans saw them, so far fewer ranges come out too
short than with `virtual_scan` on the same points.

From an occupancy grid (`virtual_scan_from_grid`)
-------------------------------------------------
Each beam is marched exactly through the grid cells it crosses (its crossings
with the vertical and the horizontal grid lines, merged and sorted per beam, all
beams at once).  The first *occupied* cell (``grid.occupied()``) whose exit lies
beyond `min_range` stops the beam.  A wall in a grid is a band of occupied cells
one or two cells thick (range noise, discretisation), so the range is the middle
of the run of consecutive occupied cells the beam crosses from there, counted at
most two cells deep (a beam grazing along a wall would otherwise run on).  Unlike
the first cell's centre, the middle of the run is not biased towards the sensor
and errs by a fraction of a cell.  Unknown and
free cells do not stop a beam; a beam that leaves the grid or reaches
`max_range` is a no-return.  The grid is anything with ``resolution`` [m],
``origin`` (lower-left corner of cell (0, 0) in the map frame [m]) and
``occupied() -> (H, W) bool`` with row 0 at the smallest y, such as
`slam.occupancy_map.OccupancyGrid`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError, warn
from data.raycast import trace
from data.types import Scan

Array = NDArray[np.float64]


class GridLike(Protocol):
    """What `virtual_scan_from_grid` needs of an occupancy grid (module docstring)."""

    resolution: float
    origin: Array

    def occupied(self) -> NDArray[np.bool_]: ...


@dataclass(frozen=True, slots=True)
class VirtualScanConfig:
    """Parameters of `virtual_scan` (see module docstring); ``asdict`` gives its kwargs.

    Attributes:
        beams: number of beams over 360 degrees.
        max_range: no-return reading; points at or beyond it are ignored [m].
        lateral_tol: a point within this distance of a beam's ray is a candidate [m].
        min_range: points closer than this to the sensor are ignored [m].
        link_dist: two points at most this far apart are one surface [m].
        max_gap_deg: widest angular gap filled between two returns [deg].
    """

    beams: int = 360
    max_range: float = 30.0
    lateral_tol: float = 0.05
    min_range: float = 0.05
    link_dist: float = 0.5
    max_gap_deg: float = 5.0

    def kwargs(self) -> dict[str, Any]:
        """The parameters as keyword arguments of `virtual_scan`."""
        return asdict(self)


def virtual_angles(beams: int) -> Array:
    """``(beams,)`` bearings [rad] of a 360-degree scan: ``-pi + j * 2 pi / beams``.

    Read-only and shared: every virtual scan of a place database holds the same array.
    """
    return _shared_angles(int(beams))


@functools.lru_cache(maxsize=8)
def _shared_angles(beams: int) -> Array:
    angles = -np.pi + (2.0 * np.pi / beams) * np.arange(beams)
    angles.setflags(write=False)
    return angles


def _check(beams: int, max_range: float, min_range: float) -> None:
    if isinstance(beams, bool) or int(beams) != beams or beams < 3:
        raise UserError(f"virtual scan needs an integer number of beams >= 3, got {beams}")
    if not (math.isfinite(max_range) and max_range > 0):
        raise UserError(f"virtual scan max range must be a positive number, got {max_range}")
    if not (math.isfinite(min_range) and 0 <= min_range < max_range):
        raise UserError(f"virtual scan min range must be in [0, max range), got {min_range}")


def _ray_segment(
    angle: Array, a: Array, b: Array
) -> tuple[Array, NDArray[np.bool_]]:
    """Distance along rays at bearings `angle` to their crossing with segments ``a -> b``.

    Returns ``(t, ok)``; ``ok`` is False where the ray is parallel to the segment or
    misses it (crossing parameter outside ``[0, 1]`` or behind the origin).
    """
    ux, uy = np.cos(angle), np.sin(angle)
    ex, ey = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    den = ux * ey - uy * ex
    ok = np.abs(den) > 1e-12
    den = np.where(ok, den, 1.0)
    t = (a[:, 0] * ey - a[:, 1] * ex) / den
    s = (a[:, 0] * uy - a[:, 1] * ux) / den
    ok &= (s >= -1e-9) & (s <= 1.0 + 1e-9) & (t > 0.0)
    return t, ok


def _scan(
    ranges: Array, beams: int, max_range: float, stamp: float, index: int, odom: ArrayLike | None
) -> Scan:
    return Scan(
        stamp=float(stamp),
        ranges=ranges,
        angles=virtual_angles(beams),
        max_range=float(max_range),
        min_range=0.0,
        odom=None if odom is None else np.asarray(odom, dtype=float).reshape(3).copy(),
        index=int(index),
    )


def virtual_scan(
    points: ArrayLike,
    beams: int = 360,
    max_range: float = 30.0,
    lateral_tol: float = 0.05,
    *,
    min_range: float = 0.05,
    link_dist: float = 0.5,
    max_gap_deg: float = 5.0,
    stamp: float = 0.0,
    index: int = 0,
    odom: ArrayLike | None = None,
    compiled: bool = True,
) -> Scan:
    """360-degree virtual scan of map `points` ``(M, 2)`` given in the sensor frame [m].

    The rule is in the module docstring.  `stamp`, `index` and `odom` (the
    keyframe's pose guess) are copied into the returned `Scan`.  `compiled` finds
    the candidates and the front-most one of each beam side with the numba kernels
    of `loopclosure.virtual_scan_kernel` (the same result; False: numpy).

    Raises:
        UserError: bad parameters (fewer than 3 beams, non-positive ranges, ...).
    """
    _check(beams, max_range, min_range)
    if not (lateral_tol >= 0 and link_dist >= 0 and max_gap_deg >= 0):
        raise UserError("virtual scan lateral_tol, link_dist and max_gap_deg must be >= 0")
    beams = int(beams)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    finite = np.all(np.isfinite(pts), axis=1)
    if not finite.all():
        warn(f"virtual scan: ignored {int((~finite).sum())} non-finite map points")
        pts = pts[finite]
    r = np.hypot(pts[:, 0], pts[:, 1])
    keep = (r >= max(min_range, 1e-9)) & (r < max_range)
    pts, r = pts[keep], r[keep]
    ranges = np.full(beams, float(max_range))
    if len(pts) == 0:
        return _scan(ranges, beams, max_range, stamp, index, odom)
    step = 2.0 * np.pi / beams
    pos = (np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / step  # bearing in beam units
    half = np.maximum(0.5, np.arcsin(np.minimum(1.0, lateral_tol / r)) / step)
    if compiled:
        # numba loads on first use (`loopclosure.virtual_scan_kernel`): the same
        # candidates in the same order, the front-most without a sort.
        from loopclosure.virtual_scan_kernel import candidates, front_most

        pid, j, dphi = candidates(pos, half, step)
        along = r[pid] * np.cos(dphi)
        best_pt, best_along, best_off = front_most(pid, j, dphi, along, beams)
    else:
        best_pt, best_along, best_off = _front_most(pts, r, pos, half, step, beams)
    best_pt, best_along = best_pt.reshape(beams, 2), best_along.reshape(beams, 2)
    best_off = best_off.reshape(beams, 2)
    # 3. one surface on both sides: cross the segment joining them; two surfaces: the
    #    one nearer in bearing (the beam passes the other's edge); one side: that one.
    ranges_hit = best_along[np.arange(beams), np.argmin(best_off, axis=1)]
    both = np.flatnonzero((best_pt >= 0).all(axis=1))
    a, b = pts[best_pt[both, 0]], pts[best_pt[both, 1]]
    linked = np.linalg.norm(b - a, axis=1) <= link_dist
    both, a, b = both[linked], a[linked], b[linked]
    t, ok = _ray_segment(virtual_angles(beams)[both], a, b)
    ranges_hit[both] = best_along[both].min(axis=1)
    ranges_hit[both[ok]] = t[ok]
    has = np.isfinite(ranges_hit) & (ranges_hit < max_range)
    ranges[has] = ranges_hit[has]
    # 4. fill narrow gaps between two returns on one surface.
    ranges = _fill_gaps(ranges, has, beams, max_range, link_dist, max_gap_deg)
    return _scan(ranges, beams, max_range, stamp, index, odom)


def _front_most(
    pts: Array, r: Array, pos: Array, half: Array, step: float, beams: int
) -> tuple[NDArray[np.intp], Array, Array]:
    """Steps 1-2 of the module docstring with numpy: per (beam, side), row
    ``2 j + side``, the front-most candidate's point id (-1: none), its along-beam
    distance [m] (inf: none) and ``|dphi|`` [rad]."""
    lo = np.ceil(pos - half).astype(np.intp)
    count = np.floor(pos + half).astype(np.intp) - lo + 1
    # 1. candidate (point, beam) pairs.
    pid = np.repeat(np.arange(len(pts)), count)
    j = lo[pid] + (np.arange(len(pid)) - np.repeat(np.cumsum(count) - count, count))
    dphi = (j - pos[pid]) * step  # beam bearing minus point bearing
    along = r[pid] * np.cos(dphi)
    ok = along > 0.0
    pid, j, dphi, along = pid[ok], np.mod(j[ok], beams), dphi[ok], along[ok]
    # 2. front-most candidate per (beam, side); side 1: point counter-clockwise of the beam.
    key = 2 * j + (dphi < 0.0)
    order = np.lexsort((along, key))
    key_sorted = key[order]
    first = order[np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])]
    best_pt = np.full(2 * beams, -1, dtype=np.intp)
    best_along = np.full(2 * beams, np.inf)
    best_off = np.full(2 * beams, np.inf)
    best_pt[key[first]] = pid[first]
    best_along[key[first]] = along[first]
    best_off[key[first]] = np.abs(dphi[first])
    return best_pt, best_along, best_off


def _fill_gaps(
    ranges: Array,
    has: NDArray[np.bool_],
    beams: int,
    max_range: float,
    link_dist: float,
    max_gap_deg: float,
) -> Array:
    """`ranges` with narrow gaps between returns filled (rule 4 of the module docstring)."""
    valid = np.flatnonzero(has)
    empty = np.flatnonzero(~has)
    if len(valid) < 2 or len(empty) == 0:
        return ranges
    step = 2.0 * np.pi / beams
    pos = np.searchsorted(valid, empty)
    nxt = valid[pos % len(valid)]
    prv = valid[pos - 1]  # pos == 0 wraps to the last valid beam
    gap = np.mod(nxt - prv, beams) - 1
    fill = gap * step <= np.radians(max_gap_deg) + 1e-12
    if not fill.any():
        return ranges
    empty, nxt, prv = empty[fill], nxt[fill], prv[fill]
    ang = virtual_angles(beams)
    end_p = ranges[prv, None] * np.column_stack([np.cos(ang[prv]), np.sin(ang[prv])])
    end_n = ranges[nxt, None] * np.column_stack([np.cos(ang[nxt]), np.sin(ang[nxt])])
    near = np.linalg.norm(end_n - end_p, axis=1) <= link_dist
    t, ok = _ray_segment(ang[empty], end_p, end_n)
    ok &= near & (t < max_range)
    out = ranges.copy()
    out[empty[ok]] = t[ok]
    return out


def virtual_scan_from_grid(
    grid: GridLike,
    pose: ArrayLike,
    beams: int = 360,
    max_range: float = 30.0,
    *,
    min_range: float | None = None,
    stamp: float = 0.0,
    index: int = 0,
) -> Scan:
    """360-degree virtual scan ray-marched through an occupancy grid (module docstring).

    Args:
        grid: occupancy grid (`GridLike`), map frame.
        pose: ``(3,)`` sensor pose ``(x, y, theta)`` in the grid's map frame.
        beams, max_range: beam count and no-return reading [m].
        min_range: occupied cells the beam leaves within this distance are ignored
            [m] (default: one cell).
        stamp, index: copied into the scan; `Scan.odom` is `pose`.
    """
    res = float(grid.resolution)
    mr = res if min_range is None else float(min_range)
    _check(beams, max_range, mr)
    p = np.asarray(pose, dtype=float).reshape(3)
    if not np.all(np.isfinite(p)):
        raise UserError(f"virtual scan pose must be finite, got {p.tolist()}")
    beams = int(beams)
    occ = np.asarray(grid.occupied(), dtype=bool)
    rows, cols = occ.shape
    ang = virtual_angles(beams) + p[2]
    u = np.column_stack([np.cos(ang), np.sin(ang)])  # (B, 2)
    g = (p[:2] - np.asarray(grid.origin, dtype=float).reshape(2)) / res  # position in cells
    n_lines = int(min(math.ceil(max_range / res) + 1, max(rows, cols) + 2))
    k = np.arange(n_lines)
    crossings = []
    for axis in (0, 1):
        d = u[:, axis:axis + 1]
        first_line = np.where(d > 0, np.floor(g[axis]) + 1, np.ceil(g[axis]) - 1)
        lines = first_line + np.where(d > 0, 1, -1) * k[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(np.abs(d) > 1e-12, (lines - g[axis]) / d, np.inf)
        crossings.append(t)
    t_all = np.sort(np.hstack([np.zeros((beams, 1)), *crossings]), axis=1) * res  # [m]
    t_all = np.minimum(t_all, max_range)
    t_in, t_out = t_all[:, :-1], t_all[:, 1:]
    mid = 0.5 * (t_in + t_out)
    cell = np.floor(g[None, None, :] + mid[..., None] * u[:, None, :] / res).astype(np.intp)
    col, row = cell[..., 0], cell[..., 1]
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    hit = np.zeros(inside.shape, dtype=bool)
    hit[inside] = occ[row[inside], col[inside]]
    hit &= (t_out > t_in + 1e-12) & (t_out > mr) & (t_in < max_range)
    any_hit = hit.any(axis=1)
    first = np.argmax(hit, axis=1)
    b = np.arange(beams)
    # The run of occupied cells the beam enters there (the wall's thickness).
    idx = np.arange(hit.shape[1])
    after = np.argmax(~hit & (idx[None, :] > first[:, None]), axis=1)
    last = np.where(after > first, after - 1, hit.shape[1] - 1)
    enter = t_in[b, first]
    rng = 0.5 * (enter + np.minimum(t_out[b, last], enter + 2.0 * res))
    ranges = np.where(any_hit & (rng < max_range), rng, float(max_range))
    return _scan(ranges, beams, max_range, stamp, index, p)


def local_map_points(
    scans: Sequence[Scan],
    poses: ArrayLike,
    frame_pose: ArrayLike,
    radius: float | None = None,
) -> Array:
    """``(M, 2)`` end points of the valid beams of `scans`, in the frame of `frame_pose`.

    Args:
        scans: the scans of the local map (valid beams only, as `Scan.points`).
        poses: ``(N, 3)`` sensor poses of the scans in the map frame; scans with a
            non-finite pose are left out.
        frame_pose: ``(3,)`` pose (map frame) of the frame to express the points in,
            e.g. the keyframe's sensor pose.
        radius: keep only points within this distance of `frame_pose` [m].
    """
    pts, valid, _ = _scan_arrays(scans, poses, frame_pose)
    out = pts[valid]
    if radius is not None:
        out = out[np.hypot(out[:, 0], out[:, 1]) <= radius]
    return out


def _scan_arrays(
    scans: Sequence[Scan], poses: ArrayLike, frame_pose: ArrayLike
) -> tuple[Array, NDArray[np.bool_], NDArray[np.intp]]:
    """Beam end points of `scans` in the frame of `frame_pose`, their validity and scan ids.

    Invalid beams (and every beam of a scan whose pose is not finite) get a NaN
    point and ``valid = False``; the points are never used for them.
    """
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(p) != len(scans):
        raise UserError(f"local map needs one pose per scan: {len(scans)} scans, {len(p)} poses")
    if not scans:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool), np.zeros(0, dtype=np.intp)
    frame = np.asarray(frame_pose, dtype=float).reshape(3)
    rel = se2.between(frame, p)
    n = np.array([len(s.ranges) for s in scans], dtype=np.intp)
    sid = np.repeat(np.arange(len(scans)), n)
    r = np.concatenate([np.asarray(s.ranges, dtype=float) for s in scans])
    a = np.concatenate([np.asarray(s.angles, dtype=float) for s in scans])
    valid = np.concatenate([s.valid for s in scans]) & np.all(np.isfinite(rel), axis=1)[sid]
    r = np.where(valid, r, np.nan)
    bearing = rel[sid, 2] + a
    pts = rel[sid, :2] + r[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    return pts, valid, sid


def virtual_scan_from_scans(
    scans: Sequence[Scan],
    poses: ArrayLike,
    frame_pose: ArrayLike,
    beams: int = 360,
    max_range: float = 30.0,
    *,
    min_range: float = 0.05,
    link_dist: float = 0.5,
    stamp: float = 0.0,
    index: int = 0,
) -> Scan:
    """360-degree virtual scan at `frame_pose` of the surfaces the local `scans` saw.

    Args:
        scans: the scans of the local map.
        poses: ``(N, 3)`` their sensor poses in the map frame.
        frame_pose: ``(3,)`` pose of the virtual sensor in the map frame (the
            keyframe's sensor pose); copied into `Scan.odom`.
        beams, max_range, min_range, link_dist: as in `virtual_scan`.
        stamp, index: copied into the scan.

    The rule is in the module docstring ("From the scans themselves").
    """
    _check(beams, max_range, min_range)
    if not link_dist >= 0:
        raise UserError("virtual scan link_dist must be >= 0")
    beams = int(beams)
    pts, valid, sid = _scan_arrays(scans, poses, frame_pose)
    linked = valid[:-1] & valid[1:] & (sid[:-1] == sid[1:])
    with np.errstate(invalid="ignore"):
        linked &= np.linalg.norm(pts[1:] - pts[:-1], axis=1) <= link_dist
    a, b = pts[:-1][linked], pts[1:][linked]
    # Segments passing within min_range of the sensor are dropped (like close points).
    e = b - a
    u = np.clip(-np.einsum("ij,ij->i", a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300),
                0.0, 1.0)
    far = np.hypot(*(a + u[:, None] * e).T) >= min_range
    segments = np.stack([a[far], b[far]], axis=1)
    step = 2.0 * np.pi / beams
    ranges = trace(segments, np.zeros((1, 3)), -np.pi, step, beams, max_range)[0]
    ranges = np.where(np.isfinite(ranges) & (ranges < max_range), ranges, float(max_range))
    return _scan(ranges, beams, max_range, stamp, index, frame_pose)
