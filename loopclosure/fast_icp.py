"""Compiled point-to-line ICP: `loopclosure.registration.register`, in numba.

The odometry front end registers every scan (200-400 points) onto its local map a
few times per scan, and the geometric check registers a keyframe's submap onto a
candidate's from several starts (`register_multi`, `loopclosure.prior_free`).
With numpy and a `scipy.spatial.cKDTree`, each Gauss-Newton iteration is a dozen
small array calls whose fixed overhead (tens of microseconds each) dominates the
arithmetic; here the whole loop, nearest-neighbour search included, is one compiled
call (numba, ``cache=True``: compiled once per machine).  Same maths, frames, units
and figures as `loopclosure.registration.register`.

This module is the front door of the compiled ICP and its Python side (arguments
checked, the kernel called, the `IcpResult` assembled, multi-start runs joined);
the work is done in one module per job, whose public names it re-exports:

* `loopclosure.grid_target`: map points, normals and kinds in a cell grid
  (`GridTarget`, `estimate_normals_fast`); a lazy grid's points get their normal the
  first time the ICP or the overlap screen meets them.
* `loopclosure.grid_nearest`: exact nearest neighbours in the grid's cells, and
  the correspondences of a source carried between iterations.
* `loopclosure.icp_kernel`: the Gauss-Newton iterations and the result's figures.
* `loopclosure.grid_overlap`: `overlap_screen` and `overlap_bound`, the scores of
  guesses before ICP (the overlap score and the overlap bound of the pose-gated
  check).
* `loopclosure.fast_points`: `voxel_downsample_fast` (=
  `loopclosure.registration.voxel_downsample`, to the bit), `beam_points_fast`,
  `within_radius`, `points_within`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.fast_points import (
    beam_points_fast,
    points_within,
    voxel_downsample_fast,
    within_radius,
)
from loopclosure.grid_overlap import overlap_bound, overlap_screen
from loopclosure.grid_target import (
    ANCHORS,
    KIND_CLUTTER,
    KIND_LINE,
    KIND_NONE,
    KIND_UNKNOWN,
    GridTarget,
    checked_points,
    estimate_normals_fast,
)
from loopclosure.icp_kernel import _register_kernel
from loopclosure.icp_types import (
    KERNEL_CONSTANTS,
    IcpConfig,
    IcpResult,
    _failed,  # the failed result of either ICP: the initial pose, no information
)
from loopclosure.registration_target import RegistrationTarget

Array = NDArray[np.float64]

_KERNELS = {"none": 0, "cauchy": 1, "huber": 2, "tukey": 3}


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
           "KIND_NONE", "KIND_UNKNOWN", "TARGET_GRID_CELL", "GridTarget", "beam_points_fast",
           "estimate_normals_fast", "overlap_bound", "overlap_screen", "points_within",
           "register_fast", "register_target", "voxel_downsample_fast", "within_radius"]
