"""The final pass's fast path: the plain least-squares optimum when it is the TLS decision."""

from __future__ import annotations

import numpy as np

from data import se2
from evaluation.robustness import aligned_position_error
from slam.consistency import incremental_tls, tls_threshold
from slam.optimize import initial_guess, optimize
from slam.pose_graph import poses_from_values
from slam.variance_components import with_information_scaled
from tests.test_backend import INFO, _square_graph


def test_a_clean_graph_returns_the_plain_optimum() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    result = optimize(graph, "none", "gnc", init="odometry", gnc_start="incremental")
    assert result.solver == "least-squares-clean"
    assert result.loop_outliers == [] and result.loop_weights.all()
    plain = optimize(graph, "none", init="odometry").poses
    assert aligned_position_error(result.poses, plain, 2) < 1e-6
    # The whole admission arrives at the same solution.
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    admitted = incremental_tls(graph, values)
    assert admitted.weights.all()
    assert aligned_position_error(poses_from_values(admitted.values, 2), result.poses, 2) < 1e-6


def test_a_false_loop_takes_the_whole_admission() -> None:
    graph, truth = _square_graph(noise=0.01)
    bad = graph.add_loop(3, 20, np.array([0.5, 3.0, 1.0]), INFO)
    result = optimize(graph, "none", "gnc", init="odometry", gnc_start="incremental")
    assert result.solver.startswith("tls-incremental")
    assert result.loop_outliers == [bad]
    assert aligned_position_error(result.poses, dict(enumerate(truth)), 2) < 0.1


def test_a_false_loop_the_least_squares_map_absorbs_takes_the_whole_admission() -> None:
    # Odometry stated 100 times too loose: the plain optimum bends onto a false loop so
    # that every loop passes its chi-square test there; the segment re-check does not.
    graph, truth = _square_graph(noise=0.02, laps=3)
    loose = with_information_scaled(graph, 0.01)
    wrong = se2.compose(se2.between(truth[10], truth[22]), np.array([0.6, 0.4, 0.1]))
    bad = loose.add_loop(10, 22, wrong, loose.loops[0].information)
    plain = optimize(loose, "none", init="odometry")
    values = loose.gtsam_values(plain.poses)
    c = tls_threshold(2)
    factors, loop_index = loose.factor_graph()
    assert max(factors.at(k).error(values) for k in loop_index) <= c
    result = optimize(loose, "none", "gnc", init="odometry", gnc_start="incremental")
    assert not result.solver.startswith("least-squares")
    assert result.loop_outliers == [bad]


def test_false_loops_absorbed_by_loose_odometry_are_seen_on_the_stiff_rungs() -> None:
    # MITb with its odometry information x0.01 and half its loops false (random): the
    # stated graph's least-squares map bends onto every one of them at an error below c.
    from data.g2o import read_g2o
    from evaluation.robustness import inject_false_loops
    from slam.clean_optimum import _clean_optimum
    from slam.pose_graph import PoseGraph
    from tests.helpers import shared_file

    graph = PoseGraph.from_g2o(read_g2o(shared_file("g2o/input_MITb_g2o.g2o")))
    loose = with_information_scaled(graph, 0.01)
    corrupted, _false = inject_false_loops(loose, 0.5, np.random.default_rng(0))
    factors, loop_index = corrupted.factor_graph()
    start = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    assert _clean_optimum(corrupted, factors, loop_index, start, 0.99, 100, True,
                          (1.0,)) is not None
    assert _clean_optimum(corrupted, factors, loop_index, start, 0.99, 100, True) is None
