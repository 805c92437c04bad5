"""Wheel odometry as logged: the scan's ``odom`` field, with a documented noise model.

The pose of each scan is its ``odom`` (sensor pose in the odometry frame: the
laser pose of a CARMEN ``FLASER`` line, the interpolated ``ODOM`` pose composed
with the laser mounting for ``RAWLASER``, the simulator's drifting odometry).
``delta`` is the increment from the previous scan; its covariance comes from
`slam.odometry.MotionNoise` (variances proportional to the distance and the
rotation of the increment, plus a floor), scaled by `WheelConfig.noise`.

A scan without odometry (or with a non-finite one) keeps the previous pose: zero
motion, status ``no_odometry`` and the covariance of the model for
`WheelConfig.missing_step` (a generous step) so a pose graph does not trust it.
Poses are given as logged: the odometry frame is the log's (first pose =
first ``odom``).  Accepts `Scan` and `PointCloud` (a ``4x4`` ``odom`` is projected
to the plane).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from data import se2
from slam.odometry import MotionNoise, OdometryEstimate, scan_odometry


@dataclass(frozen=True, slots=True)
class WheelConfig:
    """Parameters of the wheel front end.

    Attributes:
        noise: the increment noise model.
        missing_step: ``(dx, dy, dtheta)`` whose model covariance is given to a scan
            without odometry [m, m, rad].
    """

    noise: MotionNoise = field(default_factory=MotionNoise)
    missing_step: tuple[float, float, float] = (1.0, 0.0, 0.5)


class WheelOdometry:
    """``process(scan)``: the logged odometry as an `OdometryEstimate`."""

    name = "wheel"

    def __init__(self, config: WheelConfig | None = None) -> None:
        self.config = config or WheelConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the previous scan."""
        self._pose: np.ndarray | None = None
        self._odom: np.ndarray | None = None

    def process(self, scan: Any) -> OdometryEstimate:
        """Estimate for `scan` (module docstring)."""
        t0 = time.perf_counter()
        odom = scan_odometry(scan)
        extra: dict[str, Any] = {}
        if self._pose is None:
            pose = odom.copy() if odom is not None else np.zeros(3)
            delta = np.zeros(3)
            cov = self.config.noise.covariance(delta)
            status = "first"
        elif odom is None:
            pose = self._pose.copy()
            delta = np.zeros(3)
            cov = self.config.noise.covariance(self.config.missing_step)
            status = "no_odometry"
        else:
            delta = se2.between(self._odom, odom) if self._odom is not None else np.zeros(3)
            pose = se2.compose(self._pose, delta)
            cov = self.config.noise.covariance(delta)
            status = "ok"
        self._pose = pose
        if odom is not None:
            self._odom = odom
        return OdometryEstimate(
            stamp=float(scan.stamp),
            index=int(getattr(scan, "index", 0)),
            pose=pose,
            delta=delta,
            covariance=cov,
            fitness=0.0,
            seconds=time.perf_counter() - t0,
            status=status,
            extra=extra,
        )
