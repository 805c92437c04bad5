"""The nonlinear check of innovation-gate admissions (`AdmissionPass(confirm=True)`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from slam import admission
from slam.admission import AdmissionPass, _screen_order
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


def _line() -> tuple[PoseGraph, np.ndarray]:
    """Eight poses 1 m apart on a line, pose 0 fixed, odometry exact at 0.1 m / 0.1 rad
    sigmas; and the loops' information (0.05 m, 0.02 rad sigmas)."""
    graph = PoseGraph(dim=2)
    for k in range(8):
        graph.add_pose(k, np.array([float(k), 0.0, 0.0]))
    graph.fixed.add(0)
    for k in range(1, 8):
        graph.add_odometry(k - 1, k, np.array([1.0, 0.0, 0.0]), np.diag([100.0, 100.0, 100.0]))
    info = np.diag([400.0, 400.0, 2500.0])
    return graph, info


def _square() -> tuple[PoseGraph, int, int]:
    """Eight poses 1 m apart on a line, odometry exact at 0.1 m / 0.1 rad; a true loop
    (0, 7) saying 7 m and a false one (1, 6) saying 0 m: 5 m against 0.1 m sigmas over
    five steps, its actual cost is about 0.5 * 25 / (5 * 0.01 + 0.0025 ...) >> c."""
    graph, info = _line()
    true = graph.add_loop(0, 7, np.array([7.0, 0.0, 0.0]), info)
    false = graph.add_loop(1, 6, np.zeros(3), info)
    return graph, true, false


def _count_solves(run) -> list[int]:  # type: ignore[no-untyped-def]
    """The loops `run` solves without, one entry per leave-one-out solve, as they happen."""
    solves: list[int] = []
    solved_without = run._solved_without

    def counted(without, current, start, removed):  # type: ignore[no-untyped-def]
        solves.append(int(removed[-1]))
        return solved_without(without, current, start, removed)

    run._solved_without = counted  # type: ignore[method-assign]
    return solves


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


def _apart() -> tuple[PoseGraph, int, int]:
    """`_square`'s line with a false loop (1, 3) saying 0 m (2 m against 0.1 m sigmas
    over two steps: far above c) and a true loop (4, 7) saying 3 m on another stretch:
    at their joint solution the true loop's residual, and its leave-one-out cost, are
    about zero."""
    graph, info = _line()
    false = graph.add_loop(1, 3, np.zeros(3), info)
    true = graph.add_loop(4, 7, np.array([3.0, 0.0, 0.0]), info)
    return graph, true, false


def test_the_screen_turns_back_the_false_loop_with_one_solve() -> None:
    graph, true, false = _apart()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch", confirm="screen")
    run.advance()
    pending = np.array([true, false])
    kept = with_loops(run._base, run.unit, pending)
    current = run._solve(kept, run.current)
    before = run._base.error(run._solve(run._base, run.current))
    rho = run._screened(kept, current, pending)
    assert rho[0] < 1e-6 * run._c < run._c < rho[1]
    solves = _count_solves(run)
    back = run._unconfirmed(run._base, pending, np.ones(2, dtype=bool), np.arange(2),
                            current, before, run.current)
    np.testing.assert_array_equal(back, [1])
    # the true loop is cleared by the screen: only the false loop's minimum is solved
    assert solves == [false]
    run.screen = False  # the exact check turns back the same loop
    exact = run._unconfirmed(run._base, pending, np.ones(2, dtype=bool), np.arange(2),
                             current, before, run.current)
    np.testing.assert_array_equal(exact, back)


def test_the_screen_changes_nothing_on_a_consistent_return() -> None:
    graph, _ = loose_lap(TRUE_LOOPS, False)
    exact = _pass(graph, True)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    screened = AdmissionPass(graph, values, block=10, prefix_solver="batch", confirm="screen")
    screened.advance()
    assert screened.refused == 0
    np.testing.assert_array_equal(exact.weights, screened.weights)


def test_an_unknown_confirm_mode_is_refused() -> None:
    graph, _, _ = _square()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    with pytest.raises(UserError):
        AdmissionPass(graph, values, confirm="approximate")


