"""Compiled point-to-line ICP: `loopclosure.registration.register`, in numba.

The odometry front end registers every scan (200-400 points) onto its local map a
few times per scan, and the geometric check registers a keyframe's submap onto a
candidate's from several starts (`register_multi`, `loopclosure.prior_free`).
With numpy and a `scipy.spatial.cKDTree`, each Gauss-Newton iteration is a dozen
small array calls whose fixed overhead (tens of microseconds each) dominates the
arithmetic; here the whole loop, nearest-neighbour search included, is one compiled
call (numba, ``cache=True``: compiled once per machine).

Same maths as `loopclosure.registration` (read its module docstring for the
equations; frames, units and every figure of `IcpResult` are the same):
point-to-line rows onto line-like map points with their PCA normals, two
point-to-point rows (unit axes) onto clutter when `IcpConfig.point_to_point_clutter`
(weighted by `IcpConfig.clutter_weight`), no correspondence when the nearest map
point is neither; Cauchy / Huber / Tukey / no IRLS kernel of width
``kernel_constant * s``, ``s = max(min_residual_scale, 1.4826 median|r|)``; the
adaptive distance gate ``min(gate, max(min_correspondence_distance, gate_sigmas *
1.4826 median d))``; Gauss-Newton step ``-(H + Lambda)^-1 (g + Lambda (x - x_prior))``;
convergence on the step and a settled gate.  Medians are upper medians.

Nearest neighbour (`GridTarget`): the map points are bucketed in square cells of
side `cell` [m] (a CSR layout: points sorted by cell, one start offset per cell).
A query at ``p`` with gate ``d`` visits the cells within ``ceil(d / cell)`` rings
of ``p``'s cell and keeps the nearest point with ``|p - q| <= d`` (inclusive, as
`cKDTree.query` with ``distance_upper_bound``), exact for any gate.  Ties between
equidistant points may resolve differently from the KD-tree.

Map points, normals and kinds: `loopclosure.grid_target` (`GridTarget`, re-exported
here, with `estimate_normals_fast`); a lazy grid's points get their normal the first
time `_match` or the overlap screen meets them.  `overlap_screen`
scores guesses before ICP (the overlap score and the overlap bound of the
pose-gated check, one pass).  `voxel_downsample_fast` is
`loopclosure.registration.voxel_downsample` (centroid per cell, order of first
occurrence, the same summation order).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.grid_target import (
    ANCHORS,
    KIND_CLUTTER,
    KIND_LINE,
    KIND_NONE,
    KIND_UNKNOWN,
    GridTarget,
    _normals_kernel,  # noqa: F401  (the warm-up's list of kernels names it here)
    checked_points,
    estimate_normals_fast,
    resolve_point,
)
from loopclosure.registration import (
    KERNEL_CONSTANTS,
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    _failed,  # the failed result of either ICP: the initial pose, no information
    as_points,
)

Array = NDArray[np.float64]

_KERNELS = {"none": 0, "cauchy": 1, "huber": 2, "tukey": 3}
_MAD = 1.4826


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


@numba.njit(cache=True)
def _scan_cell(c, px, py, start, pts, best, best_d2):
    for k in range(start[c], start[c + 1]):
        dx = pts[k, 0] - px
        dy = pts[k, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and (best < 0 or k < best)):
            best, best_d2 = k, d2
    return best, best_d2


#: Slack [m] taken off a cell's gap to a query before the gap may skip the cell
#: (`_nearest`): far above the rounding of a cell border or a point's offset (a
#: point's cell is found by flooring its offset over the cell side), far below any
#: distance that decides a match.
_BOX_SLACK = 1e-9


@numba.njit(cache=True)
def _cell_gap(i, ci, f, cell):
    """Gap [m] along one axis between a query in cell ``ci`` (offset `f` from that
    cell's lower border) and cell ``i``, less `_BOX_SLACK`, never negative (0 for the
    query's own cell)."""
    if i < ci:
        return max(f + (ci - i - 1) * cell - _BOX_SLACK, 0.0)
    if i > ci:
        return max((i - ci) * cell - f - _BOX_SLACK, 0.0)
    return 0.0


@numba.njit(cache=True)
def _nearest(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """Index of the nearest grid point within `gate` of ``(px, py)`` (-1: none) and its
    distance.  Cells are visited ring by ring (Chebyshev distance from the query's cell);
    after ring ``r`` nothing nearer than ``r * cell + m`` can remain (``m``: distance of
    the query to its own cell's border), so the search stops there once a point at most
    that far is found.  A cell whose box lies farther from the query than the best
    point so far (its gaps ``g_x, g_y`` to the query less `_BOX_SLACK` each, ``g_x^2
    + g_y^2 > d_best^2``) is not scanned: none of its points could replace the best,
    not even by a tie, so the answer is the full scan's."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    fx = px - ox - ci * cell
    fy = py - oy - cj * cell
    margin = max(min(fx, cell - fx, fy, cell - fy), 0.0)
    rings = int(np.ceil(gate / cell))
    best, best_d2 = -1, gate * gate
    for r in range(rings + 1):
        for i in range(ci - r, ci + r + 1):
            if i < 0 or i >= nx:
                continue
            gx = _cell_gap(i, ci, fx, cell)
            gx2 = gx * gx
            if gx2 > best_d2:
                continue
            edge = i == ci - r or i == ci + r
            step = 1 if edge else 2 * r
            j = cj - r
            while j <= cj + r:
                if 0 <= j < ny:
                    gy = _cell_gap(j, cj, fy, cell)
                    if gx2 + gy * gy <= best_d2:
                        best, best_d2 = _scan_cell(i * ny + j, px, py, start, pts, best,
                                                   best_d2)
                if step == 0:
                    break
                j += step
        if best >= 0 and best_d2 <= (r * cell + margin) ** 2:
            break
    return best, np.sqrt(best_d2)


@numba.njit(cache=True)
def _scan_cell_bound(c, px, py, start, pts, best, best_d2, other_d2):
    """`_scan_cell`, also keeping the smallest squared distance `other_d2` of the
    points it met that are not the best (a replaced best included)."""
    for k in range(start[c], start[c + 1]):
        dx = pts[k, 0] - px
        dy = pts[k, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and (best < 0 or k < best)):
            if best >= 0 and best_d2 < other_d2:
                other_d2 = best_d2
            best, best_d2 = k, d2
        elif d2 < other_d2:
            other_d2 = d2
    return best, best_d2, other_d2


@numba.njit(cache=True)
def _nearest_bound(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """`_nearest` (the same cells visited, the same answer) and a lower bound [m] on
    the distance from ``(px, py)`` of every grid point other than the answer (of
    every point when there is none): the nearest of the others it met, the gaps of
    the cells it skipped (less `_BOX_SLACK`) and, beyond the rings it visited, the
    query's distance to their outer border (less `_BOX_SLACK`).  `_match` keeps an
    answer while the point moves less than half the difference."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    fx = px - ox - ci * cell
    fy = py - oy - cj * cell
    margin = max(min(fx, cell - fx, fy, cell - fy), 0.0)
    rings = int(np.ceil(gate / cell))
    best, best_d2 = -1, gate * gate
    other_d2 = np.inf
    beyond = rings * cell + margin
    for r in range(rings + 1):
        for i in range(ci - r, ci + r + 1):
            if i < 0 or i >= nx:
                continue
            gx = _cell_gap(i, ci, fx, cell)
            gx2 = gx * gx
            if gx2 > best_d2:
                other_d2 = min(other_d2, gx2)  # every cell of column i in this ring
                continue
            edge = i == ci - r or i == ci + r
            step = 1 if edge else 2 * r
            j = cj - r
            while j <= cj + r:
                if 0 <= j < ny:
                    gy = _cell_gap(j, cj, fy, cell)
                    g2 = gx2 + gy * gy
                    if g2 <= best_d2:
                        best, best_d2, other_d2 = _scan_cell_bound(i * ny + j, px, py, start,
                                                                   pts, best, best_d2, other_d2)
                    elif g2 < other_d2:
                        other_d2 = g2
                if step == 0:
                    break
                j += step
        if best >= 0 and best_d2 <= (r * cell + margin) ** 2:
            beyond = r * cell + margin
            break
    beyond = max(beyond - _BOX_SLACK, 0.0)
    return best, np.sqrt(best_d2), np.sqrt(min(other_d2, beyond * beyond))


#: Slack [m] of `_match`'s reuse test: far above the rounding of the distances and
#: of a moved point's coordinates, far below any distance between map points.
_REUSE_SLACK = 1e-9


@numba.njit(cache=True)
def _upper_median_abs(values, n):
    """The upper median ``sorted(|values[:n]|)[n // 2]`` (``n >= 1``), by selection
    (`np.partition`: the element a sort puts there, in linear time instead of a
    sort's ``n log n``; twice per ICP iteration)."""
    a = np.abs(values[:n])
    return np.partition(a, n // 2)[n // 2]


@numba.njit(cache=True)
def _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind, sel, jdx, dist, params,
           normals, anchors, near, bound, last, norms):
    """Rows of the correspondences at pose `x`: point-to-line rows first, then the x rows
    and the y rows of the point-to-point matches.  Returns (rows, lines, points).  A
    nearest point of unknown kind (a lazy grid) is resolved first (`resolve_point`).

    Nearest neighbours carried between the iterations of one run: `near` and `bound`
    hold each source point's nearest map point (-1: none within the gate when it was
    searched) and a lower bound [m] on the distance of every other map point (of
    every point for -1; `_nearest_bound`), at pose
    `last` (``last[3] = 0``: none yet); `norms` the points' distances from the source
    origin [m].  A point moves by at most ``delta = |dtheta| |p| + |dt|`` from `last`
    to `x`; where its nearest point, at distance ``d`` now, is nearer than ``bound -
    delta`` (less `_REUSE_SLACK`), no other point can be as near, so it is the
    answer of a new search (and none within the gate stays none while ``bound - delta``
    exceeds the gate, which never grows); the bound becomes ``bound - delta``.  Other
    points search again.  The same correspondences as searching every point."""
    n = src.shape[0]
    c, s = np.cos(x[2]), np.sin(x[2])
    lines = 0
    clut = 0
    csel = np.empty(n, dtype=np.int64)
    cj = np.empty(n, dtype=np.int64)
    cd = np.empty(n)
    carry = last[3] > 0.0
    turn = abs(_wrap(x[2] - last[2]))
    shift = np.hypot(x[0] - last[0], x[1] - last[1])
    gate2 = gate * gate
    for i in range(n):
        px = c * src[i, 0] - s * src[i, 1] + x[0]
        py = s * src[i, 0] + c * src[i, 1] + x[1]
        found = False
        if carry:
            delta = (turn * norms[i] + shift) * (1.0 + _REUSE_SLACK) + _REUSE_SLACK
            left = bound[i] - delta
            j = near[i]
            if j >= 0:
                dx = pts[j, 0] - px
                dy = pts[j, 1] - py
                d2 = dx * dx + dy * dy
                d = np.sqrt(d2)
                if d < left:  # still the nearest; a match if within the gate
                    found = True
                    bound[i] = left
                    if d2 > gate2:
                        j = -1
            elif left > gate:
                found = True
                bound[i] = left
        if not found:
            j, d, b = _nearest_bound(px, py, gate, ox, oy, cell, nx, ny, start, pts)
            near[i] = j
            bound[i] = b
        if j < 0:
            continue
        if kind[j] < 0:
            resolve_point(j, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind)
        if kind[j] == 1:
            sel[lines] = i
            jdx[lines] = j
            dist[lines] = d
            lines += 1
        elif kind[j] == 2:
            csel[clut] = i
            cj[clut] = j
            cd[clut] = d
            clut += 1
    for a in range(2):
        for k in range(clut):
            r = lines + a * clut + k
            sel[r] = csel[k]
            jdx[r] = cj[k]
            dist[r] = cd[k]
    last[0] = x[0]
    last[1] = x[1]
    last[2] = x[2]
    last[3] = 1.0
    return lines + 2 * clut, lines, lines + clut


@numba.njit(cache=True)
def _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm):
    """Residuals ``r`` and Jacobian rows ``J`` at pose `x` of the given correspondences."""
    c, s = np.cos(x[2]), np.sin(x[2])
    clut = points - lines
    for k in range(rows):
        i, j = sel[k], jdx[k]
        rpx = c * src[i, 0] - s * src[i, 1]
        rpy = s * src[i, 0] + c * src[i, 1]
        qx, qy = pts[j, 0], pts[j, 1]
        if k < lines:
            n0, n1 = normals[j, 0], normals[j, 1]
            qx, qy = anchors[j, 0], anchors[j, 1]
        elif k < lines + clut:
            n0, n1 = 1.0, 0.0
        else:
            n0, n1 = 0.0, 1.0
        nrm[k, 0] = n0
        nrm[k, 1] = n1
        r[k] = n0 * (rpx + x[0] - qx) + n1 * (rpy + x[1] - qy)
        jac[k, 0] = n0
        jac[k, 1] = n1
        jac[k, 2] = n1 * rpx - n0 * rpy


@numba.njit(cache=True)
def _weights(r, rows, lines, points, scale, kernel, kconst, clutter_weight, w):
    k = kconst * scale
    for i in range(rows):
        if kernel == 0:
            wi = 1.0
        else:
            u = r[i] / k
            if kernel == 1:
                wi = 1.0 / (1.0 + u * u)
            elif kernel == 2:
                a = abs(u)
                wi = 1.0 if a <= 1.0 else 1.0 / max(a, 1e-300)
            else:
                wi = (1.0 - u * u) ** 2 if abs(u) < 1.0 else 0.0
        if i >= lines:
            wi *= clutter_weight
        w[i] = wi


@numba.njit(cache=True)
def _normal_equations(r, jac, w, rows):
    h = np.zeros((3, 3))
    g = np.zeros(3)
    for k in range(rows):
        for a in range(3):
            wa = w[k] * jac[k, a]
            g[a] += wa * r[k]
            for b in range(3):
                h[a, b] += wa * jac[k, b]
    return h, g


@numba.njit(cache=True)
def _solve3(h, g):
    """``h^-1 g`` for a symmetric positive definite ``3x3`` `h` (Cholesky; LU when
    rounding leaves a pivot that is not positive)."""
    if h[0, 0] <= 0.0:
        return np.linalg.solve(h, g)
    l00 = np.sqrt(h[0, 0])
    l10 = h[1, 0] / l00
    l20 = h[2, 0] / l00
    p11 = h[1, 1] - l10 * l10
    if p11 <= 0.0:
        return np.linalg.solve(h, g)
    l11 = np.sqrt(p11)
    l21 = (h[2, 1] - l20 * l10) / l11
    p22 = h[2, 2] - l20 * l20 - l21 * l21
    if p22 <= 0.0:
        return np.linalg.solve(h, g)
    l22 = np.sqrt(p22)
    y0 = g[0] / l00
    y1 = (g[1] - l10 * y0) / l11
    y2 = (g[2] - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    out = np.empty(3)
    out[0] = x0
    out[1] = x1
    out[2] = x2
    return out


@numba.njit(cache=True)
def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@numba.njit(cache=True)
def _icp(src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind, params, lam,
         x_prior, has_prior,
         max_iterations, gate0, min_gate, gate_sigmas, kernel, kconst, min_scale, clutter_weight,
         t_tol, r_tol, min_corr, joins, join_t, join_r):
    """Gauss-Newton ICP; returns (x, iterations, converged, ok, gate, rows, lines, points,
    sel, jdx, joined) with the correspondences to evaluate (empty-matched when not
    converged).  ``joined`` is the row of `joins` (``(K, 3)`` poses where earlier runs
    of the same problem ended) that an iterate came within `join_t` [m] and `join_r`
    [rad] of, the run stopping there; -1 when none did."""
    n = src.shape[0]
    sel = np.empty(2 * n, dtype=np.int64)
    jdx = np.empty(2 * n, dtype=np.int64)
    dist = np.empty(2 * n)
    r = np.empty(2 * n)
    w = np.empty(2 * n)
    jac = np.empty((2 * n, 3))
    nrm = np.empty((2 * n, 2))
    near = np.empty(n, dtype=np.int64)  # `_match`'s neighbours carried between iterations
    bound = np.empty(n)
    last = np.zeros(4)
    norms = np.empty(n)
    for i in range(n):
        norms[i] = np.hypot(src[i, 0], src[i, 1])
    x = x0.copy()
    gate = gate0
    iterations = 0
    converged = False
    rows = lines = points = 0
    for it in range(1, max_iterations + 1):
        iterations = it
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist, params, normals, anchors, near, bound,
                                     last, norms)
        if points < min_corr:
            return x0.copy(), iterations, False, False, gate, rows, lines, points, sel, jdx, -1
        _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm)
        s = max(min_scale, _MAD * _upper_median_abs(r, rows))
        _weights(r, rows, lines, points, s, kernel, kconst, clutter_weight, w)
        h, g = _normal_equations(r, jac, w, rows)
        inv_s2 = 1.0 / (s * s)
        diff = x - x_prior
        diff[2] = _wrap(diff[2])
        for a in range(3):
            g[a] *= inv_s2
            if has_prior:
                for b in range(3):
                    g[a] += lam[a, b] * diff[b]
            for b in range(3):
                h[a, b] = h[a, b] * inv_s2 + lam[a, b]
        damp = 1e-12 * max(h[0, 0] + h[1, 1] + h[2, 2], 1e-12)
        for a in range(3):
            h[a, a] += damp
        step = -_solve3(h, g)
        x = x + step
        x[2] = _wrap(x[2])
        new_gate = min(gate, max(min_gate, gate_sigmas * _MAD * _upper_median_abs(dist, rows)))
        small = np.hypot(step[0], step[1]) < t_tol and abs(step[2]) < r_tol
        settled = new_gate >= gate * (1.0 - 1e-6)
        gate = new_gate
        if small and settled:
            converged = True
            break
        for m in range(joins.shape[0]):
            if (np.hypot(x[0] - joins[m, 0], x[1] - joins[m, 1]) < join_t
                    and abs(_wrap(x[2] - joins[m, 2])) < join_r):
                return x, iterations, False, True, gate, rows, lines, points, sel, jdx, m
    if not converged:
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist, params, normals, anchors, near, bound,
                                     last, norms)
    return x, iterations, converged, True, gate, rows, lines, points, sel, jdx, -1


