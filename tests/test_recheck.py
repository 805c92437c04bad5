"""The re-check of loop decisions under calibrated odometry, against hand-solved cases."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from evaluation.robustness import aligned_position_error
from slam.consistency import InnovationTest, tls_threshold
from slam.optimize import optimize
from slam.recheck import (
    Calibrated,
    calibrated_choice,
    greedy_removal,
    odometry_variance_step,
    recheck_loops,
    removal_costs,
    removal_gate,
)
from slam.variance_components import with_information_scaled
from tests.test_backend import _odometry_graph, _square_graph, _two_poses


def _gains_at_optimum(graph):
    """Gains of every loop of `graph`, linearised at its least-squares optimum (loops in)."""
    import gtsam

    factors = _odometry_graph(graph)
    for c in graph.loops:
        factors.add(graph.between_factor(c))
    values = graph.gtsam_values(optimize(graph, "none").poses)
    test = InnovationTest(factors, values, graph.keys, 3)
    return test.gains([graph.between_factor(c) for c in graph.loops]), factors, values, gtsam


def test_removal_cost_is_what_removing_the_loop_saves() -> None:
    # Along x the problem is linear: odometry (information a) and a loop (b) disagree by d;
    # with the loop in, the cost is 0.5 d^2 a b / (a + b), all of which removing it saves.
    a, b, d = 4.0, 100.0, 0.3
    graph = _two_poses(a, b, [d])
    gains, factors, values, _ = _gains_at_optimum(graph)
    (rho,) = removal_costs(gains)
    assert rho == pytest.approx(0.5 * d**2 * a * b / (a + b), rel=1e-6)
    assert rho == pytest.approx(factors.error(values), rel=1e-6)


def test_greedy_removal_takes_the_false_loop_and_clears_the_others() -> None:
    # Two loops at offset 0 and one at D.  Leaving out the D loop saves
    # 0.5 D^2 b (a + 2b) / (a + 3b) = 8.35; leaving out a 0 loop saves
    # 0.5 x'^2 b (a + 2b) / (a + 3b) with x' = b D / (a + 2b): 2.07.  Once the D loop is
    # gone the others sit exactly on the odometry's pose: nothing left to save.
    a, b, big = 1.0, 100.0, 0.5
    graph = _two_poses(a, b, [0.0, 0.0, big])
    gains, *_ = _gains_at_optimum(graph)
    rho = removal_costs(gains)
    x = b * big / (a + 2 * b)
    np.testing.assert_allclose(
        rho, [0.5 * x**2 * b * (a + 2 * b) / (a + 3 * b)] * 2
        + [0.5 * big**2 * b * (a + 2 * b) / (a + 3 * b)], rtol=1e-6)
    removed, after = greedy_removal(gains, removal_gate(3, 3))
    assert removed == [2]
    np.testing.assert_allclose(after[:2], 0.0, atol=1e-9)


def test_removal_gate_is_the_tls_threshold_for_one_loop_and_grows_with_more() -> None:
    assert removal_gate(1, 3) == pytest.approx(tls_threshold(2))
    gates = [removal_gate(n, 3) for n in (1, 10, 100, 1000)]
    assert gates == sorted(gates)
    # Sidak: 1 - 0.99 ** (1 / 10) = 1.005e-3 upper tail of chi2(3) is 16.2 (tables).
    assert 2 * removal_gate(10, 3) == pytest.approx(16.2, abs=0.1)


@pytest.mark.parametrize("w", [1.0, 4.0])
def test_odometry_variance_step_matches_the_hand_computed_case(w: float) -> None:
    # Odometry (information w) and one loop (information 1) disagree by `gap` along x:
    # pose 1 sits at gap / (w + 1), the odometry's error is 0.5 w (gap / (w + 1))^2 and its
    # redundancy 3 / (w + 1), so the step is w gap^2 / (3 (w + 1)).
    gap = 1e-3
    graph = _two_poses(w, 1.0, [gap])
    gains, factors, values, _ = _gains_at_optimum(graph)
    odometry_error = factors.at(1).error(values)
    step = odometry_variance_step(odometry_error, 3 * factors.size(), 6,
                                  np.trace(gains.M, axis1=1, axis2=2), 3)
    assert step == pytest.approx(w * gap**2 / (3 * (w + 1)), rel=1e-4)


def test_upper_bound_of_the_variance_factor_matches_the_chi_square_table() -> None:
    # An estimate 0.5 from 10 redundant rows: the true factor is below
    # 0.5 * 10 / chi2_10^-1(0.01) = 5 / 2.558 (tables) with 99 % confidence.
    cal = Calibrated(0.5, None, None, None, np.zeros(0, np.int64), None, 10.0, 0.5)
    assert cal.upper_bound(0.99) == pytest.approx(5.0 / 2.558, rel=1e-3)
    # Less redundancy, a looser bound for the same estimate; none without redundancy.
    assert Calibrated(0.5, None, None, None, np.zeros(0, np.int64), None, 3.0,
                      0.5).upper_bound(0.99) > cal.upper_bound(0.99)
    assert Calibrated(1.0, None, None, None, np.zeros(0, np.int64), None).upper_bound() == np.inf


def _loose_square_with_false_loop():
    """The noisy square with its odometry stated 100 times too loose, and one false loop
    from pose 10 to pose 22 that this loose odometry can absorb."""
    graph, truth = _square_graph(noise=0.02, laps=3)
    loose = with_information_scaled(graph, 0.01)
    clean = with_information_scaled(graph, 0.01)
    wrong = se2.compose(se2.between(truth[10], truth[22]), np.array([0.6, 0.4, 0.1]))
    loose.add_loop(10, 22, wrong, loose.loops[0].information)
    return clean, loose


def test_recheck_keeps_every_loop_of_a_clean_graph() -> None:
    clean, _ = _loose_square_with_false_loop()
    solution = optimize(clean, "none", "gnc", init="odometry", gnc_start="incremental",
                        calibrated=False)
    weights, factor = recheck_loops(clean, clean.gtsam_values(solution.poses),
                                    solution.loop_weights)
    assert weights.all()
    assert factor < 0.1  # the residuals show odometry far better than stated


def test_recheck_removes_a_false_loop_the_loose_odometry_absorbs() -> None:
    clean, loose = _loose_square_with_false_loop()
    stated = optimize(loose, "none", "gnc", init="odometry", gnc_start="incremental",
                      calibrated=False, segments=False)
    assert stated.loop_weights[-1] == 1.0  # the stated model admits it
    rechecked = optimize(loose, "none", "gnc", init="odometry", gnc_start="incremental",
                         calibrated=False, recheck=True, segments=False)
    assert rechecked.loop_weights[-1] == 0.0
    assert rechecked.loop_weights[:-1].all()
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(rechecked.poses, plain, 2) < 1e-6


def test_calibrated_choice_prefers_the_candidate_without_the_absorbed_false_loop() -> None:
    from slam.consistency import refine_tls, tls_cost

    _, loose = _loose_square_with_false_loop()
    start = loose.gtsam_values(optimize(loose, "none", init="odometry").poses)
    candidates = []
    for w in (np.ones(len(loose.loops)), np.r_[np.ones(len(loose.loops) - 1), 0.0]):
        values, weights = refine_tls(loose, start, w, barred=[] if w[-1] else [len(w) - 1])
        candidates.append((values, weights, tls_cost(loose, values)))
    assert candidates[0][1][-1] == 1.0 and candidates[1][1][-1] == 0.0
    assert candidates[0][2] < candidates[1][2]  # the stated objective prefers the false loop
    factor: list[float] = []
    assert calibrated_choice(loose, candidates, factor=factor) == 1
    assert factor[0] < 0.1
    # The same loops twice: nothing to choose.
    assert calibrated_choice(loose, [candidates[1], candidates[1]]) == 0


def test_blocks_are_the_gains_without_their_rows() -> None:
    graph, _ = _square_graph(noise=0.02, laps=2)
    factors = _odometry_graph(graph)
    values = graph.gtsam_values(optimize(graph, "none").poses)
    test = InnovationTest(factors, values, graph.keys, 3)
    loops = [graph.between_factor(c) for c in graph.loops]
    b, gram = test.blocks(loops)
    gains = test.gains(loops)
    np.testing.assert_allclose(b, gains.b, rtol=1e-12)
    np.testing.assert_allclose(gram, gains.M, rtol=1e-10, atol=1e-14)


def test_the_calibrated_choice_alone_rejects_the_absorbed_false_loop() -> None:
    clean, loose = _loose_square_with_false_loop()
    chosen = optimize(loose, "none", "gnc", init="odometry", gnc_start="incremental",
                      segments=False)
    assert chosen.loop_weights[-1] == 0.0
    assert chosen.loop_weights[:-1].all()
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(chosen.poses, plain, 2) < 1e-6


def test_polish_solves_a_graph_of_tiny_errors_as_far_as_any_other() -> None:
    # Every information matrix scaled by 1e-8 leaves the optimum where it was, but its
    # errors far below gtsam's default absolute stopping decrease: the polish has only the
    # relative criterion, so it still ends at the optimum from a poor start.
    from slam.consistency import polish
    from slam.optimize import initial_guess
    from slam.pose_graph import RobustKernel, poses_from_values
    from tests.test_segment_variance import _laps

    graph, _ = _laps()
    tiny = with_information_scaled(graph, 1e-8, 1e-8)
    rng = np.random.default_rng(1)
    start = {k: v + rng.normal(0, [0.5, 0.5, 0.2])
             for k, v in initial_guess(tiny, "odometry").items()}
    polished = polish(tiny.factor_graph(RobustKernel("none")), np.ones(len(tiny.loops)),
                      tiny.gtsam_values(start))
    plain = optimize(graph, "none", init="odometry").poses
    assert aligned_position_error(poses_from_values(polished, 2), plain, 2) < 3e-8


def test_calibrated_choice_starts_stiff_when_the_bent_candidate_is_a_fixed_point(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from slam import recheck
    from slam.consistency import refine_tls, tls_cost

    # Six false loops across the loosely stated square that agree on one wrong place
    # (pose b moved by T): the odometry absorbs them, and at the variance factor their
    # bending shows, rejecting them costs more than keeping them (a fixed point).
    graph, truth = _square_graph(noise=0.02, laps=2)
    loose = with_information_scaled(graph, 0.01)
    n = len(loose.loops)
    wrong = np.array([1.0, 0.5, 0.2])
    for q in range(6):
        a, b = 1 + q, 9 + q
        loose.add_loop(a, b, se2.between(truth[a], se2.compose(wrong, truth[b])),
                       loose.loops[0].information)
    start = loose.gtsam_values(optimize(loose, "none", init="odometry").poses)
    candidates = []
    for w in (np.ones(len(loose.loops)), np.r_[np.ones(n), np.zeros(6)]):
        values, weights = refine_tls(loose, start, w, barred=[] if w[-1] else list(
            range(n, n + 6)))
        candidates.append((values, weights, tls_cost(loose, values)))
    assert candidates[0][1].all() and not candidates[1][1][n:].any()
    assert candidates[0][2] < candidates[1][2]
    assert calibrated_choice(loose, candidates) == 1
    # From the stated winner (no confidence bound to start from) the bent one stays.
    monkeypatch.setattr(recheck.Calibrated, "upper_bound", lambda self, p=0.99: np.inf)
    assert calibrated_choice(loose, candidates) == 0
