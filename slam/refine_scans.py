"""Final per-scan refinement: every scan registered onto a map centred on it.

After the pose graph is optimised, a scan between keyframes gets its pose from
the keyframes around it and its odometry offsets (`slam.keyframes`).  That pose
carries the front end's own error, made against a *causal* local map (the keyframes
behind the robot only).  `refine_scan_poses` registers every scan once more, by the
front end's point-to-line ICP (`loopclosure.fast_icp.register_fast`), onto a map
built from the `half_window` map scans (keyframes) before it and the `half_window`
after it in scan order, placed at their optimised poses: twice the support of the
front end's map, on both sides of the robot, and consistent with the loop closures.

Frames and units: poses ``(x, y, theta)`` [m, m, rad] of the sensor in the map
frame; points ``(N_i, 2)`` [m] in each scan's sensor frame.

For scan ``i`` (position in `poses`), ``k`` is the position among the map scans
of the first map scan at or after ``i``; the map is the map scans at positions
``k - half_window .. k + half_window - 1`` except scan ``i`` itself (a keyframe is
never matched onto its own points), merged and voxel-downsampled to `map_voxel`,
with normals as in the front end.  ICP starts at the given pose with it as a prior,
covariance ``diag(prior_sigma^2)`` in the scan's own frame (rotated into the map
frame), so a direction the map does not constrain stays put.  The refined pose
replaces the given one when ICP succeeded with an inlier ratio of at least
`min_inlier_ratio`, an RMS residual of at most `max_rms` and a correction within
`max_correction`; otherwise the pose is kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from loopclosure.registration import LINE_ANCHORS, IcpConfig

if TYPE_CHECKING:
    from loopclosure.fast_icp import GridTarget

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RefineConfig:
    """Parameters of `refine_scan_poses` (module docstring).

    Attributes:
        half_window: map scans on each side of a scan that make its map.
        source_voxel: voxel of each scan's points [m] (0: all).
        map_voxel: voxel of the map [m].
        prior_sigma: standard deviations of the prior at the given pose
            (x [m], y [m] in the scan's frame, theta [rad]).
        min_points: scans with fewer points keep their pose.
        min_inlier_ratio: a refinement needs at least this inlier ratio.
        max_rms: and at most this RMS residual [m].
        max_correction: and a correction of at most (translation [m], rotation [rad]).
        icp: ICP parameters (the front end's defaults: clutter point to point at 0.3).
        line_anchor: where a wall's line passes (`loopclosure.fast_icp.GridTarget`):
            ``"point"``, the nearest map point, or ``"mean"``, the mean of the
            neighbours its normal was fitted to (as `Icp2dConfig.line_anchor`).
        line_anchor_radius: the neighbours of that mean are within this distance [m].
        line_anchor_band: and within this distance of the point's line [m] (inf: all).
    """

    half_window: int = 8
    source_voxel: float = 0.05
    map_voxel: float = 0.05
    prior_sigma: tuple[float, float, float] = (0.05, 0.05, 0.02)
    min_points: int = 20
    min_inlier_ratio: float = 0.5
    max_rms: float = 0.1
    max_correction: tuple[float, float] = (0.2, 0.1)
    icp: IcpConfig = field(
        default_factory=lambda: IcpConfig(point_to_point_clutter=True, clutter_weight=0.3)
    )
    line_anchor: str = "point"
    line_anchor_radius: float = 0.2
    line_anchor_band: float = float("inf")

    def __post_init__(self) -> None:
        if self.line_anchor not in LINE_ANCHORS:
            raise UserError(f"refine line_anchor must be one of {', '.join(LINE_ANCHORS)}, "
                            f"got {self.line_anchor!r}")
        if not (self.line_anchor_radius > 0 and self.line_anchor_band > 0):
            raise UserError("refine line_anchor_radius and line_anchor_band must be positive")
        if self.half_window < 1:
            raise UserError(f"refine half_window must be >= 1, got {self.half_window}")
        if not self.map_voxel > 0 or self.source_voxel < 0:
            raise UserError("refine needs map_voxel > 0 and source_voxel >= 0")
        if np.any(np.asarray(self.prior_sigma, dtype=float) <= 0):
            raise UserError(f"refine prior_sigma must be positive, got {self.prior_sigma}")


@dataclass(slots=True)
class RefinedPoses:
    """Result of `refine_scan_poses`.

    Attributes:
        poses: ``(N, 3)`` refined poses (the given pose where `refined` is False).
        refined: ``(N,)`` which scans took the refined pose.
    """

    poses: Array
    refined: NDArray[np.bool_]


def refine_scan_poses(
    points: Sequence[ArrayLike],
    poses: ArrayLike,
    map_scans: ArrayLike,
    config: RefineConfig | None = None,
) -> RefinedPoses:
    """Register every scan onto the map scans around it (module docstring).

    Args:
        points: per scan, ``(N_i, 2)`` valid end points in its sensor frame [m] (any
            float dtype; each is converted and voxelised only when it is used, and
            only the map scans of the current window are kept in the map frame, so
            the extra memory is one window's, not a copy of every scan's).
        poses: ``(N, 3)`` sensor poses in the map frame (optimised keyframes and the
            scans placed between them).
        map_scans: increasing positions (into `points` / `poses`) of the scans that
            make the maps, normally the keyframes.
        config: parameters (`RefineConfig`).
    """
    # The compiled kernel loads numba: only when a refinement runs.
    from loopclosure.fast_icp import GridTarget, register_fast, voxel_downsample_fast

    cfg = config or RefineConfig()
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(points) != len(poses):
        raise UserError(f"refine: {len(points)} point sets but {len(poses)} poses")
    members = np.asarray(map_scans, dtype=np.int64).reshape(-1)
    if len(members) and (np.any(np.diff(members) <= 0) or members[0] < 0
                         or members[-1] >= len(poses)):
        raise UserError("refine: map_scans must be increasing positions of scans")
    out = poses.copy()
    refined = np.zeros(len(poses), dtype=bool)
    if len(members) < 2:
        return RefinedPoses(out, refined)
    prior = np.square(np.asarray(cfg.prior_sigma, dtype=float))

    def source(i: int) -> Array:
        return voxel_downsample_fast(np.asarray(points[i], dtype=float), cfg.source_voxel)

    # The map scans' points in the map frame, only those of the current window:
    # windows move forward with i, so a scan that fell behind is never needed again.
    world: dict[int, Array] = {}
    key: tuple[int, int, int] | None = None
    grid: GridTarget | None = None
    for i in range(len(poses)):
        src = source(i)
        if len(src) < cfg.min_points:
            continue
        k = min(int(np.searchsorted(members, i)), len(members) - 1)
        lo, hi = max(0, k - cfg.half_window), min(len(members), k + cfg.half_window)
        own = i if members[k] == i else -1
        if (lo, hi, own) != key:
            key = (lo, hi, own)
            window = [int(m) for m in members[lo:hi]]
            world = {m: world[m] if m in world else se2.transform_points(poses[m], source(m))
                     for m in window}
            near = [world[m] for m in window if m != i]
            grid = None
            if near:
                grid = GridTarget(voxel_downsample_fast(np.vstack(near), cfg.map_voxel), cfg.icp,
                                  anchor=cfg.line_anchor, anchor_radius=cfg.line_anchor_radius,
                                  anchor_band=cfg.line_anchor_band)
                grid = grid if len(grid) else None
        if grid is None:
            continue
        c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        res = register_fast(src, grid, poses[i], config=cfg.icp, prior=poses[i],
                            prior_covariance=rot @ np.diag(prior) @ rot.T)
        step = se2.between(poses[i], res.pose)
        if (res.ok and res.inlier_ratio >= cfg.min_inlier_ratio and res.rms <= cfg.max_rms
                and np.hypot(step[0], step[1]) <= cfg.max_correction[0]
                and abs(step[2]) <= cfg.max_correction[1]):
            out[i] = res.pose
            refined[i] = True
    return RefinedPoses(out, refined)


__all__ = ["RefineConfig", "RefinedPoses", "refine_scan_poses"]
