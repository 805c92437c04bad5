"""The nonlinear check of innovation-gate admissions (`AdmissionPass(confirm=True)`)."""

from __future__ import annotations

import numpy as np

from slam.admission import AdmissionPass
from slam.admission_undo import with_loops
from slam.optimize import initial_guess
from slam.pose_graph import PoseGraph
from tests.test_admission_undo import TRUE_LOOPS, _false_return_a_block_early
from tests.test_deferral import loose_lap


def _pass(graph: PoseGraph, confirm: bool) -> AdmissionPass:
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch", confirm=confirm)
    run.advance()
    return run


def _square() -> tuple[PoseGraph, int, int]:
    """Eight poses 1 m apart on a line, odometry exact at 0.1 m / 0.1 rad; a true loop
    (0, 7) saying 7 m and a false one (1, 6) saying 0 m: 5 m against 0.1 m sigmas over
    five steps, its actual cost is about 0.5 * 25 / (5 * 0.01 + 0.0025 ...) >> c."""
    graph = PoseGraph(dim=2)
    for k in range(8):
        graph.add_pose(k, np.array([float(k), 0.0, 0.0]))
    graph.fixed.add(0)
    for k in range(1, 8):
        graph.add_odometry(k - 1, k, np.array([1.0, 0.0, 0.0]), np.diag([100.0, 100.0, 100.0]))
    info = np.diag([400.0, 400.0, 2500.0])
    true = graph.add_loop(0, 7, np.array([7.0, 0.0, 0.0]), info)
    false = graph.add_loop(1, 6, np.zeros(3), info)
    return graph, true, false


def test_the_check_returns_the_loop_whose_actual_cost_is_above_c() -> None:
    graph, true, false = _square()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch")
    run.advance()
    pending = np.array([true, false])
    accepted = np.ones(2, dtype=bool)
    kept = with_loops(run._base, run.unit, pending)
    current = run._solve(kept, run.current)
    # by hand: the false loop alone costs above c; the true one costs nothing
    without = with_loops(run._base, run.unit, pending[:1])
    cost = kept.error(current) - without.error(run._solve(without, current))
    assert cost > run._c
    before = run._base.error(run._solve(run._base, run.current))
    back = run._unconfirmed(run._base, pending, accepted, np.arange(2), current, before,
                            run.current)
    np.testing.assert_array_equal(back, [1])


def test_the_check_changes_nothing_on_a_consistent_return() -> None:
    graph, _ = loose_lap(TRUE_LOOPS, False)
    plain, checked = _pass(graph, False), _pass(graph, True)
    assert checked.refused == 0
    np.testing.assert_array_equal(plain.weights, checked.weights)


def test_the_check_never_keeps_more_false_loops() -> None:
    graph, false = _false_return_a_block_early()
    plain, checked = _pass(graph, False), _pass(graph, True)
    assert checked.weights[false] <= plain.weights[false]
    assert checked.result().tls_cost <= plain.result().tls_cost * (1 + 1e-9)
