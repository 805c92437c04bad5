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

Map normals (`GridTarget` from points): the same local PCA as
`loopclosure.registration.estimate_normals` (the `normal_neighbors` nearest points
closer than `normal_radius`, itself included; normal ``(-sin phi, cos phi)`` with
``phi = atan2(2 b, a - c) / 2`` of the neighbours' covariance ``[[a, b], [b, c]]``;
line-like when ``lambda_min <= max_normal_ratio * lambda_max`` and at least
`min_normal_neighbors` neighbours, clutter when enough neighbours but not
line-like), with the k nearest found in the grid; `estimate_normals_fast` gives the
same for a `RegistrationTarget` (its injected normal estimator).  `overlap_screen`
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

from data import se2
from data.errors import UserError
from loopclosure.registration import (
    KERNEL_CONSTANTS,
    LINE_ANCHORS,
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    _failed,  # the failed result of either ICP: the initial pose, no information
    as_points,
)

Array = NDArray[np.float64]

#: Point kinds of `GridTarget.kind`: no correspondence, point to line, point to point.
KIND_NONE, KIND_LINE, KIND_CLUTTER = 0, 1, 2
#: Where the line of a line-like map point passes: through the point itself (a voxel
#: centroid), or through the mean of the neighbours that gave its normal, which
#: averages their noise (``k`` points: the line's offset noise shrinks by ``sqrt(k)``).
ANCHORS: tuple[str, ...] = LINE_ANCHORS
_KERNELS = {"none": 0, "cauchy": 1, "huber": 2, "tukey": 3}
_MAD = 1.4826