@numba.njit(cache=True)
def _figures(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, kernel, kconst,
             min_scale,
             clutter_weight, fitness_tol):
    """Weighted residuals at the final pose: (h_data, wsum, wr2, inliers, rms, fitness)."""
    r = np.empty(rows)
    w = np.empty(rows)
    jac = np.empty((rows, 3))
    nrm = np.empty((rows, 2))
    _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm)
    s = max(min_scale, _MAD * _upper_median_abs(r, rows)) if rows > 0 else min_scale
    _weights(r, rows, lines, points, s, kernel, kconst, clutter_weight, w)
    h, _ = _normal_equations(r, jac, w, rows)
    wsum = 0.0
    wr2 = 0.0
    for k in range(rows):
        wsum += w[k]
        wr2 += w[k] * r[k] * r[k]
    clut = points - lines
    inliers = 0
    sq = 0.0
    fit = 0.0
    for k in range(points):
        if k < lines:
            rp = abs(r[k])
        else:
            rp = np.hypot(r[k], r[k + clut])
        if rp <= fitness_tol:
            inliers += 1
            sq += rp * rp
        fit += max(0.0, 1.0 - (rp / fitness_tol) ** 2)
    rms = np.sqrt(sq / inliers) if inliers > 0 else 0.0
    return h, wsum, wr2, inliers, rms, fit / src.shape[0]


