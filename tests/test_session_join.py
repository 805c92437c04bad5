"""`slam.session_join.fill_joint_graph`: a saved map of two keyframes and a new session
of two, joined by a hand-picked transform."""

from __future__ import annotations

import numpy as np

from data import se2
from slam.pose_graph import PoseGraph
from slam.session_join import fill_joint_graph
from slam.smoothers import IncrementalSmoother

INFO = np.diag([100.0, 100.0, 400.0])


def test_the_saved_graph_then_the_new_session_moved_into_the_map_frame() -> None:
    saved = {  # the fields of a `SavedMap` the join reads
        "kf_pose": np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
        "odom_ij": np.array([[0, 1]]), "odom_z": np.array([[1.0, 0.0, 0.0]]),
        "odom_info": np.array([INFO]),
        "loop_ij": np.array([[1, 0]]), "loop_z": np.array([[-1.0, 0.0, 0.0]]),
        "loop_info": np.array([INFO]),
    }
    session = PoseGraph(dim=2)  # keys 2 and 3, in the new session's own frame
    session.add_pose(2, np.zeros(3))
    session.add_pose(3, np.array([0.0, 2.0, 0.0]))
    session.add_odometry(2, 3, np.array([0.0, 2.0, 0.0]), INFO)
    session.add_loop(3, 2, np.array([0.0, -2.0, 0.0]), INFO)
    estimate = np.array([[9.0, 9.0, 9.0], [9.0, 9.0, 9.0],  # rows of the saved keys: unused
                         [0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    transform = np.array([1.0, 0.0, np.pi / 2])  # a quarter turn about (1, 0)
    joint = IncrementalSmoother(kernel="none")
    offset = fill_joint_graph(joint, saved, 2, session, estimate, transform)

    assert offset == 1  # the saved map's one loop comes first
    graph = joint.graph
    assert sorted(graph.initial) == [0, 1, 2, 3]
    np.testing.assert_allclose(graph.initial[1], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(graph.initial[2], [1.0, 0.0, np.pi / 2])
    # (0, 2) turned a quarter (to (-2, 0)) and moved by (1, 0): (-1, 0).
    np.testing.assert_allclose(graph.initial[3], [-1.0, 0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(graph.initial[3], se2.compose(transform, estimate[3]))
    assert [(c.i, c.j) for c in graph.odometry] == [(0, 1), (2, 3)]
    assert [(c.i, c.j) for c in graph.loops] == [(1, 0), (3, 2)]
    np.testing.assert_allclose(graph.loops[1].measurement, [0.0, -2.0, 0.0])
