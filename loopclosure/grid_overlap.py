"""The pre-ICP screens of a pose-gated check on a `GridTarget`, compiled (numba,
``cache=True``): for a handful of guessed poses of a source point set, how much of
it lands near the map (`overlap_bound`) and how well (`overlap_screen`), with the
grid's exact nearest-neighbour search (`loopclosure.grid_nearest`).  Poses are
``(x, y, theta)`` [m, m, rad] of the source frame in the grid's frame.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from loopclosure.grid_nearest import _nearest
from loopclosure.grid_target import KIND_NONE, GridTarget, resolve_point
from loopclosure.icp_types import as_points
from loopclosure.kernel_cache import drop_stale

Array = NDArray[np.float64]


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
def _screen_point(px, py, gate, reach, ox, oy, cell, nx, ny, start, pts, kind, params,
                  normals, anchors):
    """One moved source point's share of both screens: ``(hit, term)``, ``hit`` 1
    when its nearest map point lies within `reach`, ``term`` ``1 - (d / gate)^2``
    when that point lies within `gate` and is matchable (its normal resolved here
    when still lazy), 0 otherwise."""
    j, d = _nearest(px, py, max(gate, reach), ox, oy, cell, nx, ny, start, pts)
    if j < 0:
        return 0, 0.0
    hit = 1 if d <= reach else 0
    if d < gate and kind[j] < 0:
        resolve_point(j, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind)
    if d < gate and kind[j] != KIND_NONE:
        u = d / gate
        return hit, 1.0 - u * u
    return hit, 0.0


@numba.njit(cache=True)
def _screen_kernel(src, guesses, gate, reach, ox, oy, cell, nx, ny, start, pts, kind,
                   params, normals, anchors, scores, bounds):
    n = src.shape[0]
    for g in range(guesses.shape[0]):
        c, s = np.cos(guesses[g, 2]), np.sin(guesses[g, 2])
        score = 0.0
        hits = 0
        for i in range(n):
            px = c * src[i, 0] - s * src[i, 1] + guesses[g, 0]
            py = s * src[i, 0] + c * src[i, 1] + guesses[g, 1]
            hit, term = _screen_point(px, py, gate, reach, ox, oy, cell, nx, ny, start, pts,
                                      kind, params, normals, anchors)
            hits += hit
            score += term
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


# numba's cache does not see edits of the callees' files (`loopclosure.kernel_cache`).
drop_stale(__name__, ("loopclosure.grid_nearest", "loopclosure.grid_target"))


__all__ = ["overlap_bound", "overlap_screen"]
