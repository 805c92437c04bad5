"""Pairwise consistency (PCM) of 2D loops: the cycle residual, its covariance, the clique."""

from __future__ import annotations

import gtsam
import numpy as np

from data import se2
from slam.pairwise_consistency import adjoint, consistency_matrix, logmap, loop_cycles, max_clique
from slam.pose_graph import PoseGraph

ODO_SIGMA = np.array([0.05, 0.02, 0.01])  # m, m, rad
LOOP_SIGMA = np.array([0.03, 0.03, 0.02])


def _square_walk(n: int = 12) -> np.ndarray:
    """Poses of a walk around a 4 m square, three steps per side (x, y, theta)."""
    poses, pose = [], np.zeros(3)
    for k in range(n):
        poses.append(pose.copy())
        turn = np.pi / 2 if k % 3 == 2 else 0.0
        pose = se2.compose(pose, np.array([4.0 / 3.0, 0.0, turn]))
    return np.array(poses)


def _graph(truth: np.ndarray, odometry: np.ndarray, loops: list[tuple[int, int, np.ndarray]]):
    graph = PoseGraph(dim=2)
    for k, p in enumerate(truth):
        graph.add_pose(k, p)
    graph.fixed.add(0)
    info_o = np.diag(1.0 / ODO_SIGMA**2)
    for k in range(1, len(truth)):
        graph.add_odometry(k - 1, k, odometry[k], info_o)
    for i, j, z in loops:
        graph.add_loop(i, j, z, np.diag(1.0 / LOOP_SIGMA**2))
    return graph


def test_adjoint_and_logmap_match_gtsam() -> None:
    poses = np.array([[1.0, -2.0, 0.3], [0.2, 0.5, -2.9], [3.0, 1.0, 1e-9]])
    for p, ad, log in zip(poses, adjoint(poses), logmap(poses), strict=True):
        np.testing.assert_allclose(ad, gtsam.Pose2(*p).AdjointMap(), atol=1e-12)
        np.testing.assert_allclose(log, gtsam.Pose2.Logmap(gtsam.Pose2(*p)), atol=1e-9)


def test_cycle_covariance_matches_monte_carlo() -> None:
    """Two overlapping true loops; the cycle residual's covariance over noisy odometry and
    loop measurements equals ``Q_i + Q_j - 2 O_ij`` (small noise: first order holds)."""
    truth = _square_walk()
    rng = np.random.default_rng(3)
    pairs = [(1, 9), (4, 11)]  # overlapping intervals (4, 9]
    exact = [se2.between(truth[i], truth[j]) for i, j in pairs]
    residuals = []
    for _ in range(3000):
        odo = np.zeros((len(truth), 3))
        for k in range(1, len(truth)):
            odo[k] = se2.compose(se2.between(truth[k - 1], truth[k]),
                                 rng.normal(0.0, ODO_SIGMA))
        loops = [(i, j, se2.compose(z, rng.normal(0.0, LOOP_SIGMA)))
                 for (i, j), z in zip(pairs, exact, strict=True)]
        cycles = loop_cycles(_graph(truth, odo, loops))
        g = se2.compose(cycles.g[0], se2.inverse(cycles.g[1]))
        residuals.append(logmap(g)[0])
    residuals = np.array(residuals)
    noiseless = loop_cycles(_graph(truth, np.vstack([np.zeros(3)] + [
        se2.between(truth[k - 1], truth[k]) for k in range(1, len(truth))]),
        [(i, j, z) for (i, j), z in zip(pairs, exact, strict=True)]))
    lo, hi = 4, 9
    predicted = noiseless.q[0] + noiseless.q[1] - 2 * (noiseless.s[hi] - noiseless.s[lo])
    empirical = np.cov(residuals.T)
    np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=0.12)
    # The Mahalanobis distances of true pairs are chi-square with 3 dof: mean 3.
    d2 = np.einsum("na,ab,nb->n", residuals, np.linalg.inv(predicted), residuals)
    assert abs(d2.mean() - 3.0) < 0.2


def test_consistency_separates_a_false_loop_and_the_clique_drops_it() -> None:
    truth = _square_walk()
    odo = np.vstack([np.zeros(3)] + [se2.between(truth[k - 1], truth[k])
                                     for k in range(1, len(truth))])
    true = [(0, 9, se2.between(truth[0], truth[9])), (1, 10, se2.between(truth[1], truth[10])),
            (2, 11, se2.between(truth[2], truth[11]))]
    false = [(3, 11, np.array([0.5, 0.0, 0.0]))]  # 4 m off
    adj = consistency_matrix(_graph(truth, odo, true + false))
    assert adj[:3, :3].all()
    assert not adj[3, :3].any()
    np.testing.assert_array_equal(max_clique(adj), [0, 1, 2])


def test_max_clique_on_a_hand_graph() -> None:
    # A 4-clique {1, 2, 4, 5}, a triangle {0, 1, 3}, and vertex 6 joined to 0 only.
    edges = [(1, 2), (1, 4), (1, 5), (2, 4), (2, 5), (4, 5), (0, 1), (0, 3), (1, 3), (0, 6)]
    adj = np.eye(7, dtype=bool)
    for i, j in edges:
        adj[i, j] = adj[j, i] = True
    np.testing.assert_array_equal(max_clique(adj), [1, 2, 4, 5])
    assert len(max_clique(np.zeros((0, 0), dtype=bool))) == 0
