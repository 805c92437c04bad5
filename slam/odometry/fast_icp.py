"""Compiled scan-to-map ICP: `loopclosure.registration.register` for one scan, in numba.

The odometry front end registers every scan (200-400 points) onto its local map a
few times per scan.  With numpy and a `scipy.spatial.cKDTree`, each Gauss-Newton
iteration is a dozen small array calls whose fixed overhead (tens of microseconds
each) dominates the arithmetic; here the whole loop, nearest-neighbour search
included, is one compiled call (numba, ``cache=True``: compiled once per machine).

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
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from loopclosure.registration import (
    FAILED_VARIANCE,
    KERNEL_CONSTANTS,
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    as_points,
)

Array = NDArray[np.float64]

#: Point kinds of `GridTarget.kind`: no correspondence, point to line, point to point.
KIND_NONE, KIND_LINE, KIND_CLUTTER = 0, 1, 2
_KERNELS = {"none": 0, "cauchy": 1, "huber": 2, "tukey": 3}
_MAD = 1.4826


class GridTarget:
    """A `RegistrationTarget`'s points, normals and kinds in a cell grid for `register_fast`.

    Attributes:
        target: the `RegistrationTarget` it was built from (normals, KD-tree for the
            numpy code paths).
        cell: side of the grid cells [m].
        origin: ``(2,)`` lower-left corner of cell ``(0, 0)`` [m] (target frame).
        shape: ``(nx, ny)`` cells.
        start: ``(nx * ny + 1,)`` offsets: the points of cell ``(i, j)`` are
            ``order[start[i * ny + j] : start[i * ny + j + 1]]``.
        points, normals: ``(M, 2)`` sorted by cell [m].
        kind: ``(M,)`` `KIND_NONE`, `KIND_LINE` or `KIND_CLUTTER` (clutter counts
            only with `IcpConfig.point_to_point_clutter`).
    """

    __slots__ = ("cell", "kind", "normals", "origin", "points", "shape", "start", "target")

    def __init__(self, target: RegistrationTarget, cell: float = 0.25) -> None:
        if not (np.isfinite(cell) and cell > 0):
            raise UserError(f"grid cell must be a positive number of metres, got {cell}")
        self.target = target
        self.cell = float(cell)
        pts = target.points
        kind = np.zeros(len(pts), dtype=np.int8)
        kind[target.clutter] = KIND_CLUTTER if target.config.point_to_point_clutter else 0
        kind[target.usable] = KIND_LINE
        if len(pts) == 0:
            pts = np.zeros((1, 2))
            kind = np.zeros(1, dtype=np.int8)
            normals = np.zeros((1, 2))
        else:
            normals = target.normals
        lo = pts.min(axis=0) - self.cell
        cells = np.floor((pts - lo) / self.cell).astype(np.int64)
        nx, ny = int(cells[:, 0].max()) + 2, int(cells[:, 1].max()) + 2
        flat = cells[:, 0] * ny + cells[:, 1]
        order = np.argsort(flat, kind="stable")
        counts = np.bincount(flat, minlength=nx * ny)
        self.start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.origin = lo.astype(float)
        self.shape = (nx, ny)
        self.points = np.ascontiguousarray(pts[order], dtype=float)
        self.normals = np.ascontiguousarray(normals[order], dtype=float)
        self.kind = np.ascontiguousarray(kind[order])

    def __len__(self) -> int:
        return len(self.target)


@numba.njit(cache=True)
def _nearest(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """Index of the nearest grid point within `gate` of ``(px, py)`` (-1: none) and its distance."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    rings = int(np.ceil(gate / cell))
    best, best_d2 = -1, gate * gate
    i0, i1 = max(ci - rings, 0), min(ci + rings, nx - 1)
    j0, j1 = max(cj - rings, 0), min(cj + rings, ny - 1)
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            c = i * ny + j
            for k in range(start[c], start[c + 1]):
                dx = pts[k, 0] - px
                dy = pts[k, 1] - py
                d2 = dx * dx + dy * dy
                if d2 <= best_d2:
                    if d2 < best_d2 or best < 0 or k < best:
                        best, best_d2 = k, d2
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
def _rows(src, x, rows, lines, points, sel, jdx, pts, normals, r, jac, nrm):
    """Residuals ``r`` and Jacobian rows ``J`` at pose `x` of the given correspondences."""
    c, s = np.cos(x[2]), np.sin(x[2])
    clut = points - lines
    for k in range(rows):
        i, j = sel[k], jdx[k]
        rpx = c * src[i, 0] - s * src[i, 1]
        rpy = s * src[i, 0] + c * src[i, 1]
        if k < lines:
            n0, n1 = normals[j, 0], normals[j, 1]
        elif k < lines + clut:
            n0, n1 = 1.0, 0.0
        else:
            n0, n1 = 0.0, 1.0
        nrm[k, 0] = n0
        nrm[k, 1] = n1
        r[k] = n0 * (rpx + x[0] - pts[j, 0]) + n1 * (rpy + x[1] - pts[j, 1])
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
def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@numba.njit(cache=True)
def _icp(src, x0, ox, oy, cell, nx, ny, start, pts, normals, kind, lam, x_prior, has_prior,
         max_iterations, gate0, min_gate, gate_sigmas, kernel, kconst, min_scale, clutter_weight,
         t_tol, r_tol, min_corr):
    """Gauss-Newton ICP; returns (x, iterations, converged, ok, gate, rows, lines, points,
    sel, jdx) with the correspondences to evaluate (empty-matched when not converged)."""
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
            return x0.copy(), iterations, False, False, gate, rows, lines, points, sel, jdx
        _rows(src, x, rows, lines, points, sel, jdx, pts, normals, r, jac, nrm)
        s = max(min_scale, _MAD * _upper_median_abs(r, rows))
        _weights(r, rows, lines, points, s, kernel, kconst, clutter_weight, w)
        h, g = _normal_equations(r, jac, w, rows)
        h = h / (s * s) + lam
        g = g / (s * s)
        if has_prior:
            diff = x - x_prior
            diff[2] = _wrap(diff[2])
            g = g + lam @ diff
        damp = 1e-12 * max(np.trace(h), 1e-12)
        step = -np.linalg.solve(h + damp * np.eye(3), g)
        x = x + step
        x[2] = _wrap(x[2])
        new_gate = min(gate, max(min_gate, gate_sigmas * _MAD * _upper_median_abs(dist, rows)))
        small = np.hypot(step[0], step[1]) < t_tol and abs(step[2]) < r_tol
        settled = new_gate >= gate * (1.0 - 1e-6)
        gate = new_gate
        if small and settled:
            converged = True
            break
    if not converged:
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist)
    return x, iterations, converged, True, gate, rows, lines, points, sel, jdx