def test_the_screen_order_is_decreasing_rho_or_admission_order() -> None:
    rho = np.array([1.0, np.inf, 3.0, 3.0])
    np.testing.assert_array_equal(_screen_order(rho, 4, True), [1, 2, 3, 0])
    np.testing.assert_array_equal(_screen_order(rho, 4, False), [0, 1, 2, 3])
    np.testing.assert_array_equal(_screen_order(None, 3, True), [0, 1, 2])


def _two_stretches() -> tuple[PoseGraph, int, int]:
    """`_apart`'s line with the false loop (1, 3) saying 0 m (leave-one-out cost 88.9 by
    the linear model: 2 m against 0.1 m sigmas over two steps) and a loop (4, 7) saying
    3.5 m over three 1 m steps: 0.5 m against a variance of 3 * 0.01 + 0.0025, a cost of
    0.5 * 0.25 / 0.0325 = 3.85, between c / 2 and c (c = 5.67 in 2D)."""
    graph, info = _line()
    near = graph.add_loop(4, 7, np.array([3.5, 0.0, 0.0]), info)
    false = graph.add_loop(1, 3, np.zeros(3), info)
    return graph, near, false


@pytest.mark.parametrize("skip", [True, False])
def test_the_screen_skips_a_loop_that_cannot_be_the_costliest(
    skip: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    graph, near, false = _two_stretches()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch", confirm="screen")
    run.advance()
    pending = np.array([near, false])  # the near loop admitted first
    kept = with_loops(run._base, run.unit, pending)
    current = run._solve(kept, run.current)
    before = run._base.error(run._solve(run._base, run.current))
    rho = run._screened(kept, current, pending)
    np.testing.assert_allclose(rho, [0.5 * 0.25 / 0.0325, 0.5 * 4.0 / 0.0225], rtol=1e-6)
    assert admission.SCREEN_FRACTION * run._c < rho[0] < run._c
    solves = _count_solves(run)
    monkeypatch.setattr(admission, "SCREEN_SKIP", skip)
    back = run._unconfirmed(run._base, pending, np.ones(2, dtype=bool), np.arange(2),
                            current, before, run.current)
    np.testing.assert_array_equal(back, [1])  # the false loop, either way
    # skipping: the false loop first (largest rho), then the near loop's rho is below
    # half its cost; without: both solved, in admission order
    assert solves == ([false] if skip else [near, false])


def test_a_turned_back_loop_leaves_the_leave_one_out_copy_as_the_prefix(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`ADOPT_LEAVE_ONE_OUT`: the false loop of `_square` admitted with the true one and
    turned back by the exact check; `_turned_back` then makes no iSAM2 solve and leaves
    the prefix at what taking the false loop out of the pass's iSAM2 and solving gives
    (what it does with the option off), bit for bit."""
    from slam.isam_prefix import IsamPrefix

    graph, true, false = _square()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    calls: list[int] = []
    solve = IsamPrefix.solve
    monkeypatch.setattr(IsamPrefix, "solve", lambda self: calls.append(1) or solve(self))
    results = []
    for adopt in (True, False):
        monkeypatch.setattr(admission, "ADOPT_LEAVE_ONE_OUT", adopt)
        run = AdmissionPass(graph, values, block=10, barred=[true, false], confirm=True)
        run.advance()  # the odometry prefix, kept by iSAM2
        pending = np.array([true, false])
        start = run.current
        solved, _ = run._prefix_solve(with_loops(run._base, run.unit, pending), start, pending)
        back = run._unconfirmed(run._base, pending, np.ones(2, dtype=bool), np.arange(2),
                                solved, run._base.error(start), start)
        np.testing.assert_array_equal(back, [1])
        calls.clear()
        result, isam = run._turned_back(with_loops(run._base, run.unit, pending[:1]), start,
                                        pending[back])
        assert len(calls) == (0 if adopt else 1)
        assert isam is run._isam and isam.holds([true]) and not isam.holds([false])
        results.append([result.atPose2(k).matrix() for k in graph.keys])
    np.testing.assert_array_equal(results[0], results[1])
