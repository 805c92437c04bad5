"""The joint graph of a saved map and the new session that has just been joined to it.

When enough of the new session's loops to the saved map agree (`slam.sessions`),
`slam.pipeline.Mapper` replaces its smoother, which held the new session alone in its
own frame, by one of both sessions in the map frame: `fill_joint_graph` adds the saved
map's graph (keys ``0 .. base - 1``: its poses, odometry and loops), then the new
session's graph with its poses moved by the transform the agreeing loops imply.
Poses are planar ``(x, y, theta)`` [m, m, rad].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from data import se2
from slam.pose_graph import PoseGraph
from slam.session_file import SavedMap
from slam.smoothers import IncrementalSmoother

Array = NDArray[np.float64]


def fill_joint_graph(
    joint: IncrementalSmoother, saved: SavedMap, base: int, graph: PoseGraph,
    estimate: Array, transform: Array,
) -> int:
    """Into the empty smoother `joint`: the `base` keyframes of `saved` with their
    odometry and loops, then `graph` (the new session's, keys from `base`) with every
    pose ``estimate[key]`` (its own frame) moved into the map frame by `transform`
    (``transform (+) pose``).  Returns the number of saved loops: the new session's
    loops come after them in `joint`, their indices moved by that offset."""
    for k in range(base):
        joint.add_pose(k, saved["kf_pose"][k])
    for (i, j), z, info in zip(saved["odom_ij"], saved["odom_z"], saved["odom_info"],
                               strict=True):
        joint.add_odometry(int(i), int(j), z, info)
    for (i, j), z, info in zip(saved["loop_ij"], saved["loop_z"], saved["loop_info"],
                               strict=True):
        joint.add_loop(int(i), int(j), z, info)
    offset = len(saved["loop_ij"])
    for key in sorted(graph.initial):
        joint.add_pose(key, se2.compose(transform, estimate[key]))
    for c in graph.odometry:
        joint.add_odometry(c.i, c.j, c.measurement, c.information)
    for c in graph.loops:
        joint.add_loop(c.i, c.j, c.measurement, c.information)
    return offset
