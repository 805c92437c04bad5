"""Loops whose innovation test has no power are deferred and decided by consensus."""

from __future__ import annotations

import numpy as np

from slam.consistency import admit_incrementally
from slam.deferral import power
from slam.optimize import initial_guess
from slam.pose_graph import PoseGraph

LAP = 240  # poses per lap of the circle


def loose_lap(
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


def _return_after_a_long_loose_lap() -> tuple[PoseGraph, int]:
    """`loose_lap` closed by 16 true loops and the false loop (40, LAP - 2) before them."""
    graph, false = loose_lap(range(4, 36, 2), True)
    assert false is not None
    return graph, false


def test_a_false_first_return_is_deferred_and_rejected() -> None:
    graph, false = _return_after_a_long_loose_lap()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = admit_incrementally(graph, values, block=10, defer=True)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert result.weights[false] == 0.0
    assert result.weights[true].all()


def test_without_deferral_the_false_loop_bends_the_lap() -> None:
    """The failure the deferral removes: decided in its own block, the false loop passes
    the innovation gate and the true loops of the return are rejected."""
    from slam.consistency import AdmissionPass

    graph, false = _return_after_a_long_loose_lap()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10)
    run.advance()
    assert run.weights[false] == 1.0
    assert run.weights.sum() < len(graph.loops) / 2


def test_power_is_the_share_of_distinguishable_places_the_gate_rejects() -> None:
    gate = 5.67
    offsets = np.zeros((3, 4, 3))
    offsets[:, :, 0] = [1.0, 2.0, 4.0, 8.0]  # whitened offsets of four places
    covariances = np.stack([np.eye(3), 4.0 * np.eye(3), 100.0 * np.eye(3)])
    out = power(covariances, offsets, gate)
    # Places 4 and 8 are told apart by a perfect test (0.5 d^2 >= 5.67); S = 4 rejects
    # 8 only (0.5 * 64 / 4 = 8), S = 100 neither.
    np.testing.assert_allclose(out, [1.0, 0.5, 0.0])
