"""The map side of the compiled ICP (`loopclosure.fast_icp`): points in a cell grid
with their PCA normals and kinds (`GridTarget`), and the compiled normal estimator.

Cell grid: the map points are bucketed in square cells of side `cell` [m] (a CSR
layout: points sorted by cell, stable within a cell, one start offset per cell).

Map normals: the same local PCA as `loopclosure.registration.estimate_normals` (the
`normal_neighbors` nearest points closer than `normal_radius`, itself included;
normal ``(-sin phi, cos phi)`` with ``phi = atan2(2 b, a - c) / 2`` of the
neighbours' covariance ``[[a, b], [b, c]]``; line-like when ``lambda_min <=
max_normal_ratio * lambda_max`` and at least `min_normal_neighbors` neighbours,
clutter when enough neighbours but not line-like), with the k nearest found in the
grid.  A grid made with ``lazy=True`` computes a point's normal and kind the first
time ICP or the overlap screen finds it as a nearest neighbour (`resolve_point`):
the same computation on the same grid, so the same figures, for the few points a
scan touches instead of the whole map.  `estimate_normals_fast` gives the same
normals for a `RegistrationTarget` (its injected normal estimator).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.icp_types import LINE_ANCHORS, IcpConfig, as_points
from loopclosure.registration_target import RegistrationTarget

Array = NDArray[np.float64]

#: Point kinds of `GridTarget.kind`: no correspondence, point to line, point to point.
KIND_NONE, KIND_LINE, KIND_CLUTTER = 0, 1, 2
#: Kind of a point of a lazy grid whose normal is not computed yet.
KIND_UNKNOWN = -1
#: Where the line of a line-like map point passes: through the point itself (a voxel
#: centroid), or through the mean of the neighbours that gave its normal, which
#: averages their noise (``k`` points: the line's offset noise shrinks by ``sqrt(k)``).
ANCHORS: tuple[str, ...] = LINE_ANCHORS


class GridTarget:
    """Map points, normals and kinds in a cell grid for `loopclosure.fast_icp`.

    Built from points (normals by the grid's own PCA, all at once or, with `lazy`,
    each when first needed) or from a prepared `RegistrationTarget` (`from_target`:
    its normals, the numpy reference's).

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
            only with `IcpConfig.point_to_point_clutter`); `KIND_UNKNOWN` for the
            points of a lazy grid not resolved yet (their normal and anchor are
            not set either).
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
        params: ``(9,)`` what the compiled kernels need to resolve a point of a lazy
            grid (`resolve_point`): k, normal radius [m], anchor radius [m], anchor
            band [m], minimum neighbours, maximum eigenvalue ratio, clutter matched
            (0/1), mean anchor (0/1), enough points in the map (0/1).
    """

    __slots__ = ("_target", "anchor", "anchor_band", "anchor_radius", "anchors", "cell",
                 "config", "input_points", "kind", "normals", "origin", "params", "points",
                 "shape", "start")

    def __init__(self, points: ArrayLike, config: IcpConfig | None = None,
                 cell: float = 0.25, *, anchor: str = "point", anchor_radius: float = 0.2,
                 anchor_band: float = np.inf,
                 target: RegistrationTarget | None = None, lazy: bool = False) -> None:
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
        self.config = cfg = config or (target.config if target is not None else IcpConfig())
        self.cell = float(cell)
        self._target = target
        pts = _target_points(points)
        self.input_points = pts
        if len(pts) == 0:
            pts = np.zeros((1, 2))
        self.origin, self.shape, self.start, order, self.points = _cells_sorted(pts, self.cell)
        n = len(self.points)
        self.params = np.array([
            min(cfg.normal_neighbors, n), cfg.normal_radius, self.anchor_radius,
            self.anchor_band, cfg.min_normal_neighbors, cfg.max_normal_ratio,
            float(cfg.point_to_point_clutter), float(anchor == "mean"),
            float(n >= cfg.min_normal_neighbors)])
        if lazy and target is None and len(self.input_points) > 0:
            self.normals = np.zeros((n, 2))
            self.kind = np.full(n, KIND_UNKNOWN, dtype=np.int8)
            self.anchors = self.points.copy() if anchor == "mean" else self.points
            return
        means = self.points
        if len(self.input_points) == 0:
            normals, usable, clutter = np.zeros((1, 2)), np.zeros(1, bool), np.zeros(1, bool)
        elif target is not None:
            normals, usable, clutter = target.normals, target.usable, target.clutter
            normals, usable, clutter = normals[order], usable[order], clutter[order]
        else:
            normals, usable, clutter, means = _grid_normals(self, cfg)
        anchors = self.points  # the same array unless lines pass through the mean
        if anchor == "mean":
            anchors = self.points.copy()
            anchors[usable] = means[usable]
        self.anchors = np.ascontiguousarray(anchors)
        kind = np.zeros(len(self.points), dtype=np.int8)
        if cfg.point_to_point_clutter:
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

    def resolve(self, count: int | None = None) -> int:
        """Resolve the points of a lazy grid in order until `count` of them are
        matchable (None: all points); returns how many matchable points were met."""
        goal = -1 if count is None else int(count)
        return int(_resolve_until(goal, self.points, float(self.origin[0]),
                                  float(self.origin[1]), self.cell, self.shape[0],
                                  self.shape[1], self.start, self.params, self.normals,
                                  self.anchors, self.kind))

    def matchable(self) -> bool:
        """Whether ICP can match any point (``len(self) > 0``, resolving at most the
        points up to the first matchable one of a lazy grid)."""
        return self.resolve(1) > 0

    def __len__(self) -> int:
        """Number of points ICP can match (resolves every point of a lazy grid)."""
        self.resolve()
        return int(np.count_nonzero(self.kind))


def _grid_normals(grid: GridTarget, cfg: IcpConfig) -> tuple[Array, Array, Array, Array]:
    nx, ny = grid.shape
    n = len(grid.points)
    normals, ratio = np.zeros((n, 2)), np.full(n, np.inf)
    count, means = np.zeros(n, dtype=np.int64), grid.points.copy()
    _normals_kernel(grid.points, float(grid.origin[0]), float(grid.origin[1]), grid.cell,
                    nx, ny, grid.start, min(cfg.normal_neighbors, n), cfg.normal_radius,
                    grid.anchor_radius, grid.anchor_band, normals, ratio, count, means)
    enough = count >= cfg.min_normal_neighbors
    if len(grid.points) < cfg.min_normal_neighbors:
        enough[:] = False
    line = enough & (ratio <= cfg.max_normal_ratio)
    return normals, line, enough & ~line, means


@numba.njit(cache=True)
def _point_pca(p, pts, ox, oy, cell, nx, ny, start, k, radius, anchor_radius, band, bd, bi):
    """PCA of point `p`: its `k` nearest points (itself included) closer than `radius`
    (`loopclosure.registration`'s `estimate_normals`, the same equations), found in
    the grid's cells (scratch `bd`, `bi` of length `k`), and its line anchor: the
    point moved along its normal by the mean normal offset ``n . (q - p)`` of those
    neighbours ``q`` closer than `anchor_radius` whose offset is at most `band` (the
    other face of a thin wall or a nearby object does not pull the line).

    Returns (neighbours, normal x, normal y, ``lambda_min / lambda_max``, anchor x,
    anchor y); without neighbours (0, 0, 0, inf, the point)."""
    a2 = anchor_radius * anchor_radius
    rings = int(np.ceil(radius / cell))
    r2 = radius * radius
    # A cell farther than this from the point holds no neighbour (the slack covers
    # the rounding of the cell a point was put in); skipping it changes nothing.
    slack = 1e-6 * (1.0 + radius)
    far = radius + slack
    # Once `k` neighbours are held, a cell whose gap exceeds the k-th distance by the
    # same slack holds only points the test ``d2 < bd[k - 1]`` rejects (the k-th
    # distance never grows): skipping it changes nothing either.  `beyond` is that
    # gap squared (a relative 1e-9 above it), inf while fewer than `k` are held.
    beyond = np.inf
    px, py = pts[p, 0], pts[p, 1]
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    m = 0
    for i in range(max(ci - rings, 0), min(ci + rings, nx - 1) + 1):
        gx = max(ox + i * cell - px, px - (ox + (i + 1) * cell), 0.0)
        for j in range(max(cj - rings, 0), min(cj + rings, ny - 1) + 1):
            gy = max(oy + j * cell - py, py - (oy + (j + 1) * cell), 0.0)
            gap2 = gx * gx + gy * gy
            if gap2 >= far * far or gap2 >= beyond:
                continue
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
                    continue
                while pos > 0 and bd[pos - 1] > d2:
                    bd[pos] = bd[pos - 1]
                    bi[pos] = bi[pos - 1]
                    pos -= 1
                bd[pos] = d2
                bi[pos] = q
                if m == k:
                    reach = np.sqrt(bd[k - 1]) + slack
                    beyond = reach * reach * (1.0 + 1e-9)
    if m == 0:
        return 0, 0.0, 0.0, np.inf, px, py
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
    off = 0.0
    na = 0
    for t in range(m):
        if bd[t] < a2:
            o = n0 * (pts[bi[t], 0] - px) + n1 * (pts[bi[t], 1] - py)
            if abs(o) <= band:
                off += o
                na += 1
    ax, ay = px, py
    if na > 0:
        ax = px + n0 * off / na
        ay = py + n1 * off / na
    ratio = max(lmin, 0.0) / lmax if lmax > 0 else 1.0
    return m, n0, n1, ratio, ax, ay


@numba.njit(cache=True)
def _normals_kernel(pts, ox, oy, cell, nx, ny, start, k, radius, anchor_radius, band,
                    normals, ratio, count, means):
    """`_point_pca` of every point, written into `normals`, `ratio`, `count` and
    `means` (the anchors) in place."""
    bd = np.empty(k)
    bi = np.empty(k, dtype=np.int64)
    for p in range(pts.shape[0]):
        m, n0, n1, rt, ax, ay = _point_pca(p, pts, ox, oy, cell, nx, ny, start, k, radius,
                                           anchor_radius, band, bd, bi)
        count[p] = m
        if m == 0:
            continue
        normals[p, 0] = n0
        normals[p, 1] = n1
        means[p, 0] = ax
        means[p, 1] = ay
        ratio[p] = rt


@numba.njit(cache=True)
def resolve_point(p, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind):
    """Normal, kind and anchor of point `p` of a lazy grid (`GridTarget.params`), as
    the eager grid computes them (`_point_pca`, then the kind rules of the module
    docstring); written into `normals`, `anchors` and `kind` in place."""
    k = int(params[0])
    bd = np.empty(k)
    bi = np.empty(k, dtype=np.int64)
    m, n0, n1, rt, ax, ay = _point_pca(p, pts, ox, oy, cell, nx, ny, start, k, params[1],
                                       params[2], params[3], bd, bi)
    if m > 0:
        normals[p, 0] = n0
        normals[p, 1] = n1
    enough = m >= params[4] and params[8] > 0.0
    if enough and rt <= params[5]:
        kind[p] = 1  # KIND_LINE
        if params[7] > 0.0:
            anchors[p, 0] = ax
            anchors[p, 1] = ay
    elif enough and params[6] > 0.0:
        kind[p] = 2  # KIND_CLUTTER
    else:
        kind[p] = 0  # KIND_NONE


@numba.njit(cache=True)
def _resolve_until(goal, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind):
    """Resolve points in order until `goal` matchable ones were met (-1: all)."""
    met = 0
    for p in range(pts.shape[0]):
        if kind[p] < 0:
            resolve_point(p, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind)
        if kind[p] > 0:
            met += 1
            if met == goal:
                break
    return met


def checked_points(points: ArrayLike, what: str) -> Array:
    """``np.ascontiguousarray(as_points(points, what))``: the same array and the same
    error; a C-contiguous ``(M, 2)`` float64 array (every scan and local map of the
    front end) is checked by one compiled pass instead of numpy's conversions and
    reduction."""
    if (type(points) is np.ndarray and points.dtype == np.float64 and points.ndim == 2
            and points.shape[1] == 2 and points.flags.c_contiguous):
        if not _all_finite(points):
            raise UserError(f"{what} holds non-finite coordinates")
        return points
    return np.ascontiguousarray(as_points(points, what))


def _target_points(points: ArrayLike) -> Array:
    """`checked_points` of a grid's target points."""
    return checked_points(points, "target points")


@numba.njit(cache=True)
def _all_finite(pts):
    for i in range(pts.shape[0]):
        if not (np.isfinite(pts[i, 0]) and np.isfinite(pts[i, 1])):
            return False
    return True


def _cells(pts: Array, cell: float) -> tuple[Array, tuple[int, int], Array, Array]:
    """CSR cell layout of `pts` (``(M, 2)`` finite [m], `GridTarget`): origin [m],
    shape ``(nx, ny)``, start offsets and the stable order that sorts the points by
    cell."""
    origin, shape, start, order, _ = _cells_sorted(pts, cell)
    return origin, shape, start, order


def _cells_sorted(pts: Array, cell: float
                  ) -> tuple[Array, tuple[int, int], Array, Array, Array]:
    """`_cells` of `pts` (``(M, 2)`` finite, M >= 1) and the points sorted by cell
    (``pts[order]``, C-contiguous), in one compiled call (`_cells_kernel`)."""
    lox, loy, nx, ny, start, order, ordered = _cells_kernel(
        np.ascontiguousarray(pts, dtype=float), float(cell))
    return np.array([lox, loy]), (int(nx), int(ny)), start, order, ordered


@numba.njit(cache=True)
def _cells_kernel(pts, cell):
    """The cell layout of `pts` (``(M, 2)`` finite [m], M >= 1): the lower-left corner
    ``lo = min(pts) - cell`` (per axis), cells ``floor((p - lo) / cell)`` (one more
    row and column than the largest index, as a margin), their CSR offsets, the
    stable order that sorts the points by flat cell ``i * ny + j`` and the points in
    that order.  The same operations as ``pts.min(axis=0) - cell``, ``np.floor((pts -
    lo) / cell).astype(np.int64)`` and `_counting_sort`, so the same cells, without
    numpy's calls on small arrays (a local map is rebuilt for most scans of logs with
    a scan a metre)."""
    n = pts.shape[0]
    lox = pts[0, 0]
    loy = pts[0, 1]
    for i in range(1, n):
        lox = min(lox, pts[i, 0])
        loy = min(loy, pts[i, 1])
    lox -= cell
    loy -= cell
    ci = np.empty(n, dtype=np.int64)
    cj = np.empty(n, dtype=np.int64)
    mi = 0
    mj = 0
    for i in range(n):
        a = np.int64(np.floor((pts[i, 0] - lox) / cell))
        b = np.int64(np.floor((pts[i, 1] - loy) / cell))
        ci[i] = a
        cj[i] = b
        mi = max(mi, a)
        mj = max(mj, b)
    nx = mi + 2
    ny = mj + 2
    flat = ci * ny + cj
    start, order = _counting_sort(flat, nx * ny)
    ordered = np.empty((n, 2))
    for t in range(n):
        ordered[t, 0] = pts[order[t], 0]
        ordered[t, 1] = pts[order[t], 1]
    return lox, loy, nx, ny, start, order, ordered


@numba.njit(cache=True)
def _counting_sort(flat, cells):
    """CSR offsets ``(cells + 1,)`` of the cell indices `flat` and the stable order
    that sorts them (`np.argsort` with ``kind="stable"``), by counting: one pass
    over the points and one over the cells."""
    start = np.zeros(cells + 1, dtype=np.int64)
    for f in flat:
        start[f + 1] += 1
    for c in range(cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(len(flat), dtype=np.int64)
    for i in range(len(flat)):
        order[fill[flat[i]]] = i
        fill[flat[i]] += 1
    return start, order


def estimate_normals_fast(points: ArrayLike, config: IcpConfig
                          ) -> tuple[Array, NDArray[np.bool_], Array]:
    """`loopclosure.registration.estimate_normals`, compiled (a
    `loopclosure.registration.NormalsFn`): unit normals ``(M, 2)``, the line-like
    mask ``(M,)`` and ``lambda_min / lambda_max`` (inf with fewer than
    `min_normal_neighbors` neighbours) of `points` ``(M, 2)`` [m], in their order.

    The same local PCA (`_point_pca`: the `normal_neighbors` nearest points closer
    than `normal_radius`, itself included; the module docstring's equations), the
    neighbours found ring by ring in cells of side `normal_radius` instead of by a
    KD-tree.  Points sorted into cells, results put back in order."""
    pts = np.ascontiguousarray(as_points(points, "target points"))
    n = len(pts)
    if n < config.min_normal_neighbors:
        return np.zeros((n, 2)), np.zeros(n, dtype=bool), np.full(n, np.inf)
    cell = float(config.normal_radius)
    origin, (nx, ny), start, order, sorted_pts = _cells_sorted(pts, cell)
    k = min(config.normal_neighbors, n)
    normals_s, ratio_s = np.zeros((n, 2)), np.full(n, np.inf)
    count_s = np.zeros(n, dtype=np.int64)
    _normals_kernel(sorted_pts, float(origin[0]), float(origin[1]), cell, nx, ny, start, k,
                    config.normal_radius, 0.0, np.inf, normals_s, ratio_s, count_s,
                    sorted_pts.copy())
    normals = np.empty_like(normals_s)
    normals[order] = normals_s
    ratio = np.empty(n)
    ratio[order] = np.where(count_s >= config.min_normal_neighbors, ratio_s, np.inf)
    line_like = ratio <= config.max_normal_ratio
    return normals, line_like, ratio


__all__ = ["ANCHORS", "KIND_CLUTTER", "KIND_LINE", "KIND_NONE", "KIND_UNKNOWN", "GridTarget",
           "estimate_normals_fast", "resolve_point"]
