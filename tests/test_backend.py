"""Pose graph, robust kernels, batch/GNC/iSAM2 optimisation and the robustness benchmark."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.g2o import read_g2o, write_g2o
from evaluation.robustness import aligned_position_error, inject_false_loops, run_robustness
from slam.optimize import BatchSmoother, IncrementalSmoother, initial_guess, optimize
from slam.pose_graph import PoseGraph, RobustKernel, whitened_residual
from tests.conftest import shared_file

INFO = np.diag([100.0, 100.0, 400.0])


def _square_graph(noise: float = 0.0, seed: int = 0, laps: int = 2) -> tuple[PoseGraph, np.ndarray]:
    """A robot driving `laps` laps of a 4 m square (1 m steps), loops at every revisit."""
    rng = np.random.default_rng(seed)
    steps = [np.array([1.0, 0.0, 0.0])] * 3 + [np.array([1.0, 0.0, np.pi / 2])]
    truth = [np.zeros(3)]
    for _ in range(4 * laps):
        for s in steps:
            truth.append(se2.compose(truth[-1], s))
    truth = np.array(truth)
    graph = PoseGraph(dim=2)
    odo = [np.zeros(3)]
    for k in range(len(truth)):
        if k:
            meas = se2.between(truth[k - 1], truth[k]) + rng.normal(0, noise, 3) * [1, 1, 0.2]
            odo.append(se2.compose(odo[-1], meas))
            graph.add_odometry(k - 1, k, meas, INFO)
        graph.add_pose(k, odo[-1])
    for k in range(16, len(truth)):
        graph.add_loop(k - 16, k, se2.between(truth[k - 16], truth[k]), INFO)
    return graph, truth


def test_kernel_names_and_default_scales() -> None:
    assert RobustKernel("huber").effective_scale == 1.345
    assert RobustKernel("dcs", 2.0).effective_scale == 2.0
    with pytest.raises(UserError, match="unknown kernel"):
        RobustKernel("tukey-ish")


def test_batch_optimisation_recovers_the_square() -> None:
    graph, truth = _square_graph(noise=0.02)
    before = aligned_position_error(graph.initial, dict(enumerate(truth)), 2)
    result = optimize(graph, "none")
    after = aligned_position_error(result.poses, dict(enumerate(truth)), 2)
    assert after < 0.5 * before
    assert result.final_error < result.initial_error
    assert result.loop_outliers == []


def test_odometry_initialisation_composes_the_chain() -> None:
    graph, _ = _square_graph(noise=0.02)
    shifted = {k: v + 1.0 for k, v in graph.initial.items()}
    graph.initial = shifted
    guess = initial_guess(graph, "odometry")
    # The anchor keeps its value; every other pose follows from the odometry measurements.
    np.testing.assert_allclose(guess[0], shifted[0])
    c = graph.odometry[4]
    np.testing.assert_allclose(guess[c.j], se2.compose(guess[c.i], c.measurement), atol=1e-12)


def test_gnc_rejects_a_false_loop_and_reports_it() -> None:
    graph, truth = _square_graph(noise=0.01)
    bad = graph.add_loop(3, 20, np.array([0.5, 3.0, 1.0]), INFO)
    result = optimize(graph, method="gnc", init="odometry")
    assert bad in result.loop_outliers
    assert len(result.loop_outliers) == 1
    assert result.loop_weights is not None and result.loop_weights[bad] < 0.5
    assert aligned_position_error(result.poses, dict(enumerate(truth)), 2) < 0.1
    plain = optimize(graph, "none", init="odometry")
    assert aligned_position_error(plain.poses, dict(enumerate(truth)), 2) > 0.1


def test_incremental_and_batch_agree() -> None:
    graph, _ = _square_graph(noise=0.02)
    isam = IncrementalSmoother(kernel="none")
    batch = BatchSmoother(kernel="none")
    loops_by_j = {c.j: c for c in graph.loops}
    for smoother in (isam, batch):
        for k in graph.keys:
            smoother.add_pose(k, graph.initial[k])
            if k:
                c = graph.odometry[k - 1]
                smoother.add_odometry(c.i, c.j, c.measurement, c.information)
            if k in loops_by_j:
                c = loops_by_j[k]
                smoother.add_loop(c.i, c.j, c.measurement, c.information)
            if k % 8 == 0 or k == graph.keys[-1]:
                smoother.update()
    a, b = isam.estimate(), batch.estimate()
    assert sorted(a) == sorted(b) == graph.keys
    for k in graph.keys:
        np.testing.assert_allclose(a[k], b[k], atol=1e-4)
    np.testing.assert_allclose(
        isam.marginal_covariance(graph.keys[-1]), batch.marginal_covariance(graph.keys[-1]),
        rtol=1e-2, atol=2e-5,  # iSAM2 linearises lazily (threshold 0.01), batch at the optimum
    )


def test_whitened_residual_is_zero_for_a_consistent_edge() -> None:
    graph, truth = _square_graph()
    poses = dict(enumerate(truth))
    assert all(whitened_residual(c, poses, 2) < 1e-9 for c in graph.loops)


def test_g2o_round_trip_through_the_optimiser(tmp_path) -> None:
    graph, _ = _square_graph(noise=0.02)
    result = optimize(graph, "cauchy")
    path = tmp_path / "opt.g2o"
    write_g2o(path, graph.to_g2o(result.poses))
    back = PoseGraph.from_g2o(read_g2o(path))
    assert len(back.odometry) == len(graph.odometry) and len(back.loops) == len(graph.loops)
    for k in graph.keys:
        np.testing.assert_allclose(back.initial[k], result.poses[k], atol=1e-12)
    again = optimize(back, "cauchy")
    assert again.final_error <= result.final_error + 1e-6


def test_false_loop_injection_ratio_and_plausibility() -> None:
    graph, _ = _square_graph()
    corrupted, false = inject_false_loops(graph, 0.5, np.random.default_rng(0))
    assert len(false) == len(graph.loops)
    assert len(corrupted.loops) == 2 * len(graph.loops)
    true_meas = {tuple(c.measurement) for c in graph.loops}
    for f in false:
        c = corrupted.loops[f]
        assert tuple(c.measurement) in true_meas and abs(c.i - c.j) > 10


def test_robustness_with_no_outliers_equals_plain_optimisation() -> None:
    graph, _ = _square_graph(noise=0.02)
    (row,) = run_robustness(graph, [0.0], ["none"])
    assert row.false_loops == 0 and row.false_factors_obeyed == 0
    assert row.ate_vs_clean_m < 1e-6


def test_gnc_survives_half_false_loops_on_a_small_graph() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    rows = {r.kernel: r for r in run_robustness(graph, [0.5], ["none", "gnc"], seed=1)}
    assert rows["gnc"].ate_vs_clean_m < 0.05
    assert rows["gnc"].false_factors_obeyed <= 1
    assert rows["none"].ate_vs_clean_m > rows["gnc"].ate_vs_clean_m


def test_m3500_batch_solution() -> None:
    path = shared_file("g2o/input_M3500_g2o.g2o")
    graph = PoseGraph.from_g2o(read_g2o(path))
    result = optimize(graph, "none", init="lago")
    # The known optimum of M3500 (chi2 = 2 * error) is about 137.9.
    assert result.final_error == pytest.approx(68.96, abs=0.1)
