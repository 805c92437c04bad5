"""Trajectory error: ATE after rigid alignment and RPE, computed as evo does.

- Association: each estimated stamp is matched with the nearest reference stamp;
  pairs further apart than `max_diff` seconds (default 0.01 s, evo's default) are
  dropped.
- Alignment: Umeyama (1991) least-squares rigid motion of the matched estimated
  positions onto the reference positions (rotation + translation, no scale unless
  asked).  For planar trajectories this is the SE(2) alignment (the rotation found
  is about z because all z are 0).
- ATE: per pose the translation error ``||p_ref - (R p_est + t)||`` [m]; RMSE, mean,
  median, std, max.
- RPE: pairs ``(i, j)`` of matched poses, non-overlapping, ``j - i = delta`` frames or
  the first ``j`` whose reference path length from ``i`` reaches ``delta`` metres;
  error ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (Q reference, P estimate); translation
  ``||t(E)||`` [m] and rotation angle of ``R(E)`` [deg], summarised by RMSE.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.types import Trajectory

Array = NDArray[np.float64]


def associate(
    est_stamps: Array, ref_stamps: Array, max_diff: float = 0.01
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices ``(i_est, i_ref)`` of stamp pairs closer than `max_diff` seconds.

    `ref_stamps` must be sorted (trajectories have increasing stamps).
    """
    est = np.asarray(est_stamps, dtype=float)
    ref = np.asarray(ref_stamps, dtype=float)
    if len(ref) == 0 or len(est) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    hi = np.clip(np.searchsorted(ref, est), 1, len(ref) - 1)
    lo = hi - 1
    nearest = np.where(np.abs(ref[lo] - est) <= np.abs(ref[hi] - est), lo, hi)
    if len(ref) == 1:
        nearest = np.zeros(len(est), dtype=np.intp)
    ok = np.abs(ref[nearest] - est) <= max_diff
    return np.flatnonzero(ok), nearest[ok]