@numba.njit(cache=True)
def _figures(src, x, rows, lines, points, sel, jdx, pts, normals, kernel, kconst, min_scale,
             clutter_weight, fitness_tol):
    """Weighted residuals at the final pose: (h_data, wsum, wr2, inliers, rms, fitness)."""
    r = np.empty(rows)
    w = np.empty(rows)
    jac = np.empty((rows, 3))
    nrm = np.empty((rows, 2))
    _rows(src, x, rows, lines, points, sel, jdx, pts, normals, r, jac, nrm)
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


def _failed(initial: Array, iterations: int, count: int, prior_cov: Array | None) -> IcpResult:
    cov = FAILED_VARIANCE * np.eye(3) if prior_cov is None else prior_cov.copy()
    return IcpResult(
        pose=initial.copy(), covariance=cov, hessian=np.zeros((3, 3)), sigma=0.0,
        inlier_ratio=0.0, rms=0.0, fitness=0.0, degeneracy=0.0,
        degenerate_axis=np.array([1.0, 0.0]), iterations=iterations, converged=False,
        correspondences=count, ok=False, initial=initial.copy(),
    )


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
    cfg = config or target.target.config
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
    if target.target.tree is None or len(src) < cfg.min_correspondences:
        return _failed(x0, 0, 0, prior_cov)
    kernel, kconst = _KERNELS[cfg.kernel], KERNEL_CONSTANTS[cfg.kernel]
    nx, ny = target.shape
    grid = (float(target.origin[0]), float(target.origin[1]), target.cell, nx, ny,
            target.start, target.points)
    x, iterations, converged, ok, _gate, rows, lines, points, sel, jdx = _icp(
        src, x0, *grid, target.normals, target.kind, lam, x_prior, prior is not None,
        cfg.max_iterations, cfg.max_correspondence_distance, cfg.min_correspondence_distance,
        cfg.gate_sigmas, kernel, kconst, cfg.min_residual_scale, cfg.clutter_weight,
        cfg.translation_tolerance, cfg.rotation_tolerance, cfg.min_correspondences)
    if not ok or points < cfg.min_correspondences:
        return _failed(x0, iterations, points, prior_cov)
    h_data, wsum, wr2, inliers, rms, fitness = _figures(
        src, x, rows, lines, points, sel, jdx, target.points, target.normals, kernel, kconst,
        cfg.min_residual_scale, cfg.clutter_weight, cfg.fitness_tolerance)
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


__all__ = ["KIND_CLUTTER", "KIND_LINE", "KIND_NONE", "GridTarget", "register_fast"]
