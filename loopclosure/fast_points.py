"""Compiled point-set helpers of the front end and the geometric check (numba,
``cache=True``): the voxel grid, the beams' end points and the crop to a radius.

`voxel_downsample_fast` is `loopclosure.registration.voxel_downsample` (centroid per
cell [m], cells in the order of their first point, the same summation order, so the
same centroids to the bit); `beam_points_fast` turns a scan's ranges into its end
points [m, sensor frame] and voxel-downsamples them in the same call;
`within_radius` / `points_within` are the local map's crop ``|p - c| <= radius``
(``np.hypot``'s verdict to the bit).  Each is one compiled call because it runs for
every scan or every local map, on a few hundred points: numpy's fixed per-call
overhead would dominate.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def voxel_downsample_fast(points: ArrayLike, voxel: float) -> Array:
    """`loopclosure.registration.voxel_downsample`, compiled: the centroid of the points
    in each ``voxel x voxel`` cell [m], cells in the order of their first point;
    ``voxel <= 0`` returns a float copy.

    One compiled pass (`_voxel_kernel`): the cells are found by hashing, not sorting,
    and each cell's points are summed in index order, as the stable sort of the
    reference sums them, so the centroids are the same to the bit.  The whole
    function is one kernel call because it runs for every scan of the front end and
    every submap: numpy's per-call overhead (a floor, a cast, two shifts and an
    argsort on a few hundred points) was several times the kernel's own work."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    if voxel <= 0 or len(pts) == 0:
        return pts.copy()
    return _voxel_kernel(pts, float(voxel))


@numba.njit(cache=True)
def _voxel_kernel(pts, voxel):
    """Centroids of the cells ``key = (floor(x / voxel) << 32) ^ (floor(y / voxel) &
    0xFFFFFFFF)`` of `pts` (``(N, 2)`` [m]), in the order of each cell's first point;
    each cell's points summed in index order.  Cells are found in an open-addressing
    hash table of at least twice N slots (Fibonacci hashing, linear probing)."""
    n = pts.shape[0]
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    size = 1 << bits
    mask = size - 1
    shift = np.uint64(64 - bits)
    golden = np.uint64(0x9E3779B97F4A7C15)
    slot_key = np.empty(size, dtype=np.int64)
    slot_group = np.full(size, -1, dtype=np.int64)
    sums = np.zeros((n, 2))
    counts = np.zeros(n)
    groups = 0
    for i in range(n):
        cx = np.int64(np.floor(pts[i, 0] / voxel))
        cy = np.int64(np.floor(pts[i, 1] / voxel))
        key = (cx << 32) ^ (cy & 0xFFFFFFFF)
        h = np.int64((np.uint64(key) * golden) >> shift)
        while slot_group[h] >= 0 and slot_key[h] != key:
            h = (h + 1) & mask
        g = slot_group[h]
        if g < 0:
            g = groups
            groups += 1
            slot_group[h] = g
            slot_key[h] = key
        sums[g, 0] += pts[i, 0]
        sums[g, 1] += pts[i, 1]
        counts[g] += 1.0
    out = np.empty((groups, 2))
    for g in range(groups):
        out[g, 0] = sums[g, 0] / counts[g]
        out[g, 1] = sums[g, 1] / counts[g]
    return out


def beam_points_fast(ranges: Array, cosines: Array, sines: Array, bounds: tuple[float, ...],
                     voxel: float) -> Array:
    """End points ``(r cos a, r sin a)`` [m, sensor frame] of the beams whose range
    ``r`` is finite and within `bounds` ``(above, below, low, high)`` (``above < r <
    below`` and ``low <= r <= high``), voxel-downsampled to `voxel` [m] as
    `voxel_downsample_fast` does (``voxel <= 0``: every point), in one compiled call.

    `ranges`, `cosines` and `sines` are ``(N,)`` float64 (the cosines and sines of the
    beams' bearings, computed once per laser): each point is the same product as
    ``ranges[keep] * np.cos(angles[keep])``, in beam order, so the result is the same
    to the bit as masking, stacking and `voxel_downsample_fast`."""
    above, below, low, high = bounds
    return _beam_points_kernel(ranges, cosines, sines, float(above), float(below), float(low),
                               float(high), float(voxel))


