"""Core data types, plain and numpy-backed.  Units: seconds, metres, radians.

Frames: a `Scan`'s ranges and angles are in the sensor (laser) frame, beam angle 0
along the sensor's x axis, counter-clockwise positive.  Planar poses are
``(x, y, theta)`` arrays (see `data.se2`); 3D poses are ``4x4`` homogeneous
matrices.  Each class says which it holds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError

Array = NDArray[np.float64]


@dataclass(slots=True)
class Scan:
    """One planar laser scan.

    Attributes:
        stamp: acquisition time [s] (CARMEN ipc timestamp, ROS header stamp).
        ranges: ``(N,)`` raw range readings [m] as logged, float64.  Invalid beams
            keep their raw value (NaN, inf, 0, max-range); use `valid` to tell them.
        angles: ``(N,)`` beam bearings in the sensor frame [rad], increasing.
        max_range: readings ``>= max_range`` are "no return" [m].
        min_range: readings ``<= min_range`` are invalid [m].
        odom: ``(3,)`` pose of the *sensor* in the odometry frame, or None when the
            source has no odometry.  In raw CARMEN logs this is the pose field of the
            laser message (wheel odometry); in the GMapping-corrected logs it is the
            corrected pose.
        index: position of the scan in its source (0-based).
    """

    stamp: float
    ranges: Array
    angles: Array
    max_range: float
    min_range: float = 0.0
    odom: Array | None = None
    index: int = 0

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Beams with a real return: finite, ``> min_range`` and ``< max_range``."""
        r = self.ranges
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r > max(self.min_range, 0.0)) & (r < self.max_range)

    @property
    def fov(self) -> float:
        """Field of view [rad]: first to last beam (ROS's ``angle_max - angle_min``; pi for a
        SICK's 181 beams over 180 degrees), or 2 pi when the beams close the circle (the
        span plus one beam spacing reaches 360 degrees)."""
        if len(self.angles) < 2:
            return 0.0
        span = float(self.angles[-1] - self.angles[0])
        step = span / (len(self.angles) - 1)
        return 2.0 * np.pi if span + abs(step) >= 2.0 * np.pi - 1e-6 else span

    def points(self) -> Array:
        """``(M, 2)`` end points of the valid beams in the sensor frame [m]."""
        v = self.valid
        r, a = self.ranges[v], self.angles[v]
        return np.column_stack([r * np.cos(a), r * np.sin(a)])


@dataclass(slots=True)
class PointCloud:
    """One 3D point cloud (e.g. a `sensor_msgs/PointCloud2`).

    Attributes:
        stamp: acquisition time [s].
        points: ``(N, 3)`` finite points in the sensor frame [m].
        odom: ``4x4`` pose of the sensor in the odometry frame, or None.
        index: position in its source (0-based).
    """

    stamp: float
    points: Array
    odom: Array | None = None
    index: int = 0


@dataclass(slots=True)
class Trajectory:
    """Timed poses.  ``poses`` is ``(N, 4, 4)``: pose of the body in the world frame.

    Planar trajectories have z = 0 and rotations about z only; use `xytheta()`.
    """

    stamps: Array
    poses: Array

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=float).reshape(-1, 4, 4)
        if len(self.stamps) != len(self.poses):
            raise UserError(f"Trajectory: {len(self.stamps)} stamps but {len(self.poses)} poses "
                            "(need one stamp per pose)")

    @classmethod
    def from_xytheta(cls, stamps: Array, poses: Array) -> Trajectory:
        """Trajectory of planar poses ``(N, 3)`` (x [m], y [m], theta [rad])."""
        return cls(np.asarray(stamps, dtype=float), se2.to_se3(np.asarray(poses).reshape(-1, 3)))

    def xytheta(self) -> Array:
        """``(N, 3)`` planar poses (x, y, yaw) of the trajectory."""
        return se2.from_matrix(self.poses)

    def __len__(self) -> int:
        return len(self.stamps)


@dataclass(slots=True)
class Relation:
    """A reference relative pose between two stamps (Kümmerle et al. 2009).

    ``delta`` is the ``4x4`` pose of the body at `t2` in the body frame at `t1`.
    The file holds ``t1 t2 x y z roll pitch yaw``.
    """

    t1: float
    t2: float
    delta: Array


@dataclass(slots=True)
class GraphEdge:
    """A relative-pose constraint of a pose graph (g2o ``EDGE_SE2`` / ``EDGE_SE3:QUAT``).

    Attributes:
        i, j: vertex ids; the measurement is the pose of `j` in the frame of `i`.
        measurement: ``(3,)`` (x, y, theta) for SE2, ``4x4`` matrix for SE3.
        information: ``3x3`` (x, y, theta) or ``6x6`` (x, y, z, rx, ry, rz) information
            matrix, in g2o's ordering.
    """

    i: int
    j: int
    measurement: Array
    information: Array


@dataclass(slots=True)
class PoseGraphData:
    """A pose graph as read from or written to a g2o file.

    Attributes:
        dim: 2 (SE2) or 3 (SE3).
        vertices: id -> pose, ``(3,)`` (x, y, theta) for SE2 or ``4x4`` for SE3.
        edges: constraints in file order.
        fixed: ids of vertices marked ``FIX``.
    """

    dim: int
    vertices: dict[int, Array] = field(default_factory=dict)
    edges: list[GraphEdge] = field(default_factory=list)
    fixed: set[int] = field(default_factory=set)


@dataclass(slots=True)
class SourceInfo:
    """What `loopclosure info` prints about a log, bag or graph.

    Counts that do not apply are None (e.g. `beams` of a g2o file).
    """

    format: str
    path: str
    scans: int | None = None
    beams: int | None = None
    fov_deg: float | None = None
    max_range: float | None = None
    duration_s: float | None = None
    odometry: int | None = None
    topics: dict[str, str] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Plain dict for ``--json`` output (extra keys merged in)."""
        out: dict[str, Any] = {
            "format": self.format,
            "path": self.path,
            "scans": self.scans,
            "beams": self.beams,
            "fov_deg": self.fov_deg,
            "max_range": self.max_range,
            "duration_s": self.duration_s,
            "odometry": self.odometry,
            "topics": self.topics,
        }
        out.update(self.extra)
        return out