def umeyama(src: Array, dst: Array, with_scale: bool = False) -> tuple[Array, Array, float]:
    """Rotation ``R``, translation ``t`` and scale ``s`` minimising ``||dst - (s R src + t)||``.

    `src`, `dst` are ``(N, d)`` corresponding points (Umeyama 1991).
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, sing, vt = np.linalg.svd(cov)
    s_mat = np.eye(src.shape[1])
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s_mat[-1, -1] = -1.0
    rot = u @ s_mat @ vt
    scale = 1.0
    if with_scale:
        var = (xs**2).sum() / len(src)
        scale = float(np.trace(np.diag(sing) @ s_mat) / var) if var > 0 else 1.0
    return rot, mu_d - scale * rot @ mu_s, scale


def rotation_angle_deg(rot: Array) -> Array:
    """Rotation angle [deg], 0..180, of ``(..., 3, 3)`` rotation matrices.

    ``atan2(sin, cos)`` with ``sin = |vee(R - R^T)| / 2`` and ``cos = (tr R - 1) / 2``:
    accurate for small angles, unlike ``arccos`` alone.
    """
    rot = np.asarray(rot, dtype=float)
    skew = np.stack(
        [
            rot[..., 2, 1] - rot[..., 1, 2],
            rot[..., 0, 2] - rot[..., 2, 0],
            rot[..., 1, 0] - rot[..., 0, 1],
        ],
        axis=-1,
    )
    sin = 0.5 * np.linalg.norm(skew, axis=-1)
    cos = 0.5 * (np.trace(rot, axis1=-2, axis2=-1) - 1.0)
    return np.degrees(np.arctan2(sin, cos))


@dataclass(slots=True)
class TrajectoryErrors:
    """ATE and RPE summary (metres, degrees) and the per-pose ATE errors."""

    ate_rmse: float
    ate_mean: float
    ate_median: float
    ate_std: float
    ate_max: float
    rpe_trans_rmse: float
    rpe_rot_rmse_deg: float
    matched: int
    rpe_pairs: int
    ate_errors: Array
    aligned: Trajectory

    def to_json(self) -> dict[str, float | int]:
        """The summary figures (CLI ``--json`` keys)."""
        return {
            "ate_rmse": self.ate_rmse,
            "ate_mean": self.ate_mean,
            "ate_median": self.ate_median,
            "ate_std": self.ate_std,
            "ate_max": self.ate_max,
            "rpe_trans_rmse": self.rpe_trans_rmse,
            "rpe_rot_rmse_deg": self.rpe_rot_rmse_deg,
            "matched": self.matched,
            "rpe_pairs": self.rpe_pairs,
        }


def rpe_pairs(ref_positions: Array, delta: float, unit: str) -> tuple[Array, Array]:
    """Non-overlapping index pairs for RPE (`unit` "frames" or "m", see module doc)."""
    n = len(ref_positions)
    if unit == "frames":
        step = max(int(delta), 1)
        ids = np.arange(0, n, step)
        return ids[:-1], ids[1:]
    if unit != "m":
        raise UserError(f"unknown RPE unit {unit!r}; use 'frames' or 'm'")
    steps = np.linalg.norm(np.diff(ref_positions, axis=0), axis=1)
    path = np.concatenate([[0.0], np.cumsum(steps)])
    first, second = [], []
    i = 0
    while True:  # at most n / (pairs) iterations, each a binary search
        j = int(np.searchsorted(path, path[i] + delta, side="left"))
        if j >= n:
            break
        first.append(i)
        second.append(j)
        i = j
    return np.array(first, dtype=np.intp), np.array(second, dtype=np.intp)


def trajectory_errors(
    estimate: Trajectory,
    reference: Trajectory,
    *,
    max_diff: float = 0.01,
    align: bool = True,
    with_scale: bool = False,
    rpe_delta: float = 1.0,
    rpe_unit: str = "frames",
) -> TrajectoryErrors:
    """ATE and RPE of `estimate` against `reference` (see module docstring)."""
    i_est, i_ref = associate(estimate.stamps, reference.stamps, max_diff)
    if len(i_est) < 2:
        raise UserError(
            f"only {len(i_est)} stamps of the estimate match the reference within {max_diff} s"
        )
    p = estimate.poses[i_est]
    q = reference.poses[i_ref]
    if align:
        rot, t, s = umeyama(p[:, :3, 3], q[:, :3, 3], with_scale)
    else:
        rot, t, s = np.eye(3), np.zeros(3), 1.0
    aligned = p.copy()
    aligned[:, :3, :3] = rot @ p[:, :3, :3]
    aligned[:, :3, 3] = s * p[:, :3, 3] @ rot.T + t
    err = np.linalg.norm(q[:, :3, 3] - aligned[:, :3, 3], axis=1)
    a, b = rpe_pairs(q[:, :3, 3], rpe_delta, rpe_unit)
    if len(a):
        rel_q = np.linalg.inv(q[a]) @ q[b]
        rel_p = np.linalg.inv(aligned[a]) @ aligned[b]
        e = np.linalg.inv(rel_q) @ rel_p
        rpe_t = np.linalg.norm(e[:, :3, 3], axis=1)
        rpe_r = rotation_angle_deg(e[:, :3, :3])
        rpe_t_rmse = float(np.sqrt(np.mean(rpe_t**2)))
        rpe_r_rmse = float(np.sqrt(np.mean(rpe_r**2)))
    else:
        rpe_t_rmse = rpe_r_rmse = float("nan")
    return TrajectoryErrors(
        ate_rmse=float(np.sqrt(np.mean(err**2))),
        ate_mean=float(err.mean()),
        ate_median=float(np.median(err)),
        ate_std=float(err.std()),
        ate_max=float(err.max()),
        rpe_trans_rmse=rpe_t_rmse,
        rpe_rot_rmse_deg=rpe_r_rmse,
        matched=len(i_est),
        rpe_pairs=len(a),
        ate_errors=err,
        aligned=Trajectory(estimate.stamps[i_est], aligned),
    )