def register_fast(
    source: ArrayLike,
    target: GridTarget,
    initial: ArrayLike = (0.0, 0.0, 0.0),
    *,
    config: IcpConfig | None = None,
    prior: ArrayLike | None = None,
    prior_covariance: ArrayLike | None = None,
) -> IcpResult:
    """`loopclosure.registration.register` of `source` (``(N, 2)`` [m], source frame)
    onto a `GridTarget`; same arguments (poses ``(x, y, theta)`` of the source frame in
    the target frame, prior covariance additive in the target frame) and result."""
    result = _register_grid(source, target, initial, config, prior, prior_covariance,
                            _NO_JOINS, 0.0, 0.0)
    assert isinstance(result, IcpResult)
    return result


_NO_JOINS = np.zeros((0, 3))
_NO_PRIOR = np.zeros(3)
_NO_PRIOR_COV = np.eye(3)


@numba.njit(cache=True)
def _inv3(a):
    """``a^-1`` of a ``3x3`` matrix as `np.linalg.inv` computes it: LAPACK ``gesv``
    on the identity (numba's `np.linalg.inv` takes ``getrf`` + ``getri``, whose
    roundings differ)."""
    return np.linalg.solve(a, np.eye(3))


@numba.njit(cache=True)
def _register_kernel(src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind,
                     params, prior_cov, x_prior, has_prior, max_iterations, gate0, min_gate,
                     gate_sigmas, kernel, kconst, min_scale, clutter_weight, t_tol, r_tol,
                     min_corr, fitness_tol, joins, join_t, join_r):
    """`_icp` and the figures of its result in one compiled call.

    Returns ``(status, joined, iterations, converged, points, x, cov, h_data, sigma2,
    inliers, rms, fitness, degeneracy, axis)``; ``status`` 0: a solution, 1: failed
    (too few correspondences; only ``iterations`` and ``points`` are set), 2: joined
    row ``joined`` of `joins` (only ``iterations`` is set).  The figures (module
    docstring of `loopclosure.registration`): ``sigma^2 = max(sum w r^2 / max(sum w
    - 3, 1), min_scale^2)``; covariance ``(H / sigma^2 + Lambda + 1e-12 tr(.) I)^-1``,
    symmetrised; degeneracy the smallest eigenvalue of the translation block of
    ``H`` with the rotation eliminated (Schur complement), over ``sum w``, in
    ``[0, 0.5]``, and its eigenvector.  Each step is the numpy expression of the
    reference with the same operations in the same order, and the inverses and the
    eigen-decomposition call the LAPACK routines numpy calls (``gesv``, ``syevd``
    on the lower triangle), so every figure is the same to the bit."""
    lam = np.zeros((3, 3))
    if has_prior:
        lam = _inv3(prior_cov)
    x, iterations, converged, ok, _gate, rows, lines, points, sel, jdx, joined = _icp(
        src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind, params, lam,
        x_prior, has_prior, max_iterations, gate0, min_gate, gate_sigmas, kernel, kconst,
        min_scale, clutter_weight, t_tol, r_tol, min_corr, joins, join_t, join_r)
    cov = np.zeros((3, 3))
    h_data = np.zeros((3, 3))
    axis = np.zeros(2)
    if joined >= 0:
        return (2, joined, iterations, False, points, x, cov, h_data, 0.0, 0, 0.0, 0.0, 0.0,
                axis)
    if not ok or points < min_corr:
        return (1, -1, iterations, False, points, x, cov, h_data, 0.0, 0, 0.0, 0.0, 0.0,
                axis)
    h_data, wsum, wr2, inliers, rms, fitness = _figures(
        src, x, rows, lines, points, sel, jdx, pts, anchors, normals, kernel, kconst,
        min_scale, clutter_weight, fitness_tol)
    sigma2 = max(wr2 / max(wsum - 3.0, 1.0), min_scale**2)
    info = h_data / sigma2 + lam
    trace = info[0, 0] + info[1, 1] + info[2, 2]
    cov = _inv3(info + 1e-12 * max(trace, 1e-12) * np.eye(3))
    cov = 0.5 * (cov + cov.T)
    h_tt = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            h_tt[a, b] = h_data[a, b]
    if h_data[2, 2] > 1e-12:
        for a in range(2):
            for b in range(2):
                h_tt[a, b] = h_tt[a, b] - h_data[a, 2] * h_data[2, b] / h_data[2, 2]
    evals, evecs = np.linalg.eigh(h_tt)
    degeneracy = min(max(evals[0] / wsum, 0.0), 0.5) if wsum > 0 else 0.0
    axis[0] = evecs[0, 0]
    axis[1] = evecs[1, 0]
    x[2] = _wrap(x[2])
    return (0, -1, iterations, converged, points, x, cov, h_data, sigma2, inliers, rms,
            fitness, degeneracy, axis)