@numba.njit(cache=True)
def _beam_points_kernel(ranges, cosines, sines, above, below, low, high, voxel):
    n = ranges.shape[0]
    pts = np.empty((n, 2))
    m = 0
    for i in range(n):
        r = ranges[i]
        if np.isfinite(r) and r > above and r < below and r >= low and r <= high:
            pts[m, 0] = r * cosines[i]
            pts[m, 1] = r * sines[i]
            m += 1
    if voxel <= 0 or m == 0:
        return pts[:m].copy()
    return _voxel_kernel(pts[:m], voxel)


#: Relative margin of `within_radius`'s squared-distance test: far above the
#: rounding of ``dx^2 + dy^2`` and of ``hypot`` (a few units in the last place).
_RADIUS_MARGIN = 1e-9


def within_radius(points: Array, center: ArrayLike, radius: float) -> NDArray[np.bool_]:
    """``(N,)`` mask of the `points` (``(N, 2)`` float64 [m]) with ``np.hypot(*(points -
    center).T) <= radius`` (`center` ``(2,)`` [m]), to the bit.

    One compiled pass decides every point whose squared distance ``dx^2 + dy^2`` lies
    clearly inside ``radius^2 (1 -+ margin)^2`` (the offsets ``dx, dy`` are numpy's
    subtraction); only the few within the margin of the border take ``np.hypot`` as
    the reference does.  The local map's crop ran a dozen numpy calls per rebuild."""
    pts = np.ascontiguousarray(points, dtype=float)
    c = np.asarray(center, dtype=float).reshape(2)
    cx, cy = float(c[0]), float(c[1])
    if not radius < 1e150:  # its square would overflow: numpy's own test
        return np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) <= radius
    mask, unsure = _within_kernel(pts, cx, cy, float(radius), _RADIUS_MARGIN)
    if unsure:
        idx = np.flatnonzero(mask == 2)
        mask[idx] = np.hypot(pts[idx, 0] - cx, pts[idx, 1] - cy) <= radius
    return mask.view(np.bool_)


def points_within(points: Array, center: ArrayLike, radius: float) -> Array:
    """``points[within_radius(points, center, radius)]``: the same rows in the same
    order, `points` itself (not a copy) when every row is kept, else compacted in one
    compiled pass (numpy's boolean indexing of ``(N, 2)`` rows costs several times
    the test)."""
    pts = np.ascontiguousarray(points, dtype=float)
    mask = within_radius(pts, center, radius)
    return _compact(pts, mask)


@numba.njit(cache=True)
def _compact(pts, mask):
    """The rows of `pts` where `mask` holds, in order; `pts` itself when it holds for all."""
    kept = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            kept += 1
    if kept == pts.shape[0]:
        return pts
    out = np.empty((kept, 2))
    k = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            out[k, 0] = pts[i, 0]
            out[k, 1] = pts[i, 1]
            k += 1
    return out


@numba.njit(cache=True)
def _within_kernel(pts, cx, cy, radius, margin):
    """1 inside, 0 outside, 2 too near the border to tell from ``dx^2 + dy^2``; and
    whether any point is 2."""
    inside = (radius * (1.0 - margin)) ** 2
    outside = (radius * (1.0 + margin)) ** 2
    mask = np.empty(pts.shape[0], dtype=np.uint8)
    unsure = False
    for i in range(pts.shape[0]):
        dx = pts[i, 0] - cx
        dy = pts[i, 1] - cy
        d2 = dx * dx + dy * dy
        if d2 <= inside:
            mask[i] = 1
        elif d2 > outside:
            mask[i] = 0
        else:  # near the border, or NaN
            mask[i] = 2
            unsure = True
    return mask, unsure


__all__ = ["beam_points_fast", "points_within", "voxel_downsample_fast", "within_radius"]
