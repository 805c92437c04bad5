"""Drift since the last loop closure: the covariance that gates the mapper's loop search.

`slam.pipeline.Mapper` keeps the covariance of its newest keyframe's pose relative to
the last loop closure, in the map frame: each odometry step propagates it
(`_propagate_drift`), a loop closure resets it to the loop's own covariance turned
into the map frame (`_rotate_covariance`).  Poses are planar ``(x, y, theta)``
[m, m, rad].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def _rotate_covariance(cov: Array, theta: float) -> Array:
    """A ``(x, y, theta)`` covariance given in a frame at heading `theta`, in the map frame."""
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot @ cov @ rot.T


def _propagate_drift(drift: Array, pose: Array, delta: Array, cov: Array) -> Array:
    """First-order covariance of ``pose (+) delta`` in the map frame.

    `drift` is the covariance of `pose` (map frame, x y theta), `cov` that of `delta`
    (body frame of `pose`).  This is the uncertainty a search gate needs: how far the
    pose may have drifted since the last loop closure, without the cost of iSAM2
    marginals (which also measure drift from the *first* pose, and so grow without
    bound on a long run even where the map is locally consistent).
    """
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = delta[0], delta[1]
    jac_pose = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy],
                         [0.0, 0.0, 1.0]])
    return jac_pose @ drift @ jac_pose.T + _rotate_covariance(cov, pose[2])
