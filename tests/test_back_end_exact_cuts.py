"""The back end's shortcuts give what the long way gives, bit for bit: iSAM2's extra
iterations stopped once one relinearises nothing, the estimate's keys kept by the
smoother, the planar Gaussian factor built directly, the fast path's odometry rungs
sharing the stated graph's prior and loop factors, a loop's whitened residual in floats."""

from __future__ import annotations

import gtsam
import numpy as np

from data import se2
from slam.clean_optimum import _rung_factors
from slam.pose_graph import Constraint, PoseGraph, RobustKernel, whitened_residual
from slam.smoothers import IncrementalSmoother, _merged_keys
from slam.variance_components import with_information_scaled


def _square_run(smoother: IncrementalSmoother, laps: int = 2, side: int = 5) -> None:
    """A robot going round a square of `side` steps `laps` times with drifting
    odometry, a loop back to the first lap's pose at every pose of the later laps,
    the smoother updated after every loop (as the mapper does)."""
    rng = np.random.default_rng(3)
    step = np.array([1.0, 0.0, 0.0])
    turn = np.array([1.0, 0.0, np.pi / 2])
    info = np.diag([400.0, 400.0, 2500.0])
    truth = [np.zeros(3)]
    guess = np.zeros(3)
    smoother.add_pose(0, guess)
    n = 4 * side * laps
    for k in range(1, n + 1):
        delta = turn if k % side == 0 else step
        truth.append(se2.compose(truth[-1], delta))
        measured = delta + np.array([0.02, 0.01, 0.01]) + rng.normal(0, 0.01, 3)
        guess = se2.compose(guess, measured)
        smoother.add_pose(k, guess)
        smoother.add_odometry(k - 1, k, measured, info)
        if k > 4 * side:
            first = k - 4 * side
            smoother.add_loop(first, k, se2.between(truth[first], truth[k]), info)
            smoother.update()


class _AllIterations(IncrementalSmoother):
    """The smoother as it was: every extra iteration made, the keys read from gtsam."""

    def update(self) -> None:
        if self._new_factors.size() == 0 and self._new_values.size() == 0:
            return
        self._isam.update(self._new_factors, self._new_values)
        if self._loop_pending:
            for _ in range(self._extra_iterations):
                self._isam.update()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._loop_pending = False
        self._estimate = self._isam.calculateEstimate()

    def estimate_rows(self):
        keys = np.asarray(self._estimate.keys(), dtype=np.int64)
        return keys, gtsam.utilities.extractPose2(self._estimate)


def test_extra_iterations_stop_without_changing_the_estimate() -> None:
    fast, full = IncrementalSmoother(extra_iterations=4), _AllIterations(extra_iterations=4)
    _square_run(fast)
    _square_run(full)
    keys, poses = fast.estimate_rows()
    full_keys, full_poses = full.estimate_rows()
    np.testing.assert_array_equal(keys, np.arange(41))
    np.testing.assert_array_equal(keys, full_keys)
    assert np.array_equal(poses, full_poses)  # bit for bit
    # the loops moved the poses: the test would see a skipped iteration that mattered
    assert np.abs(poses - np.array([fast.graph.initial[k] for k in range(41)])).max() > 0.05


def test_merged_keys_appends_in_order_and_sorts_otherwise() -> None:
    none = np.zeros(0, dtype=np.int64)
    np.testing.assert_array_equal(_merged_keys(none, [0, 1, 2]), [0, 1, 2])
    np.testing.assert_array_equal(_merged_keys(np.array([0, 1]), []), [0, 1])
    np.testing.assert_array_equal(_merged_keys(np.array([0, 1]), [2, 5]), [0, 1, 2, 5])
    np.testing.assert_array_equal(_merged_keys(np.array([3, 7]), [9, 1]), [1, 3, 7, 9])
    np.testing.assert_array_equal(_merged_keys(np.array([3, 7]), [5]), [3, 5, 7])