class GridTarget:
    """Map points, normals and kinds in a cell grid for `register_fast`.

    Built from points (normals by `estimate_normals_fast`) or from a prepared
    `RegistrationTarget` (`from_target`: its normals, the numpy reference's).

    Attributes:
        config: the `IcpConfig` of the normals (and the default of `register_fast`).
        input_points: ``(M, 2)`` the points in the given order [m] (target frame).
        cell: side of the grid cells [m].
        origin: ``(2,)`` lower-left corner of cell ``(0, 0)`` [m] (target frame).
        shape: ``(nx, ny)`` cells.
        start: ``(nx * ny + 1,)`` offsets: the points of cell ``(i, j)`` are rows
            ``start[i * ny + j] : start[i * ny + j + 1]`` of `points`.
        points, normals: ``(M, 2)`` sorted by cell [m].
        kind: ``(M,)`` `KIND_NONE`, `KIND_LINE` or `KIND_CLUTTER` (clutter counts
            only with `IcpConfig.point_to_point_clutter`).
        anchor: ``"point"`` or ``"mean"`` (`ANCHORS`).
        anchor_radius: with ``"mean"``, only the normal neighbours closer than this
            to the point enter the mean [m] (a short stretch of wall: little bias
            where the wall curves or the map is sparse).
        anchor_band: with ``"mean"``, only neighbours whose offset along the normal
            is at most this enter it [m] (inf: all).
        anchors: ``(M, 2)`` the point each line-like point's line passes through:
            the point itself, or with ``"mean"`` the point moved along its normal by
            the mean normal offset of its normal neighbours within `anchor_radius`
            and `anchor_band` (for a straight wall: the mean of those neighbours).
    """

    __slots__ = ("_pca", "_target", "anchor", "anchor_band", "anchor_radius", "anchors", "cell",
                 "config",
                 "input_points", "kind", "normals", "origin", "points", "shape", "start")

    def __init__(self, points: ArrayLike, config: IcpConfig | None = None,
                 cell: float = 0.25, *, anchor: str = "point", anchor_radius: float = 0.2,
                 anchor_band: float = np.inf,
                 target: RegistrationTarget | None = None,
                 previous: GridTarget | None = None) -> None:
        if not (np.isfinite(cell) and cell > 0):
            raise UserError(f"grid cell must be a positive number of metres, got {cell}")
        if anchor not in ANCHORS:
            raise UserError(f"unknown line anchor {anchor!r}: choose one of {', '.join(ANCHORS)}")
        if anchor != "point" and target is not None:
            raise UserError("a grid made from a RegistrationTarget anchors lines at its points")
        if not anchor_radius > 0:
            raise UserError(f"line anchor radius must be positive, got {anchor_radius}")
        if not anchor_band > 0:
            raise UserError(f"line anchor band must be positive, got {anchor_band}")
        self.anchor = anchor
        self.anchor_radius = float(anchor_radius)
        self.anchor_band = float(anchor_band)
        self.config = config or (target.config if target is not None else IcpConfig())
        self.cell = float(cell)
        self._target = target
        pts = np.ascontiguousarray(as_points(points, "target points"))
        self.input_points = pts
        if len(pts) == 0:
            pts = np.zeros((1, 2))
        self.origin, self.shape, self.start, order = _cells(pts, self.cell)
        self.points = np.ascontiguousarray(pts[order], dtype=float)
        self._pca: _Pca | None = None
        means = self.points
        if len(self.input_points) == 0:
            normals, usable, clutter = np.zeros((1, 2)), np.zeros(1, bool), np.zeros(1, bool)
        elif target is not None:
            normals, usable, clutter = target.normals, target.usable, target.clutter
            normals, usable, clutter = normals[order], usable[order], clutter[order]
        else:
            normals, usable, clutter, means = _grid_normals(self, self.config, previous)
        anchors = self.points  # the same array unless lines pass through the mean
        if anchor == "mean":
            anchors = self.points.copy()
            anchors[usable] = means[usable]
        self.anchors = np.ascontiguousarray(anchors)
        kind = np.zeros(len(self.points), dtype=np.int8)
        if self.config.point_to_point_clutter:
            kind[clutter] = KIND_CLUTTER
        kind[usable] = KIND_LINE
        self.normals = np.ascontiguousarray(normals, dtype=float)
        self.kind = kind

    @classmethod
    def from_target(cls, target: RegistrationTarget, cell: float = 0.25) -> GridTarget:
        """The grid of a prepared `RegistrationTarget`, with its normals."""
        return cls(target.points, target.config, cell, target=target)

    @property
    def target(self) -> RegistrationTarget:
        """The numpy `RegistrationTarget` of the same points (built on first use)."""
        if self._target is None:
            self._target = RegistrationTarget(self.input_points, self.config)
        return self._target

    def __len__(self) -> int:
        """Number of points ICP can match."""
        return int(np.count_nonzero(self.kind))


@dataclasses.dataclass(frozen=True, slots=True)
class _Pca:
    """Per-point output of `_normals_kernel` for a grid's points (sorted by cell), kept
    so that the next grid of a changing map (`GridTarget` with ``previous``) can
    copy the points whose neighbourhood did not change: normals ``(M, 2)``,
    ``lambda_min / lambda_max`` ``(M,)``, neighbour counts ``(M,)`` and line anchors
    ``(M, 2)`` [m], whether two neighbours tied in distance ``(M,)``, and the
    parameters they were computed with."""

    normals: Array
    ratio: Array
    count: NDArray[np.int64]
    means: Array
    tie: NDArray[np.bool_]
    key: tuple[object, ...]