def _source_points(source: ArrayLike) -> Array:
    """`grid_target.checked_points` of a registration's source points."""
    return checked_points(source, "source points")


#: The grid `_matchable` last found matchable (one entry: the front end registers
#: every scan onto the same local map until it is rebuilt).
_MATCHABLE: list[GridTarget] = []


def _matchable(grid: GridTarget) -> bool:
    """`GridTarget.matchable`, remembered for the last grid that was: whether a grid
    has a matchable point is fixed by its points (lazy resolution only finds out)."""
    if _MATCHABLE and _MATCHABLE[0] is grid:
        return True
    if not grid.matchable():
        return False
    _MATCHABLE[:] = [grid]
    return True


def _register_grid(
    source: ArrayLike, target: GridTarget, initial: ArrayLike, config: IcpConfig | None,
    prior: ArrayLike | None, prior_covariance: ArrayLike | None, joins: Array,
    join_t: float, join_r: float,
) -> IcpResult | tuple[int, int]:
    """`register_fast`, or ``(row of joins, iterations)`` when the run came within
    (`join_t` [m], `join_r` [rad]) of one of the poses `joins` (``(K, 3)``) and
    stopped there (`register_target`).  One compiled call (`_register_kernel`): the
    few small numpy calls of the figures cost as much as the iterations."""
    cfg = config or target.config
    src = _source_points(source)
    x0 = np.asarray(initial, dtype=float).reshape(3).copy()
    x_prior, prior_cov = _NO_PRIOR, _NO_PRIOR_COV
    if prior is not None:
        if prior_covariance is None:
            raise UserError("register: a prior needs its prior_covariance (got None)")
        x_prior = np.asarray(prior, dtype=float).reshape(3).copy()
        prior_cov = np.ascontiguousarray(np.asarray(prior_covariance, dtype=float).reshape(3, 3))
    if len(src) < cfg.min_correspondences or not _matchable(target):
        return _failed(x0, 0, 0, None if prior is None else prior_cov)
    kernel, kconst = _KERNELS[cfg.kernel], KERNEL_CONSTANTS[cfg.kernel]
    nx, ny = target.shape
    (status, joined, iterations, converged, points, x, cov, h_data, sigma2, inliers, rms,
     fitness, degeneracy, axis) = _register_kernel(
        src, x0, float(target.origin[0]), float(target.origin[1]), target.cell, nx, ny,
        target.start, target.points, target.anchors, target.normals, target.kind,
        target.params, prior_cov, x_prior, prior is not None,
        cfg.max_iterations, cfg.max_correspondence_distance, cfg.min_correspondence_distance,
        cfg.gate_sigmas, kernel, kconst, cfg.min_residual_scale, cfg.clutter_weight,
        cfg.translation_tolerance, cfg.rotation_tolerance, cfg.min_correspondences,
        cfg.fitness_tolerance, joins, join_t, join_r)
    if status == 2:
        return int(joined), int(iterations)
    if status == 1:
        return _failed(x0, iterations, points, None if prior is None else prior_cov)
    return IcpResult(
        pose=x, covariance=cov, hessian=h_data, sigma=float(np.sqrt(sigma2)),
        inlier_ratio=inliers / len(src), rms=float(rms), fitness=float(fitness),
        degeneracy=float(degeneracy), degenerate_axis=axis, iterations=int(iterations),
        converged=bool(converged), correspondences=int(points), ok=True, initial=x0.copy(),
    )