def _factor_numbers(factor: gtsam.NonlinearFactor, values: gtsam.Values) -> tuple:
    """What a between factor contributes: its keys, whitened error and Jacobian."""
    lin = factor.linearize(values)
    a, b = lin.jacobian()
    return tuple(factor.keys()), factor.error(values), a.tobytes(), b.tobytes()


def test_planar_gaussian_factor_is_the_general_one() -> None:
    graph = PoseGraph()
    c = Constraint(0, 1, np.array([0.3, -0.2, 0.4]), np.array([[50.0, 3.0, 1.0],
                                                                 [3.0, 60.0, 2.0],
                                                                 [1.0, 2.0, 900.0]]))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose2(0.1, 0.2, 0.3))
    values.insert(1, gtsam.Pose2(0.5, -0.1, 0.6))
    general = gtsam.BetweenFactorPose2(
        0, 1, gtsam.Pose2(0.3, -0.2, 0.4), RobustKernel("none").noise(c.information))
    for kernel in (None, RobustKernel("none")):
        assert _factor_numbers(graph.between_factor(c, kernel), values) == _factor_numbers(
            general, values)
    # the poses disagree with the measurement, so the comparison is not of zeros
    assert general.error(values) > 0.1
    robust = graph.between_factor(c, RobustKernel("cauchy"))
    assert robust.error(values) < general.error(values)  # the kernel still applies


def test_rung_factors_are_the_scaled_graphs_factors() -> None:
    graph = PoseGraph()
    rng = np.random.default_rng(1)
    for k in range(6):
        graph.add_pose(k, np.array([k, 0.1 * k, 0.05 * k]))
    for k in range(5):
        graph.add_odometry(k, k + 1, np.array([1.0, 0.1, 0.05]) + rng.normal(0, 0.01, 3),
                           np.diag([100.0, 100.0, 400.0]))
    graph.add_loop(0, 5, np.array([5.0, 0.0, 0.3]), np.diag([10.0, 10.0, 40.0]))
    graph.add_loop(1, 4, np.array([3.0, 0.3, 0.1]), np.diag([20.0, 20.0, 80.0]))
    factors, loop_index = graph.factor_graph(RobustKernel("none"))
    values = graph.gtsam_values()
    for scale in (10.0, 100.0):
        rung = _rung_factors(graph, factors, loop_index, scale)
        whole = with_information_scaled(graph, scale).factor_graph(RobustKernel("none"))[0]
        assert rung.size() == whole.size() == 8
        assert rung.error(values) == whole.error(values)
        for k in range(1, whole.size()):  # the prior (0) has no between Jacobian pair
            assert _factor_numbers(rung.at(k), values) == _factor_numbers(whole.at(k), values)
        # the odometry is scaled: its error is `scale` times the stated one
        assert np.isclose(rung.at(1).error(values), scale * factors.at(1).error(values))
    # the loops are the stated graph's own factors
    assert rung.at(loop_index[0]).error(values) == factors.at(loop_index[0]).error(values)


def test_whitened_residual_of_floats_is_the_array_one() -> None:
    rng = np.random.default_rng(5)
    info = np.array([[50.0, 3.0, 1.0], [3.0, 60.0, 2.0], [1.0, 2.0, 900.0]])
    for n in range(300):
        a, b, m = rng.normal(0, 20, 3), rng.normal(0, 20, 3), rng.normal(0, 2, 3)
        if n % 3 == 0:  # headings on the wrap: -pi and pi
            a[2], b[2] = np.pi, -np.pi
        c = Constraint(0, 1, m, info)
        e = se2.between(m, se2.between(a, b))
        expected = float(np.sqrt(max(e @ info @ e, 0.0)))
        assert whitened_residual(c, {0: a, 1: b}, 2) == expected
    # by hand: the measurement is the poses' relative pose, up to 0.1 m along x
    c = Constraint(0, 1, np.array([1.0, 0.0, 0.0]), np.diag([100.0, 100.0, 100.0]))
    poses = {0: np.array([2.0, 1.0, np.pi / 2]), 1: np.array([2.0, 2.1, np.pi / 2])}
    assert np.isclose(whitened_residual(c, poses, 2), 1.0)  # 0.1 m * sqrt(100)
