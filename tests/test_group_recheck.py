"""The group test of the segment re-check: loops that agree with one another, tested whole."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from evaluation.robustness import aligned_position_error
from slam.consistency import InnovationTest
from slam.group_recheck import group_gate, joint_costs, loop_groups
from slam.loop_recheck import _quadratic, removal_gate
from slam.optimize import optimize
from slam.pose_graph import Constraint, PoseGraph
from slam.segment_recheck import segment_recheck
from tests.test_segment_variance import _laps, _solved

KWARGS = {"init": "odometry", "gnc_start": "incremental"}


def _loop(i: int, j: int) -> Constraint:
    return Constraint(i, j, np.zeros(3), np.eye(3))


def test_groups_link_loops_near_on_both_ends_in_either_order() -> None:
    loops = [_loop(10, 50), _loop(11, 51), _loop(53, 13), _loop(20, 50), _loop(12, 90),
             _loop(16, 55)]
    # 0-1-2 chain (2 is written j-first); 3 is 10 ids off on one end; 4 on the other;
    # 5 is 3 ids from 2 on both ends: outside a window of 2, inside one of 3.
    assert loop_groups(loops, range(6), window=2) == [[0, 1, 2], [3], [4], [5]]
    assert loop_groups(loops, range(6), window=3) == [[0, 1, 2, 5], [3], [4]]
    assert loop_groups(loops, [4, 1, 0], window=2) == [[4], [1, 0]]
    assert loop_groups(loops, [], window=2) == []


def test_gate_of_a_single_loop_is_the_removal_gate() -> None:
    assert group_gate(1, 40, 3) == pytest.approx(removal_gate(40, 3))
    assert group_gate(5, 40, 3) > group_gate(5, 1, 3) > group_gate(1, 1, 3)


def test_joint_cost_of_one_loop_is_its_single_innovation() -> None:
    graph, _ = _laps(n=120, every=4)
    factors, _ = graph.factor_graph()
    values = _solved(graph)
    test = InnovationTest(factors, values, graph.keys, 3)
    unit = [graph.between_factor(lp) for lp in graph.loops]
    b, gram = test.blocks(unit)
    rho = joint_costs(test, unit, [[k] for k in range(len(unit))], removal=True)
    np.testing.assert_allclose(rho, _quadratic(b, -gram), rtol=1e-8)
    delta = joint_costs(test, unit, [[k] for k in range(len(unit))], removal=False)
    np.testing.assert_allclose(delta, _quadratic(b, gram), rtol=1e-8)


def _with_false_group(size: int = 8) -> tuple[PoseGraph, PoseGraph, int]:
    """The laps with loose stated odometry (as `tests.test_segment_variance`), and the
    same graph with `size` false loops ``210 + k -> 221 + k`` all implied by one wrong
    transform of 221 in 210's frame (30 cm, 20 cm, 0.03 rad off), so they agree with one
    another exactly; and the number of true loops."""
    clean, truth = _laps(noisy=0.1, stated=0.1, every=4)
    corrupted, _ = _laps(noisy=0.1, stated=0.1, every=4)
    wrong = se2.compose(se2.between(truth[210], truth[221]), np.array([0.3, 0.2, 0.03]))
    for k in range(size):
        m = se2.compose(se2.compose(se2.between(truth[210 + k], truth[210]), wrong),
                        se2.between(truth[221], truth[221 + k]))
        corrupted.add_loop(210 + k, 221 + k, m, clean.loops[0].information)
    return clean, corrupted, len(clean.loops)


def test_a_group_of_agreeing_false_loops_is_removed_whole() -> None:
    clean, corrupted, n_true = _with_false_group()
    # Chosen by the stated TLS cost, the admission keeps the group: it holds itself up.
    admitted = optimize(corrupted, "none", "gnc", segments=False, calibrated=False, **KWARGS)
    assert admitted.loop_weights[n_true:].all()
    values = corrupted.gtsam_values(admitted.poses)
    single = segment_recheck(corrupted, values, admitted.loop_weights, groups=False)
    assert not set(single.removed) & set(range(n_true, len(corrupted.loops)))
    check = segment_recheck(corrupted, values, admitted.loop_weights)
    assert check.groups is not None
    assert sorted(check.groups.removed) == list(range(n_true, len(corrupted.loops)))
    (test,) = check.groups.tested
    assert test.delta > test.gate
    # True loops the admission rejected for disagreeing with the group are offered back.
    assert not admitted.loop_weights[:n_true].all()
    assert set(check.groups.readmitted) == set(np.flatnonzero(admitted.loop_weights[:n_true] < 0.5))
    checked = optimize(corrupted, "none", "gnc", calibrated=False, **KWARGS)
    assert not checked.loop_weights[n_true:].any()
    assert checked.loop_weights[:n_true].all()
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(checked.poses, plain, 2) < 1e-4


def test_the_default_back_end_keeps_the_loops_of_a_noisy_stretch() -> None:
    # Odometry ten times noisier on poses 100-199: the stiff start's choice leaves that
    # stretch's true loops out, and the offer back (per-segment factors) returns them;
    # the false group stays out.
    clean, corrupted, n_true = _with_false_group()
    checked = optimize(corrupted, "none", "gnc", **KWARGS)
    assert not checked.loop_weights[n_true:].any()
    assert checked.loop_weights[:n_true].all()
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(checked.poses, plain, 2) < 1e-4


def test_groups_of_true_loops_are_kept() -> None:
    # A loop from every second pose one lap back: consecutive loops are 2 ids apart on
    # both ends, so all of them form groups.
    graph, _ = _laps(noisy=0.1, stated=0.1, every=2)
    values = _solved(graph)
    check = segment_recheck(graph, values, np.ones(len(graph.loops)))
    assert check.groups is not None and check.groups.tested
    assert check.groups.removed == []


def test_loops_a_gate_rejected_come_back_when_no_group_is_removed() -> None:
    # Loops 4 ids apart form no group; two true loops left out (as a gate far below c
    # leaves out true loops whose innovation is between the two) and a false loop 0.5 m
    # off are offered to the segment-calibrated graph: the true ones pass, the false not.
    graph, truth = _laps(every=4)
    n_true = len(graph.loops)
    graph.add_loop(30, 120, se2.compose(se2.between(truth[30], truth[120]),
                                        np.array([0.5, 0.0, 0.0])), graph.loops[0].information)
    weights = np.ones(len(graph.loops))
    weights[[5, 40, n_true]] = 0.0
    clean = PoseGraph(2, dict(graph.initial), list(graph.odometry),
                      [lp for k, lp in enumerate(graph.loops) if weights[k] > 0.5])
    values = graph.gtsam_values(optimize(clean, "none", init="odometry").poses)
    check = segment_recheck(graph, values, weights)
    assert check.removed == []
    assert check.groups is not None and check.groups.tested == []
    assert check.groups.readmitted == [5, 40]
    from slam.rechecked import _segment_rechecked

    factors, loop_index = graph.factor_graph()
    result, w, solver = _segment_rechecked(graph, factors, loop_index, values, weights, 0.99,
                                           "tls", True)
    assert solver == "tls-segments"
    np.testing.assert_array_equal(w, np.r_[np.ones(n_true), 0.0])
    without_false = PoseGraph(2, dict(graph.initial), list(graph.odometry), graph.loops[:n_true])
    plain = optimize(without_false, "none", init="odometry").poses
    assert aligned_position_error(
        {k: np.array([result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()])
         for k in graph.keys}, plain, 2) < 1e-6
