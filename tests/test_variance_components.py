"""Variance-component estimation of a pose graph's odometry, against hand-solved cases."""

from __future__ import annotations

import numpy as np
import pytest

from slam.optimize import optimize
from slam.pose_graph import PoseGraph
from slam.variance_components import (
    _redundancies,
    estimate_variance_factors,
    with_information_scaled,
)


def _parallel(odometry_information: float, gap: float = 2.0) -> PoseGraph:
    """Pose 1 measured twice from the anchor 0: odometry at x = 0, a loop at x = `gap` [m].

    Odometry information ``w`` and loop information 1 on every axis: to first order the
    odometry's redundancy is ``3 / (w + 1)`` (per axis ``1 - w / (w + 1)``), the loop's
    ``3 w / (w + 1)``, together ``m - n = 9 - 6 = 3``.
    """
    graph = PoseGraph(dim=2)
    graph.add_pose(0, np.zeros(3))
    graph.add_pose(1, np.zeros(3))
    graph.add_odometry(0, 1, np.zeros(3), odometry_information * np.eye(3))
    graph.add_loop(0, 1, np.array([gap, 0.0, 0.0]), np.eye(3))
    return graph


@pytest.mark.parametrize("w", [1.0, 4.0])
def test_redundancies_match_the_hand_computed_split(w: float) -> None:
    graph = _parallel(w, gap=1e-3)  # near-linear: first order is exact to ~1e-6
    factors, _ = graph.factor_graph()
    values = graph.gtsam_values(optimize(graph, "none").poses)
    r = _redundancies(factors, values, np.array([0, 1, 2]), 3)
    assert r == pytest.approx([0.0, 3 / (w + 1), 3 * w / (w + 1)], abs=1e-5)


def test_odometry_factor_is_a_fixed_point_and_ignores_the_stated_scale() -> None:
    calibrated = []
    for stated in (1.0, 10.0, 0.1):
        graph = _parallel(stated)
        values = graph.gtsam_values(optimize(graph, "none").poses)
        f = estimate_variance_factors(graph, np.ones(1), values, iterations=400,
                                      tolerance=1e-7, min_redundancy=0.1)
        assert f.loops == 1.0
        calibrated.append(stated / f.odometry)  # information the residuals support
        # At the calibrated information the odometry's variance factor is 1.
        cal = with_information_scaled(graph, 1.0 / f.odometry)
        factors, _ = cal.factor_graph()
        solved = cal.gtsam_values(optimize(cal, "none").poses)
        r = _redundancies(factors, solved, np.array([0, 1, 2]), 3)
        assert 2.0 * factors.at(1).error(solved) / r[1] == pytest.approx(1.0, abs=5e-3)
    assert calibrated == pytest.approx([calibrated[0]] * 3, rel=1e-2)


def test_too_little_redundancy_leaves_the_factor_at_one() -> None:
    graph = _parallel(1.0)
    values = graph.gtsam_values(optimize(graph, "none").poses)
    factors = estimate_variance_factors(graph, np.zeros(1), values)  # the loop is excluded
    assert factors.odometry == 1.0


def test_scaling_touches_only_the_chosen_group() -> None:
    graph = _parallel(2.0)
    scaled = with_information_scaled(graph, 0.1)
    assert np.allclose(scaled.odometry[0].information, 0.2 * np.eye(3))
    assert np.allclose(scaled.loops[0].information, np.eye(3))
    assert np.allclose(graph.odometry[0].information, 2.0 * np.eye(3))  # the original is kept