def _grid_normals(grid: GridTarget, cfg: IcpConfig, previous: GridTarget | None
                  ) -> tuple[Array, Array, Array, Array]:
    """Normals, line-like and clutter masks and line anchors of the grid's points.

    With `previous` (a grid of the same parameters, built from points), a point whose
    normal neighbourhood is unchanged takes its figures from there: every point within
    `normal_radius` of it (itself included) is in both maps at bit-identical
    coordinates, so `_normals_kernel` would find the same neighbours, in the same
    order of distance, and repeat the same arithmetic (`_reuse_kernel`).  Only the
    other points are computed."""
    nx, ny = grid.shape
    n = len(grid.points)
    k = min(cfg.normal_neighbors, n)
    key = (cfg, grid.cell, k, grid.anchor_radius, grid.anchor_band)
    normals = np.zeros((n, 2))
    means = grid.points.copy()
    ratio = np.full(n, np.inf)
    count = np.zeros(n, dtype=np.int64)
    tie = np.zeros(n, dtype=np.bool_)
    old = previous._pca if previous is not None else None
    if old is not None and old.key == key and previous is not None:
        pnx, pny = previous.shape
        which = _reuse_kernel(
            grid.points, float(grid.origin[0]), float(grid.origin[1]), grid.cell, nx, ny,
            grid.start, previous.points, float(previous.origin[0]),
            float(previous.origin[1]), pnx, pny, previous.start, cfg.normal_radius,
            old.normals, old.ratio, old.count, old.means, old.tie, normals, ratio, count,
            means)
    else:
        which = np.arange(n, dtype=np.int64)
    _normals_kernel(grid.points, float(grid.origin[0]), float(grid.origin[1]), grid.cell,
                    nx, ny, grid.start, k, cfg.normal_radius, grid.anchor_radius,
                    grid.anchor_band, which, normals, ratio, count, means, tie)
    grid._pca = _Pca(normals, ratio, count, means, tie, key)
    enough = count >= cfg.min_normal_neighbors
    if len(grid.points) < cfg.min_normal_neighbors:
        enough[:] = False
    line = enough & (ratio <= cfg.max_normal_ratio)
    return normals, line, enough & ~line, means


@numba.njit(cache=True)
def _normals_kernel(pts, ox, oy, cell, nx, ny, start, k, radius, anchor_radius, band, which,
                    normals, ratio, count, means, tie):
    """PCA normal, ``lambda_min / lambda_max`` and neighbour count of the points `which`
    (indices into `pts`, written into `normals`, `ratio`, `count` and `means` in place;
    the others untouched): its `k`
    nearest points (itself included) closer than `radius` (`loopclosure.registration`'s
    `estimate_normals`, the same equations), and the line anchor: the point moved along
    its normal by the mean normal offset ``n . (q - p)`` of those neighbours ``q``
    closer than `anchor_radius` whose offset is at most `band` (the other face of a
    thin wall or a nearby object does not pull the line).  Untouched entries of a
    point without neighbours: normal 0, ratio inf, count 0, anchor the point.

    `tie` is set where two of the neighbours kept (or the last kept and one dropped)
    are exactly equidistant: which of them is kept, or the order of the sums, then
    depends on the order the cells are visited in, not on the coordinates alone."""
    a2 = anchor_radius * anchor_radius
    rings = int(np.ceil(radius / cell))
    r2 = radius * radius
    bd = np.empty(k)
    bi = np.empty(k, dtype=np.int64)
    for p in which:
        px, py = pts[p, 0], pts[p, 1]
        ci = int(np.floor((px - ox) / cell))
        cj = int(np.floor((py - oy) / cell))
        m = 0
        for i in range(max(ci - rings, 0), min(ci + rings, nx - 1) + 1):
            for j in range(max(cj - rings, 0), min(cj + rings, ny - 1) + 1):
                c = i * ny + j
                for q in range(start[c], start[c + 1]):
                    dx = pts[q, 0] - px
                    dy = pts[q, 1] - py
                    d2 = dx * dx + dy * dy
                    if d2 >= r2:
                        continue
                    if m < k:
                        pos = m
                        m += 1
                    elif d2 < bd[k - 1]:
                        pos = k - 1
                    else:
                        if d2 == bd[k - 1]:
                            tie[p] = True
                        continue
                    while pos > 0 and bd[pos - 1] > d2:
                        bd[pos] = bd[pos - 1]
                        bi[pos] = bi[pos - 1]
                        pos -= 1
                    if pos > 0 and bd[pos - 1] == d2:
                        tie[p] = True
                    bd[pos] = d2
                    bi[pos] = q
        count[p] = m
        if m == 0:
            continue
        mx = 0.0
        my = 0.0
        for t in range(m):
            mx += pts[bi[t], 0]
            my += pts[bi[t], 1]
        mx /= m
        my /= m
        a = 0.0
        b = 0.0
        cc = 0.0
        for t in range(m):
            ex = pts[bi[t], 0] - mx
            ey = pts[bi[t], 1] - my
            a += ex * ex
            b += ex * ey
            cc += ey * ey
        a /= m
        b /= m
        cc /= m
        half = 0.5 * (a - cc)
        root = np.sqrt(half * half + b * b)
        lmax = 0.5 * (a + cc) + root
        lmin = 0.5 * (a + cc) - root
        phi = 0.5 * np.arctan2(2.0 * b, a - cc)
        n0, n1 = -np.sin(phi), np.cos(phi)
        normals[p, 0] = n0
        normals[p, 1] = n1
        off = 0.0
        na = 0
        for t in range(m):
            if bd[t] < a2:
                o = n0 * (pts[bi[t], 0] - px) + n1 * (pts[bi[t], 1] - py)
                if abs(o) <= band:
                    off += o
                    na += 1
        if na > 0:
            means[p, 0] = px + n0 * off / na
            means[p, 1] = py + n1 * off / na
        ratio[p] = max(lmin, 0.0) / lmax if lmax > 0 else 1.0


