"""Pose graph, robust kernels, batch/GNC/iSAM2 optimisation and the robustness benchmark."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.g2o import read_g2o, write_g2o
from evaluation.robustness import aligned_position_error, inject_false_loops, run_robustness
from slam.consistency import (
    InnovationTest,
    admission_costs,
    admit_incrementally,
    greedy_admission,
    incremental_tls,
    refine_tls,
    tls_cost,
    tls_threshold,
)
from slam.optimize import initial_guess, optimize
from slam.pose_graph import PoseGraph, RobustKernel, whitened_residual
from slam.smoothers import BatchSmoother, IncrementalSmoother
from tests.helpers import shared_file

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


def test_the_screened_admission_check_holds_where_the_exact_one_does() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    rows = {r.kernel: r for r in run_robustness(graph, [0.5], ["gnc", "gnc-screen"], seed=1)}
    assert rows["gnc-screen"].ate_vs_clean_m < 0.05
    assert rows["gnc-screen"].false_factors_obeyed == rows["gnc"].false_factors_obeyed
    assert rows["gnc-screen"].true_factors_rejected == rows["gnc"].true_factors_rejected


def test_m3500_batch_solution() -> None:
    path = shared_file("g2o/input_M3500_g2o.g2o")
    graph = PoseGraph.from_g2o(read_g2o(path))
    result = optimize(graph, "none", init="lago")
    # The known optimum of M3500 (chi2 = 2 * error) is about 137.9.
    assert result.final_error == pytest.approx(68.96, abs=0.1)


# -- time-ordered TLS admission (slam.consistency) ----------------------------------------------


def _two_poses(odo_info: float, loop_info: float, offsets: list[float]) -> PoseGraph:
    """Pose 1 one metre ahead of anchored pose 0; loops 0 -> 1 that put it `offsets` further."""
    graph = PoseGraph(dim=2)
    graph.add_pose(0, np.zeros(3))
    graph.add_pose(1, np.array([1.0, 0.0, 0.0]))
    graph.add_odometry(0, 1, np.array([1.0, 0.0, 0.0]), np.diag([odo_info] * 3))
    for dx in offsets:
        graph.add_loop(0, 1, np.array([1.0 + dx, 0.0, 0.0]), np.diag([loop_info] * 3))
    return graph


def _odometry_graph(graph: PoseGraph):
    import gtsam

    factors = gtsam.NonlinearFactorGraph()
    factors.add(graph.prior_factor(graph.keys[0]))
    for c in graph.odometry:
        factors.add(graph.between_factor(c))
    return factors


def test_innovation_cost_matches_the_hand_computed_schur_complement() -> None:
    # Along x the problem is linear: odometry (information a) and loop (information b)
    # disagree by d, so adding the loop costs 0.5 d^2 a b / (a + b) at the new optimum.
    a, b, d = 4.0, 100.0, 0.3
    graph = _two_poses(a, b, [d])
    values = graph.gtsam_values()
    test = InnovationTest(_odometry_graph(graph), values, graph.keys, 3)
    (delta,) = admission_costs(test.gains([graph.between_factor(graph.loops[0])]))
    assert delta == pytest.approx(0.5 * d**2 * a * b / (a + b), rel=1e-6)
    # ... which is what re-solving with the loop actually costs.
    solved = optimize(graph, "none")
    assert solved.final_error == pytest.approx(delta, rel=1e-6)


def test_innovation_covariance_is_the_marginal_covariance() -> None:
    import gtsam

    graph, _ = _square_graph(noise=0.02)
    # Sparse ids: the test must map them to Jacobian columns in sorted order.
    renamed = PoseGraph(dim=2)
    for k in graph.keys:
        renamed.add_pose(10 * k + 7, graph.initial[k])
    for c in graph.odometry:
        renamed.add_odometry(10 * c.i + 7, 10 * c.j + 7, c.measurement, c.information)
    factors = _odometry_graph(renamed)
    values = renamed.gtsam_values()
    test = InnovationTest(factors, values, renamed.keys, 3)
    marginals = gtsam.Marginals(factors, values)
    for n in (3, 20, len(renamed.keys) - 1):
        unit = np.zeros((test.n, 3))
        unit[3 * n : 3 * n + 3] = np.eye(3)
        block = test.covariance(unit)[3 * n : 3 * n + 3]
        expected = marginals.marginalCovariance(renamed.keys[n])
        np.testing.assert_allclose(block, expected, rtol=1e-6, atol=1e-12)


def test_greedy_admission_keeps_one_of_two_contradicting_loops() -> None:
    # Weak odometry lets either loop in alone (cost 0.045).  Once one is in, pose 1 sits
    # at 1 + b d / (a + b) with information a + b, so the other misses by
    # r = d (a + 2b) / (a + b) and would cost 0.5 r^2 (a + b) b / (a + 2b)
    # = 0.5 d^2 b (a + 2b) / (a + b) = 8.96 > c = 5.67.
    a, b, d = 1.0, 100.0, 0.3
    graph = _two_poses(a, b, [d, -d])
    test = InnovationTest(_odometry_graph(graph), graph.gtsam_values(), graph.keys, 3)
    gains = test.gains([graph.between_factor(c) for c in graph.loops])
    alone = admission_costs(gains)
    np.testing.assert_allclose(alone, 0.5 * d**2 * a * b / (a + b), rtol=1e-6)
    admitted, final = greedy_admission(gains, tls_threshold(2))
    assert len(admitted) == 1
    other = 1 - admitted[0]
    assert final[other] == pytest.approx(0.5 * d**2 * b * (a + 2 * b) / (a + b), rel=1e-6)
    assert final[other] > tls_threshold(2)


def test_tls_cost_and_refinement_on_exact_poses() -> None:
    graph, truth = _square_graph()
    bad = graph.add_loop(2, 30, np.array([0.5, 3.0, 1.0]), INFO)
    values = graph.gtsam_values(dict(enumerate(truth)))
    # Exact odometry and true loops cost nothing; the false loop costs the TLS cap c.
    assert tls_cost(graph, values) == pytest.approx(tls_threshold(2), abs=1e-9)
    _, weights = refine_tls(graph, values, np.zeros(len(graph.loops)))
    assert weights[bad] == 0 and weights.sum() == len(graph.loops) - 1


def _square_with_tail(odometry_information: float, tail: int = 20) -> tuple[PoseGraph, int]:
    """Three laps with loops, then `tail` poses with none; a false loop ties the tail's end
    to pose 5.  Measurements are good to 3 mm while odometry claims far less."""
    rng = np.random.default_rng(0)
    steps = [np.array([1.0, 0.0, 0.0])] * 3 + [np.array([1.0, 0.0, np.pi / 2])]
    truth = [np.zeros(3)]
    for _ in range(12):
        for s in steps:
            truth.append(se2.compose(truth[-1], s))
    truth += [se2.compose(truth[-1], [0.5 * (k + 1), 0.0, 0.0]) for k in range(tail)]
    info = np.diag([1.0, 1.0, 4.0]) * odometry_information
    graph = PoseGraph(dim=2)
    for k, pose in enumerate(truth):
        graph.add_pose(k, pose)
        if k:
            meas = se2.between(truth[k - 1], pose) + rng.normal(0, 0.003, 3)
            graph.add_odometry(k - 1, k, meas, info)
    for k in range(16, 49):
        noisy = se2.between(truth[k - 16], truth[k]) + rng.normal(0, 0.003, 3)
        graph.add_loop(k - 16, k, noisy, INFO)
    return graph, graph.add_loop(5, len(truth) - 1, np.array([0.3, 0.2, 0.1]), INFO)


def test_calibrated_gate_refuses_a_false_loop_on_a_loose_tail() -> None:
    graph, bad = _square_with_tail(odometry_information=4.0)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    stated = admit_incrementally(graph, values, gate="stated")
    calibrated = admit_incrementally(graph, values, gate="calibrated")
    # The stated odometry covariance lets the tail bend onto the false loop for less than
    # c; the variance factor of the data (~1e-4) says the bend is implausible.
    assert stated.weights[bad] == 1 and calibrated.weights[bad] == 0
    assert calibrated.weights[:bad].all() and stated.weights[:bad].all()
    # Judged by the stated covariances the bend *is* cheaper than the cap c: a lone false
    # loop on a loose tail is the stated TLS optimum, and incremental_tls, which keeps
    # the lower stated TLS cost, keeps it (a documented limitation).
    assert stated.tls_cost < calibrated.tls_cost
    chosen = incremental_tls(graph, values)
    assert chosen.tls_cost == pytest.approx(min(stated.tls_cost, calibrated.tls_cost), rel=1e-6)
    # With honest odometry covariances neither gate takes it.
    graph, bad = _square_with_tail(odometry_information=2.5e4)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    assert incremental_tls(graph, values).weights[bad] == 0


def test_incremental_tls_rejects_half_false_loops() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    corrupted, false = inject_false_loops(graph, 0.5, np.random.default_rng(2))
    result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
    assert sorted(result.loop_outliers) == false
    assert result.solver.startswith("tls-incremental")
    reference = optimize(graph, "none").poses
    assert aligned_position_error(result.poses, reference, 2) < 1e-3


def test_incremental_tls_needs_an_anchored_odometry_spine() -> None:
    graph, _ = _square_graph()
    graph.fixed = {5}
    with pytest.raises(UserError, match="anchored"):
        incremental_tls(graph, graph.gtsam_values())
    graph, _ = _square_graph()
    graph.odometry = [c for c in graph.odometry if c.j != 7]
    with pytest.raises(UserError, match="odometry"):
        incremental_tls(graph, graph.gtsam_values())
    with pytest.raises(UserError, match="GNC start"):
        optimize(graph, method="gnc", gnc_start="sideways")


def _loose(graph: PoseGraph, factor: float) -> PoseGraph:
    """`graph` with its odometry information multiplied by `factor`."""
    from slam.variance_components import with_information_scaled

    return with_information_scaled(graph, factor)


def test_odometry_ladder_keeps_the_plain_optimum_without_outliers() -> None:
    graph = _loose(_square_graph(noise=0.02, laps=3)[0], 0.01)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    chosen = incremental_tls(graph, values)
    assert chosen.weights.all()
    plain = optimize(graph, "none", init="odometry").poses
    from slam.pose_graph import poses_from_values

    assert aligned_position_error(poses_from_values(chosen.values, 2), plain, 2) < 1e-3


def test_odometry_ladder_is_never_worse_than_its_first_rung() -> None:
    graph = _loose(_square_graph(noise=0.02, laps=3)[0], 0.01)
    corrupted, _ = inject_false_loops(graph, 0.5, np.random.default_rng(3))
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    first = incremental_tls(corrupted, values, ladder=(1.0,))
    ladder = incremental_tls(corrupted, values)
    assert ladder.tls_cost <= first.tls_cost * (1 + 1e-9)
    assert ladder.tls_cost == pytest.approx(tls_cost(corrupted, ladder.values), rel=1e-9)
    with pytest.raises(UserError, match="ladder"):
        incremental_tls(corrupted, values, ladder=())


def test_clean_optimum_drops_given_loops_it_does_not_obey() -> None:
    from evaluation.robustness import clean_optimum

    graph, _ = _square_graph(noise=0.02)
    expected = optimize(graph, "none", init="odometry").poses
    graph.add_loop(2, 20, np.array([3.0, -2.0, 1.0]), INFO)  # a wild given loop
    reference = clean_optimum(graph)
    assert whitened_residual(graph.loops[-1], reference, 2) > 10
    assert aligned_position_error(reference, expected, 2) < 1e-6


def test_barred_loops_are_never_admitted_nor_refined_back() -> None:
    from slam.consistency import bar_search

    graph, _ = _square_graph(noise=0.02)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = admit_incrementally(graph, values, barred=[3])
    assert run.weights[3] == 0 and np.delete(run.weights, 3).all()
    _, weights = refine_tls(graph, run.values, np.ones(len(graph.loops)), barred=[3])
    assert weights[3] == 0 and np.delete(weights, 3).all()
    # On a clean graph no barred re-run lowers the TLS cost: the search returns its start.
    best = incremental_tls(graph, values, tries=0)
    assert bar_search(graph, graph, values, best).tls_cost == best.tls_cost
