"""Odometry front ends: one output type, one factory, three implementations.

Front ends (`make_odometry(name, config)`):

* ``"icp2d"``: our scan-to-map ICP, point to line and, on clutter, point to point
  (`slam.odometry.icp2d`).
* ``"kiss-icp"``: KISS-ICP on point clouds and on planar scans lifted to z = 0
  (`slam.odometry.kiss`).
* ``"wheel"``: the odometry in the log (`slam.odometry.wheel`).

Each is a class with ``process(scan) -> OdometryEstimate`` (called once per scan in
the source's order) and ``reset()``.

Frames and conventions (all front ends)
---------------------------------------
* ``pose`` is the pose of the *sensor* in the odometry frame, ``(x, y, theta)``
  [m, m, rad].  The odometry frame is the frame of the first scan's ``odom``
  when it has one (so the first pose equals it), else the first scan's sensor
  frame (first pose zero).
* ``delta`` is ``between(previous pose, pose)``: the motion since the previous
  processed scan in the previous sensor frame (zero for the first scan).
* ``covariance`` (``3x3``, x, y, theta) is the covariance of `delta` as a *right*
  perturbation, ``delta_true = delta ⊕ eps``, ``eps ~ N(0, covariance)``: the
  convention of gtsam's ``BetweenFactorPose2`` noise model.  Use `accumulate` to
  chain increments into keyframe-to-keyframe factors.
* Never NaN: a scan the front end cannot use (no valid beams, failed match,
  odometry jump) still gets an estimate, from the motion prediction, with an
  inflated covariance and a ``status`` saying why (`STATUSES`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from data.types import Scan

Array = NDArray[np.float64]

#: Front-end names accepted by `make_odometry` (and the CLI's ``--odometry``).
FRONT_ENDS: tuple[str, ...] = ("icp2d", "kiss-icp", "wheel")


#: Values of `OdometryEstimate.status`.
STATUSES: dict[str, str] = {
    "first": "first scan: the origin of the odometry frame",
    "ok": "registered (or, for wheel, taken from the log)",
    "degenerate": "registered, but one direction was unconstrained (e.g. a corridor); "
    "the motion prediction fixed it",
    "no_points": "too few valid beams: motion prediction, inflated covariance",
    "failed": "registration failed (too few inliers or too large residual): "
    "motion prediction, inflated covariance",
    "odometry_jump": "implausible odometry increment (kidnap or glitch): registered "
    "without it when the map confirms a pose (extra['kidnap'] False), else the map "
    "restarts and the increment gets a huge covariance (extra['kidnap'] True)",
    "no_odometry": "wheel front end on a scan without odometry: zero motion, "
    "inflated covariance",
}


@dataclass(slots=True)
class OdometryEstimate:
    """One front-end output per scan (see module docstring for frames).

    Attributes:
        stamp: the scan's stamp [s].
        index: the scan's index in its source.
        pose: ``(3,)`` sensor pose in the odometry frame (x [m], y [m], theta [rad]).
        delta: ``(3,)`` motion since the previous scan, in the previous sensor frame.
        covariance: ``3x3`` covariance of `delta` (right perturbation; x, y, theta).
        fitness: registration overlap score in [0, 1] (`loopclosure.registration`);
            0 when the estimate does not come from our ICP (wheel, kiss-icp, fallbacks).
        seconds: wall time spent on this scan by the front end [s].
        status: one of `STATUSES`.
        matrix: ``4x4`` full pose when the front end is 3D (kiss-icp), else None.
        extra: front-end specific figures (inlier ratio, rms, iterations, ...).
    """

    stamp: float
    index: int
    pose: Array
    delta: Array
    covariance: Array
    fitness: float
    seconds: float
    status: str
    matrix: Array | None = None
    extra: dict[str, Any] = field(default_factory=dict)


class Odometry(Protocol):
    """What every front end provides."""

    name: str

    def process(self, scan: Any) -> OdometryEstimate:
        """The estimate for the next scan (in source order)."""
        ...

    def reset(self) -> None:
        """Forget everything: the next scan starts a new odometry frame."""
        ...


@dataclass(frozen=True, slots=True)
class MotionNoise:
    """Documented odometry noise model: variances proportional to distance and rotation.

    For an increment with travelled distance ``d = |(dx, dy)|`` [m] and rotation
    ``|dtheta|`` [rad] (a random walk, so the accumulated variance does not depend on
    the scan rate)::

        var_x     = along_per_m^2   d + along_per_rad^2   |dtheta| + min_sigma_xy^2
        var_y     = lateral_per_m^2 d + lateral_per_rad^2 |dtheta| + min_sigma_xy^2
        var_theta = rot_per_m^2     d + rot_per_rad^2     |dtheta| + min_sigma_theta^2

    x is along the robot's heading (the increment's frame), y to the left.
    Defaults: 10 cm after 1 m along the path, 5 cm sideways, 2.9 degrees of heading
    per metre and 10 % per radian turned (typical indoor wheel odometry, e.g.
    Probabilistic Robotics ch. 5; not fitted to any log).

    Attributes:
        along_per_m: [m / sqrt(m)].  along_per_rad: [m / sqrt(rad)].
        lateral_per_m: [m / sqrt(m)].  lateral_per_rad: [m / sqrt(rad)].
        rot_per_m: [rad / sqrt(m)].  rot_per_rad: [rad / sqrt(rad)].
        min_sigma_xy: floor [m].  min_sigma_theta: floor [rad].
    """

    along_per_m: float = 0.10
    along_per_rad: float = 0.02
    lateral_per_m: float = 0.05
    lateral_per_rad: float = 0.02
    rot_per_m: float = 0.05
    rot_per_rad: float = 0.10
    min_sigma_xy: float = 1e-3
    min_sigma_theta: float = 1e-3

    def __post_init__(self) -> None:
        for name in self.__slots__:  # type: ignore[attr-defined]
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise UserError(f"motion noise {name} must be a number >= 0, got {value}")

    def covariance(self, delta: ArrayLike) -> Array:
        """``3x3`` diagonal covariance of one increment ``(dx, dy, dtheta)``."""
        d = np.asarray(delta, dtype=float).reshape(3)
        dist = float(np.hypot(d[0], d[1]))
        rot = float(abs(se2.wrap_angle(d[2])))
        return self.diagonal(dist, rot)

    def diagonal(self, dist: float, rot: float) -> Array:
        """`covariance` of an increment of length `dist` [m] (``hypot(dx, dy)``) and
        turn `rot` [rad] (``|wrap(dtheta)|``), for a caller that has both already."""
        xx = self.along_per_m**2 * dist + self.along_per_rad**2 * rot + self.min_sigma_xy**2
        yy = self.lateral_per_m**2 * dist + self.lateral_per_rad**2 * rot + self.min_sigma_xy**2
        tt = self.rot_per_m**2 * dist + self.rot_per_rad**2 * rot + self.min_sigma_theta**2
        # np.diag of the three, without its conversions (the front end asks every scan)
        return np.array([[xx, 0.0, 0.0], [0.0, yy, 0.0], [0.0, 0.0, tt]])


def adjoint(pose: ArrayLike) -> Array:
    """``3x3`` adjoint of an SE(2) pose (x, y, theta), tangent order (x, y, theta).

    ``pose ⊕ exp(eps) ⊕ pose^-1 = exp(adjoint(pose) @ eps)`` to first order.
    """
    x, y, th = np.asarray(pose, dtype=float).reshape(3)
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s, y], [s, c, -x], [0.0, 0.0, 1.0]])


def accumulate(
    delta_ab: ArrayLike, cov_ab: ArrayLike, delta_bc: ArrayLike, cov_bc: ArrayLike
) -> tuple[Array, Array]:
    """Chain two independent increments: ``delta_ac = delta_ab ⊕ delta_bc`` and its covariance.

    Right-perturbation covariances (module docstring), to first order::

        cov_ac = Ad(delta_bc^-1) cov_ab Ad(delta_bc^-1)^T + cov_bc
    """
    d_bc = np.asarray(delta_bc, dtype=float).reshape(3)
    ad = adjoint(se2.inverse(d_bc))
    cov = ad @ np.asarray(cov_ab, dtype=float).reshape(3, 3) @ ad.T + np.asarray(
        cov_bc, dtype=float
    ).reshape(3, 3)
    return se2.compose(np.asarray(delta_ab, dtype=float).reshape(3), d_bc), 0.5 * (cov + cov.T)


def scan_odometry(scan: Scan) -> Array | None:
    """The scan's odometry pose ``(3,)`` if present and finite, else None."""
    odom = getattr(scan, "odom", None)
    if odom is None:
        return None
    if type(odom) is np.ndarray and odom.dtype == np.float64 and odom.shape == (3,):
        # A reader's usual odometry (every scan of a log): three float checks instead
        # of numpy's conversions, reshape and reduction.
        x, y, theta = odom.tolist()
        return odom if math.isfinite(x) and math.isfinite(y) and math.isfinite(theta) else None
    odom = np.asarray(odom, dtype=float)
    if odom.shape == (4, 4):
        odom = se2.from_matrix(odom)
    odom = odom.reshape(-1)
    if odom.shape != (3,) or not np.all(np.isfinite(odom)):
        return None
    return odom