@numba.njit(cache=True)
def _cell_of(px, py, ox, oy, cell, nx, ny):
    """Flat index of the grid cell holding ``(px, py)`` (-1 outside the grid)."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    if ci < 0 or ci >= nx or cj < 0 or cj >= ny:
        return -1
    return ci * ny + cj


@numba.njit(cache=True)
def _mark_near(px, py, pts, ox, oy, cell, nx, ny, start, reach, dirty):
    """Mark `dirty` every grid point closer than `reach` to ``(px, py)``."""
    rings = int(np.ceil(reach / cell))
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    r2 = reach * reach
    for i in range(max(ci - rings, 0), min(ci + rings, nx - 1) + 1):
        for j in range(max(cj - rings, 0), min(cj + rings, ny - 1) + 1):
            c = i * ny + j
            for q in range(start[c], start[c + 1]):
                dx = pts[q, 0] - px
                dy = pts[q, 1] - py
                if dx * dx + dy * dy < r2:
                    dirty[q] = True


@numba.njit(cache=True)
def _reuse_kernel(pts, ox, oy, cell, nx, ny, start, old, pox, poy, pnx, pny, pstart, radius,
                  old_normals, old_ratio, old_count, old_means, old_tie, normals, ratio, count,
                  means):
    """Copy the normal figures of the unchanged points of a previous grid (same cell
    side): returns the indices of the points of `pts` that need `_normals_kernel`.

    A point of `pts` is matched to a point of `old` at bit-identical coordinates
    (looked up in its cell of the previous grid).  The changed points are the
    unmatched ones of either map; a point is clean when it is matched and no changed
    point lies closer than `radius` (a hair more: rounding only makes more points
    dirty) -- its neighbourhood within `radius` is then the same set of coordinates
    in both maps.  Clean points get the previous figures, except where two
    neighbours tied in distance (`_normals_kernel`): their order of visit may differ
    in the new grid, so they are computed again."""
    n = pts.shape[0]
    match = np.full(n, -1, dtype=np.int64)
    used = np.zeros(old.shape[0], dtype=np.bool_)
    for p in range(n):
        c = _cell_of(pts[p, 0], pts[p, 1], pox, poy, cell, pnx, pny)
        if c < 0:
            continue
        for q in range(pstart[c], pstart[c + 1]):
            if old[q, 0] == pts[p, 0] and old[q, 1] == pts[p, 1]:
                match[p] = q
                used[q] = True
                break
    reach = radius * (1.0 + 1e-9) + 1e-12
    dirty = np.zeros(n, dtype=np.bool_)
    for p in range(n):
        if match[p] < 0:
            dirty[p] = True
            _mark_near(pts[p, 0], pts[p, 1], pts, ox, oy, cell, nx, ny, start, reach, dirty)
    for q in range(old.shape[0]):
        if not used[q]:
            _mark_near(old[q, 0], old[q, 1], pts, ox, oy, cell, nx, ny, start, reach, dirty)
    todo = 0
    for p in range(n):
        if not dirty[p] and old_tie[match[p]]:
            dirty[p] = True
        if dirty[p]:
            todo += 1
            continue
        q = match[p]
        normals[p, 0] = old_normals[q, 0]
        normals[p, 1] = old_normals[q, 1]
        ratio[p] = old_ratio[q]
        count[p] = old_count[q]
        means[p, 0] = old_means[q, 0]
        means[p, 1] = old_means[q, 1]
    which = np.empty(todo, dtype=np.int64)
    t = 0
    for p in range(n):
        if dirty[p]:
            which[t] = p
            t += 1
    return which


def _cells(pts: Array, cell: float) -> tuple[Array, tuple[int, int], Array, Array]:
    """CSR cell layout of `pts` (`GridTarget`): origin, shape ``(nx, ny)``, start
    offsets and the stable order that sorts the points by cell."""
    lo = pts.min(axis=0) - cell
    cells = np.floor((pts - lo) / cell).astype(np.int64)
    nx, ny = int(cells[:, 0].max()) + 2, int(cells[:, 1].max()) + 2
    flat = cells[:, 0] * ny + cells[:, 1]
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=nx * ny)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return lo.astype(float), (nx, ny), start, order


def estimate_normals_fast(points: ArrayLike, config: IcpConfig
                          ) -> tuple[Array, NDArray[np.bool_], Array]:
    """`loopclosure.registration.estimate_normals`, compiled (a
    `loopclosure.registration.NormalsFn`): unit normals ``(M, 2)``, the line-like
    mask ``(M,)`` and ``lambda_min / lambda_max`` (inf with fewer than
    `min_normal_neighbors` neighbours) of `points` ``(M, 2)`` [m], in their order.

    The same local PCA (`_normals_kernel`: the `normal_neighbors` nearest points
    closer than `normal_radius`, itself included; the module docstring's
    equations), the neighbours found ring by ring in cells of side `normal_radius`
    instead of by a KD-tree.  Points sorted into cells, results put back in order."""
    pts = np.ascontiguousarray(as_points(points, "target points"))
    n = len(pts)
    if n < config.min_normal_neighbors:
        return np.zeros((n, 2)), np.zeros(n, dtype=bool), np.full(n, np.inf)
    cell = float(config.normal_radius)
    origin, (nx, ny), start, order = _cells(pts, cell)
    sorted_pts = np.ascontiguousarray(pts[order])
    k = min(config.normal_neighbors, n)
    normals_s, ratio_s = np.zeros((n, 2)), np.full(n, np.inf)
    count_s = np.zeros(n, dtype=np.int64)
    _normals_kernel(sorted_pts, float(origin[0]), float(origin[1]), cell, nx, ny, start, k,
                    config.normal_radius, 0.0, np.inf, np.arange(n, dtype=np.int64),
                    normals_s, ratio_s, count_s, sorted_pts.copy(), np.zeros(n, dtype=np.bool_))
    normals = np.empty_like(normals_s)
    normals[order] = normals_s
    ratio = np.empty(n)
    ratio[order] = np.where(count_s >= config.min_normal_neighbors, ratio_s, np.inf)
    line_like = ratio <= config.max_normal_ratio
    return normals, line_like, ratio


def voxel_downsample_fast(points: ArrayLike, voxel: float) -> Array:
    """`loopclosure.registration.voxel_downsample`, compiled: the centroid of the points
    in each ``voxel x voxel`` cell [m], cells in the order of their first point;
    ``voxel <= 0`` returns a float copy."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    if voxel <= 0 or len(pts) == 0:
        return pts.copy()
    cells = np.floor(pts / voxel).astype(np.int64)
    key = (cells[:, 0] << 32) ^ (cells[:, 1] & 0xFFFFFFFF)
    # numpy's stable sort (timsort) is several times numba's mergesort on these keys.
    return _voxel_kernel(pts, key, np.argsort(key, kind="stable"))


