"""A deferred loop waits a bounded number of loop-bearing blocks, then the gate decides."""

from __future__ import annotations

import numpy as np

from slam.consistency import DEFER_MODES, admit_incrementally
from slam.optimize import initial_guess
from slam.pose_graph import PoseGraph

LAP = 240  # poses per lap of the circle


def _lap(
    true_loops: range, false_loop: bool, bias: float = 0.0
) -> tuple[PoseGraph, int | None]:
    """One and a half laps of a circle of radius 8 m, odometry exact but stated loosely
    (0.1 m, 0.1 rad per step); the return to the start is closed by the true loops
    ``(k, LAP + k)`` for k in `true_loops` and, with `false_loop`, one false loop a block
    before them that says pose ``LAP - 2`` is where pose 40 is.  `bias` [rad] is added to
    every odometry turn (the chain drifts, so the return is not obeyed at its start).
    Returns the graph and the false loop's index (None without it)."""
    n = LAP + LAP // 2
    step = 2 * np.pi / LAP
    radius = 8.0
    angles = step * np.arange(n)
    truth = np.stack([radius * np.sin(angles), radius * (1 - np.cos(angles)), angles], axis=1)
    graph = PoseGraph(dim=2)
    for k in range(n):
        graph.add_pose(k, truth[k])
    graph.fixed.add(0)
    odo = np.array([radius * np.sin(step), radius * (1 - np.cos(step)), step + bias])
    for k in range(1, n):
        graph.add_odometry(k - 1, k, odo, np.diag([100.0, 100.0, 100.0]))
    loop_info = np.diag([400.0, 400.0, 2500.0])
    false = graph.add_loop(40, LAP - 2, np.zeros(3), loop_info) if false_loop else None
    for k in true_loops:
        graph.add_loop(k, LAP + k, np.zeros(3), loop_info)
    return graph, false


def test_bounded_wait_lets_the_return_be_admitted_before_a_false_first_loop() -> None:
    graph, false = _lap(range(4, 36, 2), false_loop=True)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = admit_incrementally(graph, values, block=10, defer=True, wait=1)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert result.weights[false] == 0.0
    assert result.weights[true].all()


def test_a_lone_true_loop_is_decided_by_the_gate_after_its_wait() -> None:
    """No consensus ever comes for one loop: waiting to the end rejects it, a bounded
    wait hands it to the plain gate, which admits it."""
    graph, _ = _lap(range(4, 5), false_loop=False, bias=0.002)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    forever = admit_incrementally(graph, values, block=10, defer=True)
    bounded = admit_incrementally(graph, values, block=10, defer=True, wait=1)
    plain = admit_incrementally(graph, values, block=10)
    assert plain.weights[0] == 1.0
    assert forever.weights[0] == 0.0
    assert bounded.weights[0] == 1.0


def test_bounded_is_a_deferral_mode() -> None:
    assert {"bounded", "both"} <= set(DEFER_MODES)


def test_both_compares_the_passes_with_and_without_the_bounded_wait() -> None:
    from slam.consistency import incremental_tls

    graph, false = _lap(range(4, 36, 2), false_loop=True)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = incremental_tls(graph, values, block=10, defer="both", tries=0)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert result.weights[false] == 0.0
    assert result.weights[true].all()
