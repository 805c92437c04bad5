"""2D registration: point-to-line ICP of a source point set onto a target with normals.

Used by the odometry front end (scan to local map, `slam.odometry.icp2d`) and by the
loop-closure geometric check (keyframe submap to keyframe submap); both start ICP
from several guesses with `loopclosure.multi_start`, whose headings come from
`loopclosure.headings`.  This module is the numpy reference ICP and the front door of
its types: `IcpConfig` and `IcpResult` live in `loopclosure.icp_types`, the prepared
target in `loopclosure.registration_target`, both re-exported here; the compiled ICP
(`loopclosure.fast_icp`) computes the same figures.

Frames and units
----------------
Points are ``(N, 2)`` arrays [m].  The source is given in its own frame S, the
target in its frame T.  The result `IcpResult.pose` is ``(x, y, theta)`` [m, m,
rad], the pose of S in T: ``target ~ data.se2.transform_points(pose, source)``.

Target (`RegistrationTarget`)
-----------------------------
Built once, used for many sources (`loopclosure.registration_target`): a
`scipy.spatial.cKDTree` over all target points and a unit normal per point from
local PCA; only line-like points (and, with `point_to_point_clutter`, clutter:
enough neighbours, not line-like) get correspondences.

ICP (`register`)
----------------
Gauss-Newton on ``x = (t_x, t_y, theta)`` with the point-to-line residual of
source point ``p_i`` matched to its nearest target point ``q_j`` (normal ``n_j``)::

    r_i(x)  = n_j . (R(theta) p_i + t - q_j)
    J_i     = [n_x, n_y, n_j . (R'(theta) p_i)],  R'(theta) p = (-(R p)_y, (R p)_x)
    H       = sum_i w_i J_i^T J_i / s^2 + Lambda          (3x3, closed form)
    g       = sum_i w_i J_i^T r_i / s^2 + Lambda (x - x_prior)
    x      <- x - H^-1 g

(``Lambda``: optional prior information, zero unless a prior is given; with
``(x, y, theta)`` as coordinates the update is additive and exact.)

With `point_to_point_clutter`, a source point whose nearest target point is
clutter (vegetation, poles, rubble: most of an outdoor scan) is matched to it
point to point: two residual rows of the same form with the normals ``(1, 0)`` and
``(0, 1)``, i.e. the two components of ``R p_i + t - q_j``.  Its per-point residual
(inlier test, fitness, rms) is the distance ``|R p_i + t - q_j|``.

Outlier rejection, both adaptive:

* Distance gate: a correspondence counts only if the nearest target point is within
  the gate ``d_max``.  It starts at `max_correspondence_distance` and after each
  iteration shrinks to ``gate_sigmas * 1.4826 * median(d)`` (robust scale of the
  point-to-point distances), never below `min_correspondence_distance` and never
  growing.
* Robust kernel on the point-to-line residual (iteratively reweighted least
  squares) with width ``k = kernel_constant * s``, where
  ``s = max(min_residual_scale, 1.4826 * median|r|)``: Cauchy ``w = 1 / (1 + (r/k)^2)``
  (constant 2.3849), Huber ``w = min(1, k / |r|)`` (1.345), Tukey
  ``w = (1 - (r/k)^2)^2`` for ``|r| < k`` else 0 (4.6851), or none (``w = 1``): the
  usual 95%-efficiency constants for Gaussian noise.

Convergence: an update with ``|dt| < translation_tolerance`` and
``|dtheta| < rotation_tolerance`` while the gate no longer shrinks, or
`max_iterations`.  (Medians are upper medians, by `np.partition`.)

Result (`IcpResult`), at the final pose with the correspondences of the last
iteration (after convergence the pose moved less than the tolerances since they
were found; otherwise they are searched again at the final pose):

* ``covariance = (H_data / sigma^2 + Lambda)^-1`` with ``H_data = sum w J^T J`` and
  ``sigma^2 = sum w r^2 / (sum w - 3)`` (the weighted residual variance), never below
  ``min_residual_scale^2``.  This is the Gauss-Newton (Cramer-Rao) covariance of
  independent point noise; it ignores correlated errors (map blur, correspondence
  ambiguity) and is therefore optimistic: callers that feed a pose graph add a floor.
  It is additive in (x, y, theta) of the target frame; `body_covariance` turns it
  into the right-perturbation (body frame) covariance a ``BetweenFactorPose2`` takes.
* ``inlier_ratio``: fraction of source points with a correspondence inside the gate
  and ``|r| <= fitness_tolerance`` (``r``: the point's residual, point to line or,
  for a point-to-point match, its distance).
* ``rms``: root mean square residual ``r`` of those inliers [m].
* ``fitness``: the score used to rank hypotheses, in [0, 1]:
  ``mean_i max(0, 1 - (r_i / fitness_tolerance)^2)`` over all source points, 0 for
  points without a correspondence within the gate (a truncated-quadratic overlap:
  rewards both overlap and tight alignment).
* ``degeneracy``: the smallest eigenvalue of the translational information after
  marginalising the rotation (Schur complement of ``H_data``), divided by
  ``sum w`` (the trace of the translational block, since normals are unit): 0 when
  one direction is unconstrained (a corridor), at most 0.5 (isotropic).
  ``degenerate_axis`` is the unit vector (target frame) of that direction.
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from loopclosure.icp_types import (
    FAILED_VARIANCE,
    KERNEL_CONSTANTS,
    LINE_ANCHORS,
    IcpConfig,
    IcpResult,
    _failed,
    as_points,
    body_covariance,
)
from loopclosure.registration_target import NormalsFn, RegistrationTarget, estimate_normals

Array = NDArray[np.float64]

_MAD = 1.4826  # median absolute deviation -> standard deviation (Gaussian)


def voxel_downsample(points: ArrayLike, voxel: float) -> Array:
    """Centroid of the points in each ``voxel x voxel`` cell [m]; order of first occurrence.

    ``voxel <= 0`` returns the points unchanged (as a float copy).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if voxel <= 0 or len(pts) == 0:
        return pts.copy()
    cells = np.floor(pts / voxel).astype(np.int64)
    key = (cells[:, 0] << 32) ^ (cells[:, 1] & 0xFFFFFFFF)
    _, first, inverse, counts = np.unique(
        key, return_index=True, return_inverse=True, return_counts=True
    )
    sums = np.zeros((len(first), 2))
    np.add.at(sums, inverse.reshape(-1), pts)
    centroids = sums / counts[:, None]
    return centroids[np.argsort(first, kind="stable")]



