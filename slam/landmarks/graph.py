"""A gtsam pose graph with object landmarks: odometry between-factors and robust
range-bearing factors to recognised objects.

The graph reads like the maths:

- poses ``x_k`` (`gtsam.Pose2`, key ``gtsam.symbol('x', k)``) of the keyframes, a
  strong prior on ``x_0`` at its odometry pose (the odometry frame is the map frame);
- ``BetweenFactorPose2(x_{k-1}, x_k, odom_{k-1}^-1 odom_k)`` with the information of
  the wheel-odometry model (`odometry_information`);
- landmarks ``l_j`` (`gtsam.Point2`, key ``gtsam.symbol('l', j)``, j = the recognised
  library object), one per recognised object identity;
- ``BearingRangeFactor2D(x_k, l_j, bearing, range)`` for every accepted recognition,
  with a Gaussian of `bearing_sigma`, `range_sigma` wrapped in the robust kernel
  (`slam.pose_graph.RobustKernel`, Cauchy by default), so a wrong recognition pulls
  little.  Seeing an object again is an object-level loop closure: its second
  factor ties the current pose to the landmark the first sighting placed.

Solved in batch by Levenberg-Marquardt from the odometry poses and, for each
landmark, its first observation projected from its keyframe's odometry pose.  With no
landmark factor the optimum is the odometry itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from data import se2
from data.sim import OdometryNoise
from slam.pose_graph import RobustKernel

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class GraphConfig:
    """Keyframes and factor noise.

    Attributes:
        keyframe_spacing: odometry distance between keyframes [m].
        bearing_sigma: standard deviation of a landmark bearing [rad].
        range_sigma: standard deviation of a landmark range [m].
        kernel: robust kernel name of the landmark factors (`RobustKernel`).
        kernel_scale: its scale in whitened units (None: the kernel's default).
        min_sigma: floor of every odometry standard deviation [m or rad].
    """

    keyframe_spacing: float = 0.5
    bearing_sigma: float = 0.015
    range_sigma: float = 0.01
    kernel: str = "cauchy"
    kernel_scale: float | None = None
    min_sigma: float = 1e-3

    def to_json(self) -> dict[str, object]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class LandmarkObservation:
    """Range and bearing of landmark `landmark` from keyframe `keyframe` (its robot frame)."""

    keyframe: int
    landmark: int
    bearing: float
    range: float


def keyframe_indices(odom: Array, spacing: float) -> NDArray[np.intp]:
    """Scan indices of keyframes: the first scan, then each scan that has travelled
    `spacing` [m] (odometry path length) since the last keyframe, and the last scan."""
    odom = np.asarray(odom, dtype=float).reshape(-1, 3)
    step = np.linalg.norm(np.diff(odom[:, :2], axis=0), axis=1)
    path = np.concatenate([[0.0], np.cumsum(step)])
    marks = np.floor(path / spacing).astype(np.int64)
    idx = np.flatnonzero(np.r_[True, marks[1:] != marks[:-1]])
    if idx[-1] != len(odom) - 1:
        idx = np.append(idx, len(odom) - 1)
    return idx.astype(np.intp)


def odometry_information(delta: Array, noise: OdometryNoise, min_sigma: float = 1e-3) -> Array:
    """``3x3`` information (x, y, theta) of a wheel-odometry increment ``delta`` (x, y, theta).

    Variances of `data.sim.motion`'s model over the increment's distance ``d`` and
    rotation, with its systematic biases counted as noise of the same size:
    ``var_x = trans^2 d + (scale_bias d)^2``, ``var_y = lateral^2 d``,
    ``var_theta = rot_m^2 d + rot_rad^2 |dtheta| + (heading_bias d)^2
    + (rot_scale_bias dtheta)^2``; each standard deviation at least `min_sigma`.
    """
    d = float(np.hypot(delta[0], delta[1]))
    dt = abs(float(delta[2]))
    var = np.array([
        noise.trans_sigma**2 * d + (noise.scale_bias * d) ** 2,
        noise.lateral_sigma**2 * d,
        noise.rot_sigma_per_m**2 * d + noise.rot_sigma_per_rad**2 * dt
        + (noise.heading_bias * d) ** 2 + (noise.rot_scale_bias * dt) ** 2,
    ])
    return np.diag(1.0 / np.maximum(var, min_sigma**2))


def X(k: int) -> int:
    """gtsam key of keyframe pose `k`."""
    return int(gtsam.symbol("x", int(k)))


def L(j: int) -> int:
    """gtsam key of landmark `j`."""
    return int(gtsam.symbol("l", int(j)))


def build_graph(
    keyframe_odom: Array,
    observations: Sequence[LandmarkObservation],
    noise: OdometryNoise,
    config: GraphConfig | None = None,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The factor graph of the module docstring and its initial values."""
    cfg = config or GraphConfig()
    kf = np.asarray(keyframe_odom, dtype=float).reshape(-1, 3)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*kf[0]), prior))
    for k, pose in enumerate(kf):
        values.insert(X(k), gtsam.Pose2(*pose))
        if k == 0:
            continue
        delta = se2.between(kf[k - 1], pose)
        info = odometry_information(delta, noise, cfg.min_sigma)
        graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(*delta),
                                           gtsam.noiseModel.Gaussian.Information(info)))
    kernel = RobustKernel(cfg.kernel, cfg.kernel_scale)
    info = np.diag([1.0 / cfg.bearing_sigma**2, 1.0 / cfg.range_sigma**2])
    for ob in observations:
        if not values.exists(L(ob.landmark)):
            pose = kf[ob.keyframe]
            c, s = np.cos(pose[2] + ob.bearing), np.sin(pose[2] + ob.bearing)
            values.insert(L(ob.landmark), gtsam.Point2(pose[0] + ob.range * c,
                                                       pose[1] + ob.range * s))
        graph.add(gtsam.BearingRangeFactor2D(X(ob.keyframe), L(ob.landmark),
                                             gtsam.Rot2(ob.bearing), ob.range,
                                             kernel.noise(info)))
    return graph, values


@dataclass(slots=True)
class LandmarkSolution:
    """Optimised keyframe poses ``(K, 3)`` and landmark positions (id -> (2,)) [m]."""

    poses: Array
    landmarks: dict[int, Array]
    initial_error: float
    final_error: float
    iterations: int


def solve(
    keyframe_odom: Array,
    observations: Sequence[LandmarkObservation],
    noise: OdometryNoise,
    config: GraphConfig | None = None,
) -> LandmarkSolution:
    """Levenberg-Marquardt solution of `build_graph` (the odometry when no observation)."""
    kf = np.asarray(keyframe_odom, dtype=float).reshape(-1, 3)
    graph, values = build_graph(kf, observations, noise, config)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-10)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    poses = np.array([[p.x(), p.y(), p.theta()]
                      for p in (result.atPose2(X(k)) for k in range(len(kf)))])
    ids = sorted({ob.landmark for ob in observations})
    landmarks = {j: np.asarray(result.atPoint2(L(j)), dtype=float) for j in ids}
    return LandmarkSolution(poses, landmarks, float(graph.error(values)),
                            float(graph.error(result)), int(optimizer.iterations()))
