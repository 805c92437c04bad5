"""Factors taken out of the iSAM2 prefix (`IsamPrefix.remove`, `IsamPrefix.of`) and the
incremental confirm check that uses them."""

from __future__ import annotations

import gtsam
import numpy as np

from slam.admission import AdmissionPass
from slam.isam_prefix import IsamPrefix
from slam.least_squares import StickySolver
from slam.optimize import initial_guess
from slam.pose_graph import Constraint, PoseGraph
from tests.test_admission_confirm import _square
from tests.test_consistency_prefix import square_chain_prefix


def _chain() -> tuple[IsamPrefix, gtsam.NonlinearFactorGraph, gtsam.Values, object]:
    """The square graph's anchor and odometry solved in an `IsamPrefix`, and its first
    loop moved 5 m off (a false loop)."""
    isam = IsamPrefix()
    graph, factors = square_chain_prefix(isam)
    loop = graph.loops[0]
    false = Constraint(loop.i, loop.j, loop.measurement + np.array([5.0, 0.0, 1.0]),
                       loop.information)
    return isam, factors, isam.solve(), graph.between_factor(false)


def test_a_removed_loop_leaves_the_prefix_without_it() -> None:
    isam, factors, chain, false = _chain()
    isam.add(false, "false")
    bent = isam.solve()
    assert factors.error(bent) > factors.error(chain) + 1.0  # the false loop bent the chain
    isam.remove(["false"])
    unbent = isam.solve()
    assert isam.converged
    # the odometry chain alone has zero error at its solution: iSAM2 returns to it
    assert factors.error(unbent) < 1e-6
    assert not isam._index and isam._all.size() == factors.size()


def test_a_copy_keeps_the_tags_and_a_rebuilt_prefix_solves_as_the_original() -> None:
    isam, factors, chain, false = _chain()
    isam.add(false, 7)
    other = isam.copy()
    isam.solve()
    other.solve()
    other.remove([7])
    assert factors.error(other.solve()) < 1e-6
    fresh = IsamPrefix.of(factors, chain)
    assert factors.error(fresh.solve()) < 1e-6


def test_the_incremental_check_turns_back_what_the_re_solves_did() -> None:
    """A lone admitted loop's cost is the joint cost: the check needs no re-solve and
    turns back the loop whose cost a batch solve without it puts above c."""
    graph, true, false = _square()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch")
    run.advance()
    solve = StickySolver()
    base = run._base
    with_true = gtsam.NonlinearFactorGraph(base)
    with_true.add(run.unit[true])
    before_values = solve(with_true, run.current)
    both = gtsam.NonlinearFactorGraph(with_true)
    both.add(run.unit[false])
    solved = solve(both, before_values)
    pending = np.array([true, false])
    accepted = np.ones(2, dtype=bool)
    calls = []
    run._solve = lambda f, v: calls.append(1) or solve(f, v)
    back = run._unconfirmed(base, pending, accepted, np.array([1]), solved,
                            with_true.error(before_values), before_values)
    np.testing.assert_array_equal(back, [1])
    assert not calls  # one admitted loop: its cost is the joint cost
    cost = both.error(solved) - with_true.error(before_values)
    assert cost > run._c


def _bent_chain() -> tuple[PoseGraph, int, int]:
    """Twenty poses 1 m apart on a line, odometry exact with information 100 (position)
    and 10 (heading); a false loop (0, 9) saying 9 m ahead and 5 m aside, whose
    linearised innovation passes the gate while bending the chain costs more than ``c``
    (the heading's freedom is what the linearisation over-states), and a true loop
    (0, 19) in the next block."""
    graph = PoseGraph(dim=2)
    for k in range(20):
        graph.add_pose(k, np.array([float(k), 0.0, 0.0]))
    graph.fixed.add(0)
    for k in range(1, 20):
        graph.add_odometry(k - 1, k, np.array([1.0, 0.0, 0.0]), np.diag([100.0, 100.0, 10.0]))
    info = np.diag([10.0, 10.0, 10.0])
    false = graph.add_loop(0, 9, np.array([9.0, 5.0, 0.0]), info)
    true = graph.add_loop(0, 19, np.array([19.0, 0.0, 0.0]), info)
    return graph, false, true


def test_a_pass_that_turns_loops_back_keeps_its_isam2_prefix_and_decides_as_batch() -> None:
    graph, false, true = _bent_chain()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    runs = {}
    for mode in ("batch", "isam2"):
        runs[mode] = AdmissionPass(graph, values, block=10, prefix_solver=mode, confirm=True)
        runs[mode].advance()
    assert runs["isam2"].refused == runs["batch"].refused == 1
    np.testing.assert_array_equal(runs["isam2"].weights, runs["batch"].weights)
    assert runs["isam2"].weights[false] == 0 and runs["isam2"].weights[true] == 1
    assert runs["isam2"].result().prefix == "isam2"  # never handed over to batch solves
    gap = runs["isam2"].result().tls_cost - runs["batch"].result().tls_cost
    assert abs(gap) < 1e-6


def test_holds_says_whether_every_tag_can_be_taken_out() -> None:
    isam, _, _, false = _chain()
    isam.add(false, 3)
    assert isam.holds([3])  # handed over, not solved yet
    isam.solve()
    assert isam.holds([3]) and isam.holds([])
    assert not isam.holds([3, 4])  # 4 was never handed over with its tag
    isam.remove([3])
    isam.solve()
    assert not isam.holds([3])