@numba.njit(cache=True)
def _voxel_kernel(pts, key, order):
    """Centroids of the runs of equal `key` along `order` (a stable argsort of `key`:
    each cell's points summed in index order), output in the order of each cell's
    first point (found by a pass over the indices, no second sort)."""
    n = len(key)
    sums = np.zeros((n, 2))
    counts = np.zeros(n)
    group_at = np.full(n, -1, dtype=np.int64)  # cell of the point that opens it
    g = -1
    for t in range(n):
        i = order[t]
        if t == 0 or key[i] != key[order[t - 1]]:
            g += 1
            group_at[i] = g  # the smallest index of the run: the sort is stable
        sums[g, 0] += pts[i, 0]
        sums[g, 1] += pts[i, 1]
        counts[g] += 1.0
    out = np.empty((g + 1, 2))
    row = 0
    for i in range(n):
        h = group_at[i]
        if h >= 0:
            out[row, 0] = sums[h, 0] / counts[h]
            out[row, 1] = sums[h, 1] / counts[h]
            row += 1
    return out


@numba.njit(cache=True)
def _scan_cell(c, px, py, start, pts, best, best_d2):
    for k in range(start[c], start[c + 1]):
        dx = pts[k, 0] - px
        dy = pts[k, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and (best < 0 or k < best)):
            best, best_d2 = k, d2
    return best, best_d2


