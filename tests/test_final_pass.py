"""`slam.final_pass`: where the final GNC starts, and a false loop rejected and marked
on its event."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from data import se2
from slam.config import BackendConfig
from slam.final_pass import final_gnc, final_start
from slam.mapping_result import LoopEvent
from slam.pose_graph import PoseGraph

INFO = np.diag([100.0, 100.0, 400.0])


def _square(laps: int = 2) -> tuple[PoseGraph, np.ndarray]:
    """`laps` laps of a 4 m square in 1 m steps, exact odometry, a loop at every revisit."""
    steps = [np.array([1.0, 0.0, 0.0])] * 3 + [np.array([1.0, 0.0, np.pi / 2])]
    truth = [np.zeros(3)]
    for _ in range(4 * laps):
        for s in steps:
            truth.append(se2.compose(truth[-1], s))
    graph = PoseGraph(dim=2)
    for k, pose in enumerate(truth):
        graph.add_pose(k, pose)
        if k:
            graph.add_odometry(k - 1, k, steps[(k - 1) % 4], INFO)
    for k in range(16, len(truth)):
        graph.add_loop(k - 16, k, se2.between(truth[k - 16], truth[k]), INFO)
    return graph, np.array(truth)


def test_a_graph_without_an_odometry_spine_starts_from_the_given_poses() -> None:
    graph, _ = _square()
    incremental = BackendConfig(final_start="incremental")
    assert final_start(graph, incremental) == "incremental"
    graph.odometry.pop(5)  # pose 6 is reached by loops alone
    assert final_start(graph, incremental) == "given"
    assert final_start(graph, BackendConfig(final_start="given")) == "given"


def test_the_false_loop_is_rejected_and_its_event_marked() -> None:
    graph, truth = _square()
    bad = graph.add_loop(3, 20, np.array([0.5, 3.0, 1.0]), INFO)
    events = [LoopEvent(SimpleNamespace(), 0.0, 0.0, factor=0),
              LoopEvent(SimpleNamespace(), 0.0, 0.0, factor=bad),
              LoopEvent(SimpleNamespace(), 0.0, 0.0)]  # never added to the graph
    poses, rejected = final_gnc(graph, dict(graph.initial), BackendConfig(), events)
    assert rejected == {bad}
    assert [e.rejected_by_gnc for e in events] == [False, True, False]
    solved = np.array([poses[k] for k in range(len(truth))])
    np.testing.assert_allclose(solved[:, :2], truth[:, :2], atol=1e-6)
    np.testing.assert_allclose(np.cos(solved[:, 2] - truth[:, 2]), 1.0, atol=1e-9)
