"""The ICP's parameters and outcome, shared by the numpy reference
(`loopclosure.registration.register`) and the compiled ICP (`loopclosure.fast_icp`):
`IcpConfig`, `IcpResult` (every figure defined in `loopclosure.registration`'s module
docstring), the failed result, the input check of point sets, and the conversion of
a result's covariance to the body frame (`body_covariance`).

Points are ``(N, 2)`` arrays [m]; poses ``(x, y, theta)`` [m, m, rad], the pose of the
source frame S in the target frame T.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError

Array = NDArray[np.float64]

#: Robust kernels and their 95%-efficiency tuning constants (in units of the scale s).
KERNEL_CONSTANTS: dict[str, float] = {
    "cauchy": 2.3849,
    "huber": 1.345,
    "tukey": 4.6851,
    "none": 0.0,
}

#: Variance [m^2, rad^2] put on the diagonal of the covariance of a failed registration.
FAILED_VARIANCE = 1.0e6


#: Where the line of a line-like target point passes (`loopclosure.fast_icp.GridTarget`):
#: through the point itself (a voxel centroid), or through the mean of the
#: neighbours that gave its normal.
LINE_ANCHORS: tuple[str, ...] = ("point", "mean")


@dataclass(frozen=True, slots=True)
class IcpConfig:
    """Parameters of the target normals (`loopclosure.registration_target`) and of ICP
    (`loopclosure.registration`'s module docstring).

    Attributes:
        max_iterations: Gauss-Newton iterations at most.
        max_correspondence_distance: initial distance gate [m].
        min_correspondence_distance: the gate never shrinks below this [m].
        gate_sigmas: gate = this times the robust scale of point-to-point distances.
        kernel: ``"cauchy"``, ``"huber"``, ``"tukey"`` or ``"none"``.
        min_residual_scale: floor of the residual scale s and of sigma [m]
            (sensor noise plus map blur).
        translation_tolerance: convergence on the translation update [m].
        rotation_tolerance: convergence on the rotation update [rad].
        min_correspondences: fewer correspondences than this is a failure.
        normal_neighbors: neighbours (itself included) of the PCA normal.
        normal_radius: neighbours farther than this do not count [m].
        min_normal_neighbors: fewer neighbours than this: no normal, point dropped.
        max_normal_ratio: ``lambda_min / lambda_max`` above this: not line-like, dropped.
        fitness_tolerance: residual scale of `fitness` and of the inlier test [m].
        point_to_point_clutter: match source points whose nearest target point is
            clutter (enough neighbours, not line-like) point to point instead of
            dropping them (outdoor scans).
        clutter_weight: weight of those point-to-point rows relative to point-to-line
            ones (multiplies the robust kernel's weight).
    """

    max_iterations: int = 30
    max_correspondence_distance: float = 1.0
    min_correspondence_distance: float = 0.1
    gate_sigmas: float = 4.0
    kernel: str = "cauchy"
    min_residual_scale: float = 0.01
    translation_tolerance: float = 1e-4
    rotation_tolerance: float = 1e-4
    min_correspondences: int = 10
    normal_neighbors: int = 8
    normal_radius: float = 0.5
    min_normal_neighbors: int = 4
    max_normal_ratio: float = 0.1
    fitness_tolerance: float = 0.05
    point_to_point_clutter: bool = False
    clutter_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.kernel not in KERNEL_CONSTANTS:
            raise UserError(
                f"unknown ICP kernel {self.kernel!r}: choose one of {', '.join(KERNEL_CONSTANTS)}"
            )
        positive = (
            "max_correspondence_distance",
            "min_correspondence_distance",
            "gate_sigmas",
            "clutter_weight",
            "min_residual_scale",
            "normal_radius",
            "fitness_tolerance",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise UserError(f"ICP {name} must be a positive number, got {value}")
        if self.max_iterations < 1 or self.min_correspondences < 3:
            raise UserError(
                "ICP needs max_iterations >= 1 and min_correspondences >= 3, got "
                f"{self.max_iterations} and {self.min_correspondences}"
            )
        if self.normal_neighbors < 3 or not 2 <= self.min_normal_neighbors <= self.normal_neighbors:
            raise UserError(
                "ICP normals need normal_neighbors >= 3 and 2 <= min_normal_neighbors <= "
                f"normal_neighbors, got {self.normal_neighbors} and {self.min_normal_neighbors}"
            )


@dataclass(slots=True)
class IcpResult:
    """Outcome of one ICP run (`loopclosure.registration`'s module docstring defines
    every figure).

    Attributes:
        pose: ``(3,)`` pose of the source frame in the target frame (x, y, theta).
        covariance: ``3x3`` covariance of `pose` (x, y, theta), additive in the target
            frame; ``FAILED_VARIANCE * I`` when `ok` is False.
        hessian: ``3x3`` data information ``sum w J^T J`` (without the 1/sigma^2).
        sigma: residual standard deviation used for the covariance [m].
        inlier_ratio: inliers / source points.
        rms: RMS residual of the inliers [m] (0 without inliers).
        fitness: overlap score in [0, 1] (ranking of hypotheses).
        degeneracy: normalised smallest translational eigenvalue in [0, 0.5].
        degenerate_axis: ``(2,)`` unit direction of that eigenvalue (target frame).
        iterations: Gauss-Newton iterations run.
        converged: the update fell below the tolerances before `max_iterations`.
        correspondences: matched source points at the final pose.
        ok: enough correspondences for a solution (False: `pose` is the initial guess).
        initial: ``(3,)`` the initial guess it started from.
    """

    pose: Array
    covariance: Array
    hessian: Array
    sigma: float
    inlier_ratio: float
    rms: float
    fitness: float
    degeneracy: float
    degenerate_axis: Array
    iterations: int
    converged: bool
    correspondences: int
    ok: bool
    initial: Array = field(default_factory=lambda: np.zeros(3))


def as_points(points: ArrayLike, what: str) -> Array:
    """`points` as a float ``(N, 2)`` array of finite coordinates [m]; `what` names them
    in the `UserError` otherwise."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise UserError(f"{what} must be an (N, 2) array of points, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise UserError(f"{what} holds non-finite coordinates")
    return pts



def _failed(initial: Array, iterations: int, count: int, prior_cov: Array | None) -> IcpResult:
    cov = FAILED_VARIANCE * np.eye(3) if prior_cov is None else prior_cov.copy()
    return IcpResult(
        pose=initial.copy(), covariance=cov, hessian=np.zeros((3, 3)), sigma=0.0,
        inlier_ratio=0.0, rms=0.0, fitness=0.0, degeneracy=0.0,
        degenerate_axis=np.array([1.0, 0.0]), iterations=iterations, converged=False,
        correspondences=count, ok=False, initial=initial.copy(),
    )



def body_covariance(pose: ArrayLike, covariance: ArrayLike) -> Array:
    """`IcpResult.covariance` (additive in the target frame) as a right perturbation.

    ``pose_true = pose ⊕ eps`` with ``eps`` in the source (body) frame, the convention of
    gtsam's ``BetweenFactorPose2``: ``B^T C B`` with ``B = blockdiag(R(theta), 1)``.
    """
    th = float(np.asarray(pose, dtype=float).reshape(3)[2])
    c, s = np.cos(th), np.sin(th)
    b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = b.T @ np.asarray(covariance, dtype=float).reshape(3, 3) @ b
    return 0.5 * (out + out.T)


__all__ = ["FAILED_VARIANCE", "KERNEL_CONSTANTS", "LINE_ANCHORS", "IcpConfig", "IcpResult",
           "as_points", "body_covariance"]