@numba.njit(cache=True)
def _nearest(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """Index of the nearest grid point within `gate` of ``(px, py)`` (-1: none) and its
    distance.  Cells are visited ring by ring (Chebyshev distance from the query's cell);
    after ring ``r`` nothing nearer than ``r * cell + m`` can remain (``m``: distance of
    the query to its own cell's border), so the search stops there once a point at most
    that far is found."""
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
            edge = i == ci - r or i == ci + r
            step = 1 if edge else 2 * r
            j = cj - r
            while j <= cj + r:
                if 0 <= j < ny:
                    best, best_d2 = _scan_cell(i * ny + j, px, py, start, pts, best, best_d2)
                if step == 0:
                    break
                j += step
        if best >= 0 and best_d2 <= (r * cell + margin) ** 2:
            break
    return best, np.sqrt(best_d2)


@numba.njit(cache=True)
def _upper_median_abs(values, n):
    a = np.abs(values[:n])
    a.sort()
    return a[n // 2]


@numba.njit(cache=True)
def _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind, sel, jdx, dist):
    """Rows of the correspondences at pose `x`: point-to-line rows first, then the x rows
    and the y rows of the point-to-point matches.  Returns (rows, lines, points)."""
    n = src.shape[0]
    c, s = np.cos(x[2]), np.sin(x[2])
    lines = 0
    clut = 0
    csel = np.empty(n, dtype=np.int64)
    cj = np.empty(n, dtype=np.int64)
    cd = np.empty(n)
    for i in range(n):
        px = c * src[i, 0] - s * src[i, 1] + x[0]
        py = s * src[i, 0] + c * src[i, 1] + x[1]
        j, d = _nearest(px, py, gate, ox, oy, cell, nx, ny, start, pts)
        if j < 0:
            continue
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
def _icp(src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind, lam, x_prior,
         has_prior,
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
    x = x0.copy()
    gate = gate0
    iterations = 0
    converged = False
    rows = lines = points = 0
    for it in range(1, max_iterations + 1):
        iterations = it
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist)
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
                                     sel, jdx, dist)
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