#: Grid cell of `register_target` [m]: a cell holds a few points of a wall at the
#: check's submap resolution, and a 1 m gate visits 5 x 5 cells.
TARGET_GRID_CELL = 0.5

#: `register_target` stops a run whose iterate comes within this translation [m] and
#: rotation [rad] of where an earlier run ended: from there it follows the earlier
#: run's path to the same fixed point.  Well below the loop constraints' covariance
#: floor (2 cm, 0.5 degrees), and below the geometric check's ambiguity radius
#: (runs that end this close are one answer).
JOIN_TRANSLATION = 0.005
JOIN_ROTATION = float(np.radians(0.05))


@numba.njit(cache=True)
def _bound_kernel(src, guesses, reach, ox, oy, cell, nx, ny, start, pts, out):
    n = src.shape[0]
    for g in range(guesses.shape[0]):
        c, s = np.cos(guesses[g, 2]), np.sin(guesses[g, 2])
        hits = 0
        for i in range(n):
            px = c * src[i, 0] - s * src[i, 1] + guesses[g, 0]
            py = s * src[i, 0] + c * src[i, 1] + guesses[g, 1]
            j, _ = _nearest(px, py, reach, ox, oy, cell, nx, ny, start, pts)
            if j >= 0:
                hits += 1
        out[g] = hits / n