def _weights(r: Array, scale: float, kernel: str) -> Array:
    if kernel == "none":
        return np.ones_like(r)
    k = KERNEL_CONSTANTS[kernel] * scale
    u = r / k
    if kernel == "cauchy":
        return 1.0 / (1.0 + u * u)
    if kernel == "huber":
        a = np.abs(u)
        return np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-300))
    # tukey
    return np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)


@dataclass(slots=True)
class _Matches:
    """Correspondences of the source at one pose: one row per residual.

    A point-to-line match is one row; a point-to-point match two (normals ``(1, 0)``
    and ``(0, 1)``), both with the same source index in `sel`.
    """

    sel: NDArray[np.intp]  # (K,) source point of each row
    dist: Array  # (K,) point-to-point distances
    q: Array  # (K, 2) target points
    n: Array  # (K, 2) target normals (or unit axes)
    points: int  # matched source points (<= K)
    lines: int  # the first `lines` rows are point-to-line, the rest point-to-point


def _rotated(src: Array, theta: float) -> Array:
    """``R(theta) p`` for every source point."""
    c, s = np.cos(theta), np.sin(theta)
    return src @ np.array([[c, s], [-s, c]])


_AXES = np.eye(2)


def _match(target: RegistrationTarget, moved: Array, gate: float, cfg: IcpConfig) -> _Matches:
    dist, idx = target.tree.query(moved, k=1, distance_upper_bound=gate)
    found = np.flatnonzero(np.isfinite(dist))
    j = idx[found]
    line = target.usable[j]
    if not cfg.point_to_point_clutter:
        sel, j = found[line], j[line]
        return _Matches(sel, dist[sel], target.points[j], target.normals[j], len(sel), len(sel))
    keep = line | target.clutter[j]
    sel, j, line = found[keep], j[keep], line[keep]
    pt_sel, pt_j = sel[~line], j[~line]
    rows_sel = np.concatenate([sel[line], pt_sel, pt_sel])
    rows_j = np.concatenate([j[line], pt_j, pt_j])
    normals = np.concatenate([
        target.normals[j[line]],
        np.broadcast_to(_AXES[0], (len(pt_j), 2)),
        np.broadcast_to(_AXES[1], (len(pt_j), 2)),
    ])
    return _Matches(rows_sel, dist[rows_sel], target.points[rows_j], normals, len(sel),
                    int(line.sum()))