def _register_grid(
    source: ArrayLike, target: GridTarget, initial: ArrayLike, config: IcpConfig | None,
    prior: ArrayLike | None, prior_covariance: ArrayLike | None, joins: Array,
    join_t: float, join_r: float,
) -> IcpResult | tuple[int, int]:
    """`register_fast`, or ``(row of joins, iterations)`` when the run came within
    (`join_t` [m], `join_r` [rad]) of one of the poses `joins` (``(K, 3)``) and
    stopped there (`register_target`)."""
    cfg = config or target.config
    src = np.ascontiguousarray(as_points(source, "source points"))
    x0 = np.asarray(initial, dtype=float).reshape(3).copy()
    lam = np.zeros((3, 3))
    x_prior = np.zeros(3)
    prior_cov = None
    if prior is not None:
        if prior_covariance is None:
            raise UserError("register: a prior needs its prior_covariance (got None)")
        x_prior = np.asarray(prior, dtype=float).reshape(3).copy()
        prior_cov = np.asarray(prior_covariance, dtype=float).reshape(3, 3)
        lam = np.linalg.inv(prior_cov)
    if len(target) == 0 or len(src) < cfg.min_correspondences:
        return _failed(x0, 0, 0, prior_cov)
    kernel, kconst = _KERNELS[cfg.kernel], KERNEL_CONSTANTS[cfg.kernel]
    nx, ny = target.shape
    grid = (float(target.origin[0]), float(target.origin[1]), target.cell, nx, ny,
            target.start, target.points)
    x, iterations, converged, ok, _gate, rows, lines, points, sel, jdx, joined = _icp(
        src, x0, *grid, target.anchors, target.normals, target.kind, lam, x_prior,
        prior is not None,
        cfg.max_iterations, cfg.max_correspondence_distance, cfg.min_correspondence_distance,
        cfg.gate_sigmas, kernel, kconst, cfg.min_residual_scale, cfg.clutter_weight,
        cfg.translation_tolerance, cfg.rotation_tolerance, cfg.min_correspondences,
        joins, join_t, join_r)
    if joined >= 0:
        return int(joined), int(iterations)
    if not ok or points < cfg.min_correspondences:
        return _failed(x0, iterations, points, prior_cov)
    h_data, wsum, wr2, inliers, rms, fitness = _figures(
        src, x, rows, lines, points, sel, jdx, target.points, target.anchors, target.normals,
        kernel, kconst, cfg.min_residual_scale, cfg.clutter_weight, cfg.fitness_tolerance)
    sigma2 = max(wr2 / max(wsum - 3.0, 1.0), cfg.min_residual_scale**2)
    info = h_data / sigma2 + lam
    cov = np.linalg.inv(info + 1e-12 * max(np.trace(info), 1e-12) * np.eye(3))
    cov = 0.5 * (cov + cov.T)
    h_tt = h_data[:2, :2]
    if h_data[2, 2] > 1e-12:
        h_tt = h_tt - np.outer(h_data[:2, 2], h_data[2, :2]) / h_data[2, 2]
    evals, evecs = np.linalg.eigh(h_tt)
    degeneracy = float(np.clip(evals[0] / wsum, 0.0, 0.5)) if wsum > 0 else 0.0
    x[2] = float(se2.wrap_angle(x[2]))
    return IcpResult(
        pose=x, covariance=cov, hessian=h_data, sigma=float(np.sqrt(sigma2)),
        inlier_ratio=inliers / len(src), rms=float(rms), fitness=float(fitness),
        degeneracy=degeneracy, degenerate_axis=evecs[:, 0].copy(), iterations=int(iterations),
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
                   scores, bounds):
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
                   grid.kind, scores, bounds)
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
           "KIND_NONE", "TARGET_GRID_CELL", "GridTarget", "estimate_normals_fast",
           "overlap_bound", "overlap_screen", "register_fast", "register_target",
           "voxel_downsample_fast"]
