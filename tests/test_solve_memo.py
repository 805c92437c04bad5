"""`slam.least_squares.StickySolver`'s memo of solutions (`SolveMemo`) and its dogleg by
Cholesky with the stiff factors' poses eliminated first."""

from __future__ import annotations

import gtsam
import numpy as np

from slam.least_squares import (
    StickySolver,
    dogleg_qr,
    dogleg_stiff_first,
    same_factors,
    stiff_keys,
)


def _chain(second: float) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Three poses: a prior on 0, odometry 0->1 (1 m ahead) and 1->2 (`second` m ahead,
    turning 0.3 rad), a loop 0->2; the start is the odometry perturbed."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), noise))
    graph.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(1.0, 0.0, 0.0), noise))
    graph.add(gtsam.BetweenFactorPose2(1, 2, gtsam.Pose2(second, 0.0, 0.3), noise))
    graph.add(gtsam.BetweenFactorPose2(0, 2, gtsam.Pose2(1.0 + second, 0.1, 0.3), noise))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose2(0.05, -0.02, 0.01))
    values.insert(1, gtsam.Pose2(0.9, 0.1, 0.05))
    values.insert(2, gtsam.Pose2(1.8, 0.3, 0.2))
    return graph, values


def test_a_repeated_solve_returns_the_same_solution_as_a_copy() -> None:
    graph, values = _chain(1.0)
    solver = StickySolver()
    first = solver(graph, values)
    again = solver(gtsam.NonlinearFactorGraph(graph), gtsam.Values(values))
    assert (solver.memo.hits, solver.memo.misses) == (1, 1)
    assert again.equals(first, 0.0)
    fresh = StickySolver(memo=0)(graph, values)
    assert fresh.equals(first, 0.0)  # what the solve itself gives, bit for bit
    again.update(2, gtsam.Pose2(5.0, 5.0, 1.0))  # the caller's copy, not the memo's
    assert solver(graph, values).equals(first, 0.0)


def test_another_graph_or_start_is_solved_again() -> None:
    graph, values = _chain(1.0)
    other, _ = _chain(1.0 + 1e-12)  # same size, same keys, one measurement apart
    assert not same_factors(graph, other)
    solver = StickySolver()
    solver(graph, values)
    solver(other, values)
    moved = gtsam.Values(values)
    moved.update(1, gtsam.Pose2(0.9, 0.1, 0.05 + 1e-15))
    solver(graph, moved)
    assert (solver.memo.hits, solver.memo.misses) == (0, 3)


def test_the_path_is_part_of_the_key_and_old_entries_go() -> None:
    graph, values = _chain(1.0)
    solver = StickySolver(memo=1)
    solver(graph, values)
    solver.dogleg = True  # a solver that has gone to dogleg solves the same graph again
    solver(graph, values)
    assert solver.memo.hits == 0 and len(solver.memo._store) == 1
    solver.dogleg = False  # the LM entry was dropped: one entry kept
    solver(graph, values)
    assert solver.memo.hits == 0


def _stiff_chain() -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Four poses; odometry 1->2 turns in place with a translation information of
    eigenvalues 1e12 and 10 (condition 1e11), the others isotropic; a loop 0->3."""
    soft = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s], [s, c]])
    info = np.zeros((3, 3))
    info[:2, :2] = rot @ np.diag([1e12, 10.0]) @ rot.T
    info[2, 2] = 400.0
    stiff = gtsam.noiseModel.Gaussian.Information(info)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), soft))
    graph.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(1.0, 0.0, 0.0), soft))
    graph.add(gtsam.BetweenFactorPose2(1, 2, gtsam.Pose2(0.0, 0.0, 1.0), stiff))
    graph.add(gtsam.BetweenFactorPose2(2, 3, gtsam.Pose2(1.0, 0.0, 0.0), soft))
    graph.add(gtsam.BetweenFactorPose2(0, 3, gtsam.Pose2(1.5, 0.8, 1.0), soft))
    values = gtsam.Values()
    for k, pose in enumerate([(0, 0, 0), (1.1, 0.1, 0.05), (1.0, -0.1, 0.9), (1.6, 0.9, 1.1)]):
        values.insert(k, gtsam.Pose2(*pose))
    return graph, values


def test_stiff_factors_found_and_solved_by_cholesky_as_by_qr() -> None:
    graph, values = _stiff_chain()
    assert stiff_keys(graph) == [1, 2]  # condition 1e11 > 1/sqrt(eps); the others 4 or 1
    qr = dogleg_qr(graph, values, 100).optimize()
    chol = dogleg_stiff_first(graph, values, 100, [1, 2])
    assert abs(graph.error(chol) - graph.error(qr)) <= 1e-9 * graph.error(qr)
    for k in range(4):
        assert np.allclose(chol.atPose2(k).translation(), qr.atPose2(k).translation(),
                           atol=1e-6)
    solver = StickySolver(stiff_cholesky=True)
    solver.dogleg = True
    assert solver(graph, values).equals(chol, 0.0)