def overlap_bound(source: ArrayLike, grid: GridTarget, guesses: ArrayLike,
                  reach: float) -> Array:
    """``(K,)`` for each of `guesses` (``(K, 3)``, poses of the source frame in the
    grid's frame [m, m, rad]): the share of `source` points (``(N, 2)`` [m]) that
    have a map point of `grid` within `reach` [m] once moved by the guess,
    ``B_k = #{i : min_j |R_k p_i + t_k - q_j| <= reach} / N``.

    An upper bound of the inlier ratio (and so of the fitness, which never exceeds
    it) of any fit whose points lie within ``reach - fitness_tolerance`` of where
    guess ``k`` puts them: an inlier lies within the inlier tolerance of a map
    point's line, next to that point.  Nearest neighbours in the grid's cells
    (`_nearest`, exact); one compiled call for all guesses (0 without points)."""
    src = np.ascontiguousarray(as_points(source, "source points"))
    g = np.ascontiguousarray(np.asarray(guesses, dtype=float).reshape(-1, 3))
    out = np.zeros(len(g))
    if len(src) == 0 or len(grid.input_points) == 0:
        return out
    nx, ny = grid.shape
    _bound_kernel(src, g, float(reach), float(grid.origin[0]), float(grid.origin[1]),
                  grid.cell, nx, ny, grid.start, grid.points, out)
    return out