def _normal_equations(
    rp: Array, moved: Array, m: _Matches, cfg: IcpConfig
) -> tuple[Array, Array, Array, Array, float]:
    """Residuals, weights, ``J^T W J`` and ``J^T W r`` (unscaled) and the scale s."""
    n = m.n
    r = np.einsum("ij,ij->i", n, moved[m.sel] - m.q)
    s = _robust_scale(r, cfg.min_residual_scale)
    w = _weights(r, s, cfg.kernel)
    if m.lines < len(r):
        w[m.lines:] *= cfg.clutter_weight
    rps = rp[m.sel]
    jac = np.empty((len(r), 3))
    jac[:, :2] = n
    jac[:, 2] = n[:, 1] * rps[:, 0] - n[:, 0] * rps[:, 1]
    jw = jac * w[:, None]
    return r, w, jw.T @ jac, jw.T @ r, s


_DAMP = 1e-12 * np.eye(3)


def _solve(h: Array, g: Array) -> Array:
    return np.linalg.solve(h + _DAMP * max(float(np.trace(h)), 1e-12), g)


def _median_abs(values: Array) -> float:
    """Median of ``|values|`` (upper median for even counts; `np.partition`, no sort)."""
    a = np.abs(values)
    k = len(a) // 2
    return float(np.partition(a, k)[k])


def _robust_scale(values: Array, floor: float) -> float:
    return max(floor, _MAD * _median_abs(values)) if len(values) else floor


def register(
    source: ArrayLike,
    target: RegistrationTarget,
    initial: ArrayLike = (0.0, 0.0, 0.0),
    *,
    config: IcpConfig | None = None,
    prior: ArrayLike | None = None,
    prior_covariance: ArrayLike | None = None,
) -> IcpResult:
    """Point-to-line ICP of `source` (``(N, 2)``, source frame) onto `target`.

    Args:
        source: source points [m] in the source frame.
        target: the prepared target.
        initial: ``(3,)`` initial pose of the source frame in the target frame.
        config: ICP parameters (default: the target's).
        prior: ``(3,)`` optional prior pose (target frame) with `prior_covariance`
            (``3x3``, additive x, y, theta in the target frame); it enters the normal
            equations as ``Lambda = prior_covariance^-1`` and keeps directions the
            data does not constrain (e.g. along a corridor) at the prior.

    Returns:
        An `IcpResult` (module docstring); ``ok`` is False, with the initial pose,
        when fewer than `min_correspondences` points match (the covariance is then
        the prior's, or ``FAILED_VARIANCE * I``).
    """
    cfg = config or target.config
    src = as_points(source, "source points")
    x = np.asarray(initial, dtype=float).reshape(3).copy()
    x0 = x.copy()
    lam = np.zeros((3, 3))
    x_prior = None
    prior_cov = None
    if prior is not None:
        if prior_covariance is None:
            raise UserError("register: a prior needs its prior_covariance (got None)")
        x_prior = np.asarray(prior, dtype=float).reshape(3)
        prior_cov = np.asarray(prior_covariance, dtype=float).reshape(3, 3)
        lam = np.linalg.inv(prior_cov)
    if target.tree is None or len(src) < cfg.min_correspondences:
        return _failed(x0, 0, 0, prior_cov)

    gate = cfg.max_correspondence_distance
    iterations = 0
    converged = False
    for iterations in range(1, cfg.max_iterations + 1):
        rp = _rotated(src, x[2])
        moved = rp + x[:2]
        m = _match(target, moved, gate, cfg)
        if m.points < cfg.min_correspondences:
            return _failed(x0, iterations, m.points, prior_cov)
        _, _, h, g, s = _normal_equations(rp, moved, m, cfg)
        h = h / s**2 + lam
        g = g / s**2
        if x_prior is not None:
            diff = x - x_prior
            diff[2] = se2.wrap_angle(diff[2])
            g = g + lam @ diff
        step = -_solve(h, g)
        x = x + step
        x[2] = float(se2.wrap_angle(x[2]))
        new_gate = min(gate, max(cfg.min_correspondence_distance,
                                 cfg.gate_sigmas * _robust_scale(m.dist, 0.0)))
        small = (float(np.hypot(step[0], step[1])) < cfg.translation_tolerance
                 and abs(step[2]) < cfg.rotation_tolerance)
        gate_settled = new_gate >= gate * (1.0 - 1e-6)
        gate = new_gate
        if small and gate_settled:
            converged = True
            break
    # After convergence the last correspondences still hold (the pose moved < tolerance).
    last = m if converged else None
    return _evaluate(src, target, x, x0, gate, cfg, lam, prior_cov, iterations, converged, last)


