"""KISS-ICP odometry (the ``kiss-icp`` front end) for point clouds and lifted planar scans.

Wraps the installed ``kiss_icp`` package (Vizzo et al., "KISS-ICP: In Defense of
Point-to-Point ICP", RA-L 2023): `kiss_icp.kiss_icp.KissICP` with a
`kiss_icp.config.KISSConfig` built from `KissConfig`.  Input:

* `data.types.PointCloud`: its ``(N, 3)`` points (sensor frame) as they are.
* `data.types.Scan`: the valid end points lifted to z = 0.

Odometry seeding.  KISS-ICP predicts each pose with a constant-velocity model
(``last_pose @ last_delta``).  On lifted 2D scans that prediction is poor and the
estimate drifts badly, by an order of magnitude in relations error on an indoor
log.  Whenever the scan carries odometry and `use_odometry`
is set, ``last_delta`` is replaced by the odometry increment since the previous
scan (a ``4x4`` lifted from ``between(odom_prev, odom)`` for scans, or
``odom_prev^-1 @ odom`` for point clouds) before ``register_frame``.

No deskewing (our types carry no per-point times).  KISS-ICP does not expose its
Hessian, so the covariance of each increment comes from the documented model
`KissConfig.noise` (a `MotionNoise` applied to the estimated increment), not from
the registration.  `OdometryEstimate.fitness` is 0 (KISS-ICP has no such score).

Frames: KISS-ICP starts at the identity; poses are reported in the odometry frame
of `slam.odometry` (left-multiplied by the first scan's odometry when it has one).
``pose`` is the planar projection (x, y, yaw) and ``matrix`` the full ``4x4``.

Graceful handling: fewer than `min_points` points, the pose is the constant-velocity
(or odometry) prediction and KISS-ICP's state moves to it (status ``no_points``,
covariance inflated); an odometry increment beyond `max_step` / `max_step_rotation`
is not used as a seed (zero motion instead; status ``odometry_jump``, covariance
inflated).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from data.types import PointCloud, Scan
from slam.odometry import MotionNoise, OdometryEstimate

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class KissConfig:
    """Parameters of the KISS-ICP front end.

    Attributes:
        max_range: points farther than this are dropped [m]; None: 40 m for planar
            scans (indoor laser), 100 m for point clouds (KISS-ICP's default).
        min_range: points closer than this are dropped [m].
        voxel_size: KISS-ICP map voxel [m]; None: 0.1 m for planar scans, KISS-ICP's
            ``max_range / 100`` for point clouds.
        max_points_per_voxel: KISS-ICP's map density.
        initial_threshold: KISS-ICP's initial adaptive threshold [m].
        min_motion_th: KISS-ICP's minimum motion for the threshold update [m].
        max_iterations: ICP iterations at most.
        convergence_criterion: KISS-ICP's ICP convergence [m / rad].
        threads: worker threads of KISS-ICP (0: all cores).
        use_odometry: seed the prediction with the odometry increment when present.
        noise: covariance model of the estimated increment.
        min_points: fewer points than this: prediction only.
        fallback_inflation: covariance multiplier of fallback estimates.
        max_step: odometry increments longer than this are not used [m].
        max_step_rotation: odometry increments turning more are not used [rad].
    """

    max_range: float | None = None
    min_range: float = 0.05
    voxel_size: float | None = None
    max_points_per_voxel: int = 20
    initial_threshold: float = 2.0
    min_motion_th: float = 0.1
    max_iterations: int = 500
    convergence_criterion: float = 1e-4
    threads: int = 1
    use_odometry: bool = True
    noise: MotionNoise = field(
        default_factory=lambda: MotionNoise(
            along_per_m=0.03, along_per_rad=0.01, lateral_per_m=0.03, lateral_per_rad=0.01,
            rot_per_m=0.01, rot_per_rad=0.02, min_sigma_xy=0.005, min_sigma_theta=0.002,
        )
    )
    min_points: int = 20
    fallback_inflation: float = 10.0
    max_step: float = 1.0
    max_step_rotation: float = 1.0

    def __post_init__(self) -> None:
        for name in ("max_range", "voxel_size"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value > 0):
                raise UserError(f"kiss-icp {name} must be a positive number, got {value}")
        if self.min_range < 0 or self.min_points < 3 or self.threads < 0:
            raise UserError("kiss-icp needs min_range >= 0, min_points >= 3, threads >= 0")


def _points_of(item: Scan | PointCloud, cfg: KissConfig) -> tuple[Array, bool]:
    """``(N, 3)`` points of a scan (lifted) or cloud, and whether the input is planar."""
    if isinstance(item, PointCloud):
        pts = np.asarray(item.points, dtype=float).reshape(-1, 3)
        return pts[np.all(np.isfinite(pts), axis=1)], False
    pts2 = item.points()
    return np.column_stack([pts2, np.zeros(len(pts2))]), True


def _odom_matrix(item: Scan | PointCloud) -> Array | None:
    """The item's odometry as a ``4x4`` matrix, or None (absent or not finite)."""
    odom = getattr(item, "odom", None)
    if odom is None:
        return None
    odom = np.asarray(odom, dtype=float)
    if odom.shape == (4, 4):
        return odom if np.all(np.isfinite(odom)) else None
    odom = odom.reshape(-1)
    if odom.shape != (3,) or not np.all(np.isfinite(odom)):
        return None
    return se2.to_se3(odom)


class KissOdometry:
    """``process(scan_or_cloud)``: KISS-ICP odometry (module docstring)."""

    name = "kiss-icp"

    def __init__(self, config: KissConfig | None = None) -> None:
        self.config = config or KissConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the map and the motion: the next input starts a new odometry frame."""
        self._kiss: Any = None
        self._origin = np.eye(4)
        self._odom: Array | None = None
        self._planar = True
        self._pose3: Array | None = None

    def _make(self, planar: bool, item: Scan | PointCloud) -> Any:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        cfg = self.config
        if cfg.max_range is not None:
            max_range = cfg.max_range
        elif planar:
            max_range = float(min(getattr(item, "max_range", 40.0), 40.0))
        else:
            max_range = 100.0
        voxel = cfg.voxel_size
        if voxel is None:
            voxel = 0.1 if planar else max_range / 100.0
        kc = KISSConfig()
        kc.data.max_range = max_range
        kc.data.min_range = cfg.min_range
        kc.data.deskew = False
        kc.mapping.voxel_size = voxel
        kc.mapping.max_points_per_voxel = cfg.max_points_per_voxel
        kc.adaptive_threshold.initial_threshold = cfg.initial_threshold
        kc.adaptive_threshold.min_motion_th = cfg.min_motion_th
        kc.registration.max_num_iterations = cfg.max_iterations
        kc.registration.convergence_criterion = cfg.convergence_criterion
        kc.registration.max_num_threads = cfg.threads
        return KissICP(kc)

    def process(self, item: Scan | PointCloud) -> OdometryEstimate:
        """Estimate for the next scan or cloud (in source order)."""
        t0 = time.perf_counter()
        cfg = self.config
        points, planar = _points_of(item, cfg)
        odom = _odom_matrix(item)
        extra: dict[str, Any] = {"points": len(points)}
        first = self._kiss is None
        if first:
            self._kiss = self._make(planar, item)
            self._planar = planar
            self._origin = odom.copy() if odom is not None else np.eye(4)
        kiss = self._kiss
        prev3 = kiss.last_pose.copy()
        status = "first" if first else "ok"
        inflate = 1.0
        if not first and odom is not None and self._odom is not None and cfg.use_odometry:
            step = np.linalg.inv(self._odom) @ odom
            planar_step = se2.from_matrix(step)
            if (np.hypot(planar_step[0], planar_step[1]) > cfg.max_step
                    or abs(planar_step[2]) > cfg.max_step_rotation):
                kiss.last_delta = np.eye(4)
                status, inflate = "odometry_jump", cfg.fallback_inflation
                extra["odometry_step"] = planar_step
            else:
                kiss.last_delta = step
        if odom is not None:
            self._odom = odom
        if len(points) >= cfg.min_points:
            kiss.register_frame(points, np.zeros(0))
        else:
            predicted = kiss.last_pose @ kiss.last_delta
            if not first:
                kiss.last_pose = predicted
            status, inflate = ("first" if first else "no_points"), cfg.fallback_inflation
        pose3 = self._origin @ kiss.last_pose
        delta3 = np.linalg.inv(prev3) @ kiss.last_pose
        delta = np.zeros(3) if first else se2.from_matrix(delta3)
        cov = cfg.noise.covariance(delta) * inflate
        return OdometryEstimate(
            stamp=float(item.stamp),
            index=int(getattr(item, "index", 0)),
            pose=se2.from_matrix(pose3),
            delta=delta,
            covariance=cov,
            fitness=0.0,
            seconds=time.perf_counter() - t0,
            status=status,
            matrix=pose3,
            extra=extra,
        )