@numba.njit(cache=True)
def _screen_kernel(src, guesses, gate, reach, ox, oy, cell, nx, ny, start, pts, kind,
                   params, normals, anchors, scores, bounds):
    n = src.shape[0]
    radius = max(gate, reach)
    for g in range(guesses.shape[0]):
        c, s = np.cos(guesses[g, 2]), np.sin(guesses[g, 2])
        score = 0.0
        hits = 0
        for i in range(n):
            px = c * src[i, 0] - s * src[i, 1] + guesses[g, 0]
            py = s * src[i, 0] + c * src[i, 1] + guesses[g, 1]
            j, d = _nearest(px, py, radius, ox, oy, cell, nx, ny, start, pts)
            if j < 0:
                continue
            if d <= reach:
                hits += 1
            if d < gate and kind[j] < 0:
                resolve_point(j, pts, ox, oy, cell, nx, ny, start, params, normals, anchors,
                              kind)
            if d < gate and kind[j] != KIND_NONE:
                u = d / gate
                score += 1.0 - u * u
        scores[g] = score / n
        bounds[g] = hits / n


def overlap_screen(source: ArrayLike, grid: GridTarget, guesses: ArrayLike, gate: float,
                   reach: float) -> tuple[Array, Array]:
    """Both pre-ICP screens of a pose-gated check in one compiled pass over the
    guesses (`guesses` ``(K, 3)``, poses of the source frame in the grid's frame [m,
    m, rad]; `source` ``(N, 2)`` [m]): ``(scores, bounds)``, each ``(K,)``.

    ``scores``: `loopclosure.multi_start.overlap_scores` at tolerance `gate`,
    ``mean_i max(0, 1 - (d_i / gate)^2)`` with ``d_i`` the distance of moved point
    ``i`` to its nearest map point when that point is matchable (a kind other than
    `KIND_NONE`), 0 otherwise.  ``bounds``: `overlap_bound` at `reach`.  One nearest
    neighbour per point and guess within ``max(gate, reach)`` serves both (the
    nearest point within the larger radius is the nearest within the smaller one
    when it lies there).  Zeros without points."""
    src = np.ascontiguousarray(as_points(source, "source points"))
    g = np.ascontiguousarray(np.asarray(guesses, dtype=float).reshape(-1, 3))
    scores, bounds = np.zeros(len(g)), np.zeros(len(g))
    if len(src) == 0 or len(grid.input_points) == 0:
        return scores, bounds
    nx, ny = grid.shape
    _screen_kernel(src, g, float(gate), float(reach), float(grid.origin[0]),
                   float(grid.origin[1]), grid.cell, nx, ny, grid.start, grid.points,
                   grid.kind, grid.params, grid.normals, grid.anchors, scores, bounds)
    return scores, bounds