def _evaluate(
    src: Array,
    target: RegistrationTarget,
    x: Array,
    x0: Array,
    gate: float,
    cfg: IcpConfig,
    lam: Array,
    prior_cov: Array | None,
    iterations: int,
    converged: bool,
    matches: _Matches | None = None,
) -> IcpResult:
    """The figures of the result at the final pose (module docstring).

    `matches`: correspondences to reuse (those of the converged last iteration);
    None searches them at the final pose.
    """
    rp = _rotated(src, x[2])
    moved = rp + x[:2]
    m = matches if matches is not None else _match(target, moved, gate, cfg)
    if m.points < cfg.min_correspondences:
        return _failed(x0, iterations, m.points, prior_cov)
    r, w, h_data, _, _ = _normal_equations(rp, moved, m, cfg)
    wsum = float(w.sum())
    sigma2 = max(float(w @ r**2) / max(wsum - 3.0, 1.0), cfg.min_residual_scale**2)
    info = h_data / sigma2 + lam
    cov = np.linalg.inv(info + 1e-12 * max(np.trace(info), 1e-12) * np.eye(3))
    cov = 0.5 * (cov + cov.T)
    n_src = len(src)
    # Point-to-line rows first, then the x and the y rows of the point-to-point matches:
    # a point-to-point match's residual is its distance.
    x_rows, y_rows = r[m.lines : m.points], r[m.points :]
    r_point = np.concatenate([r[: m.lines], np.hypot(x_rows, y_rows)])
    inlier = np.abs(r_point) <= cfg.fitness_tolerance
    rms = float(np.sqrt(np.mean(r_point[inlier] ** 2))) if inlier.any() else 0.0
    fitness = float(
        np.clip(1.0 - (r_point / cfg.fitness_tolerance) ** 2, 0.0, None).sum() / n_src
    )
    # Schur complement of the rotation: translational information with theta marginalised.
    h_tt = h_data[:2, :2]
    if h_data[2, 2] > 1e-12:
        h_tt = h_tt - np.outer(h_data[:2, 2], h_data[2, :2]) / h_data[2, 2]
    evals, evecs = np.linalg.eigh(h_tt)
    degeneracy = float(np.clip(evals[0] / wsum, 0.0, 0.5)) if wsum > 0 else 0.0
    return IcpResult(
        pose=x.copy(), covariance=cov, hessian=h_data, sigma=float(np.sqrt(sigma2)),
        inlier_ratio=float(inlier.sum()) / n_src, rms=rms, fitness=fitness,
        degeneracy=degeneracy, degenerate_axis=evecs[:, 0].copy(), iterations=iterations,
        converged=converged, correspondences=m.points, ok=True, initial=x0.copy(),
    )


__all__ = ["FAILED_VARIANCE", "KERNEL_CONSTANTS", "LINE_ANCHORS", "IcpConfig", "IcpResult",
           "NormalsFn", "RegistrationTarget", "as_points", "body_covariance", "estimate_normals",
           "register", "voxel_downsample"]
