"""`slam.innovation.removal_costs`: the linearised leave-one-out cost of a factor."""

from __future__ import annotations

import numpy as np

from slam.innovation import InnovationTest, removal_costs
from slam.pose_graph import PoseGraph, RobustKernel


def test_on_a_linear_problem_it_is_the_drop_of_the_minimum() -> None:
    rng = np.random.default_rng(3)
    d, n = 3, 6
    a = rng.normal(size=(15, n))  # the other factors: 15 whitened rows
    y = rng.normal(size=15)
    b_rows = rng.normal(size=(d, n))  # factor q: d whitened rows
    z = rng.normal(size=d)
    full_a, full_y = np.vstack([a, b_rows]), np.concatenate([y, z])
    x = np.linalg.lstsq(full_a, full_y, rcond=None)[0]
    x_without = np.linalg.lstsq(a, y, rcond=None)[0]
    drop = 0.5 * np.sum((full_a @ x - full_y) ** 2) - 0.5 * np.sum((a @ x_without - y) ** 2)
    h_inv = np.linalg.inv(full_a.T @ full_a)
    gram = b_rows @ h_inv @ b_rows.T
    rho = removal_costs((b_rows @ x - z)[None], gram[None])
    np.testing.assert_allclose(rho, [drop], rtol=1e-10)


def test_a_factor_that_alone_fixes_its_variables_costs_inf() -> None:
    # one variable, one row: M = B H^-1 B^T = 1 and I - M is singular
    rho = removal_costs(np.array([[0.5]]), np.array([[[1.0]]]))
    assert np.isinf(rho[0])


def test_from_the_innovation_test_it_matches_the_re_solve_on_a_near_linear_graph() -> None:
    """A 2D square of odometry with two loops that disagree with it by 0.1-0.3 m and
    0.05-0.1 rad (near linear): each
    loop's linearised leave-one-out cost from `InnovationTest.blocks` at the joint optimum
    matches the drop of the re-solved minimum to a few percent."""
    graph = PoseGraph(dim=2)
    path = [(0.0, 0.0, 0.0), (1.0, 0.0, np.pi / 2), (1.0, 1.0, np.pi), (0.0, 1.0, -np.pi / 2)]
    for k, p in enumerate(path):
        graph.add_pose(k, np.array(p))
    graph.fixed.add(0)
    info = np.diag([100.0, 100.0, 400.0])
    for k in range(1, 4):
        graph.add_odometry(k - 1, k, np.array([1.0, 0.0, np.pi / 2]), info)
    graph.add_loop(3, 0, np.array([1.2, 0.1, np.pi / 2 + 0.05]), info)
    graph.add_loop(0, 2, np.array([1.0, 1.3, np.pi - 0.1]), info)
    factors, loop_index = graph.factor_graph(RobustKernel("none"))
    import gtsam

    values = graph.gtsam_values(graph.initial)
    optimum = gtsam.LevenbergMarquardtOptimizer(factors, values).optimize()
    test = InnovationTest(factors, optimum, graph.keys, 3)
    b, gram = test.blocks([factors.at(k) for k in loop_index])
    rho = removal_costs(b, gram)
    for n, k in enumerate(loop_index):
        without = gtsam.NonlinearFactorGraph()
        for j in range(factors.size()):
            if j != k:
                without.add(factors.at(j))
        alone = gtsam.LevenbergMarquardtOptimizer(without, optimum).optimize()
        drop = factors.error(optimum) - without.error(alone)
        assert drop > 0.1  # not a trivial case
        np.testing.assert_allclose(rho[n], drop, rtol=0.05)