def make_odometry(name: str, config: Any = None) -> Odometry:
    """A front end by name (`FRONT_ENDS`), with its config object (None: defaults).

    ``"icp2d"`` takes an `Icp2dConfig`, ``"kiss-icp"`` a `KissConfig`, ``"wheel"`` a
    `WheelConfig`.  Raises `UserError` for an unknown name or a config of the wrong type.
    """
    key = name.strip().lower().replace("_", "-")
    if key in ("kiss", "kissicp"):
        key = "kiss-icp"
    if key == "icp2d":
        from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry

        return Icp2dOdometry(_checked(config, Icp2dConfig, name))
    if key == "kiss-icp":
        from slam.odometry.kiss import KissConfig, KissOdometry

        return KissOdometry(_checked(config, KissConfig, name))
    if key == "wheel":
        from slam.odometry.wheel import WheelConfig, WheelOdometry

        return WheelOdometry(_checked(config, WheelConfig, name))
    raise UserError(f"unknown odometry {name!r}: choose one of {', '.join(FRONT_ENDS)}")


def _checked(config: Any, kind: type, name: str) -> Any:
    if config is None:
        return kind()
    if not isinstance(config, kind):
        raise UserError(
            f"odometry {name!r} needs a {kind.__name__}, got {type(config).__name__}"
        )
    return config


__all__ = [
    "FRONT_ENDS",
    "STATUSES",
    "MotionNoise",
    "Odometry",
    "OdometryEstimate",
    "accumulate",
    "adjoint",
    "make_odometry",
    "scan_odometry",
]