def register_target(source: ArrayLike, target: RegistrationTarget | None,
                    initials: ArrayLike, *, config: IcpConfig | None = None, join: bool = True,
                    grid: GridTarget | None = None) -> list[IcpResult]:
    """`loopclosure.registration.register` of `source` onto a prepared target from
    each of `initials` (``(K, 3)``), by the compiled kernel on one grid of the
    target (its points and normals, `GridTarget.from_target`) made for these runs
    and dropped after them: a grid per cached target would cost the loop detector's
    target cache tens of MB.

    With `join`, a run that comes within `JOIN_TRANSLATION` and `JOIN_ROTATION` of
    the end of an earlier run stops there and returns that run's result (its own
    `IcpResult.initial` and iterations): several guesses of a multi-start search
    mostly fall into one basin, and the iterations after they meet repeat the
    earlier run's.  `grid`: that grid when the caller has made it already (`target`
    may then be None)."""
    if grid is None:
        if target is None:
            raise UserError("register_target needs a target or its grid")
        grid = GridTarget.from_target(target, TARGET_GRID_CELL)
    results: list[IcpResult] = []
    ends = np.zeros((0, 3))
    owners: list[int] = []
    for x0 in np.asarray(initials, dtype=float).reshape(-1, 3):
        joins = ends if join else _NO_JOINS
        out = _register_grid(source, grid, x0, config, None, None, joins, JOIN_TRANSLATION,
                             JOIN_ROTATION)
        if isinstance(out, tuple):
            row, iterations = out
            out = dataclasses.replace(results[owners[row]], initial=x0.copy(),
                                      iterations=iterations)
        elif out.ok:
            ends = np.vstack([ends, out.pose])
            owners.append(len(results))
        results.append(out)
    return results


__all__ = ["ANCHORS", "JOIN_ROTATION", "JOIN_TRANSLATION", "KIND_CLUTTER", "KIND_LINE",
           "KIND_NONE", "KIND_UNKNOWN", "TARGET_GRID_CELL", "GridTarget", "estimate_normals_fast",
           "overlap_bound", "overlap_screen", "points_within", "register_fast",
           "register_target", "voxel_downsample_fast", "within_radius"]
