"""The re-check of loop decisions under calibrated odometry, against hand-solved cases."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from evaluation.robustness import aligned_position_error
from slam.calibrated_choice import Calibrated, calibrated_choice, odometry_variance_step
from slam.consistency import InnovationTest, tls_threshold
from slam.loop_recheck import greedy_removal, recheck_loops, removal_costs, removal_gate
from slam.optimize import optimize
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


def loose_square_candidates():
    """The loose square (`_loose_square_with_false_loop`), its odometry solution, and its
    candidates with and without its absorbed false loop: ``(values, weights, tls cost)``."""
    from slam.consistency import refine_tls, tls_cost

    _, loose = _loose_square_with_false_loop()
    start = loose.gtsam_values(optimize(loose, "none", init="odometry").poses)
    candidates = []
    for w in (np.ones(len(loose.loops)), np.r_[np.ones(len(loose.loops) - 1), 0.0]):
        values, weights = refine_tls(loose, start, w, barred=[] if w[-1] else [len(w) - 1])
        candidates.append((values, weights, tls_cost(loose, values)))
    return loose, start, candidates


def test_calibrated_choice_prefers_the_candidate_without_the_absorbed_false_loop() -> None:
    loose, _, candidates = loose_square_candidates()
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
    from slam import calibrated_choice as choice_module
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
    monkeypatch.setattr(choice_module.Calibrated, "upper_bound", lambda self, p=0.99: np.inf)
    assert calibrated_choice(loose, candidates) == 0


def test_mixed_factors_take_the_own_factor_where_its_loops_give_redundancy() -> None:
    from slam.offer_back import mixed_factors
    from slam.segment_variance import SegmentFactors

    segment = np.array([0, 0, 1, 2])
    own = SegmentFactors(np.array([0.01, 0.02, 0.03]), np.array([0.01, np.inf, 0.03]),
                         np.array([10.0, 0.0, 3.0]), 0.02, segment)
    other = SegmentFactors(np.array([0.5, 0.6, 0.7]), np.array([0.5, 0.6, 0.7]),
                           np.array([20.0, 30.0, 40.0]), 0.6, segment)
    mixed = mixed_factors(own, other, min_redundancy=3.0)
    np.testing.assert_array_equal(mixed.factors, [0.01, 0.6, 0.03])
    np.testing.assert_array_equal(mixed.redundancy, [10.0, 30.0, 3.0])
    np.testing.assert_array_equal(mixed.per_odometry(), [0.01, 0.01, 0.6, 0.03])


def _offer_back_case():
    """The laps with odometry noise 0.1 m on poses 100-199 and 0.003 m elsewhere, all
    stated as 0.1 m, a loop every fourth pose, and a false loop 210 -> 221 (5.25 cm,
    3.5 cm, 0.007 rad off); A keeps every loop, B none whose later pose is in 100-215
    and not the false one.  Returns the graph, A's and B's weights and stated
    solutions."""
    from slam.pose_graph import PoseGraph
    from tests.test_segment_variance import _laps

    graph, truth = _laps(noisy=0.1, stated=0.1, every=4)
    wrong = se2.compose(se2.between(truth[210], truth[221]), np.array([0.0525, 0.035, 0.007]))
    graph.add_loop(210, 221, wrong, graph.loops[0].information)
    later = np.array([max(lp.i, lp.j) for lp in graph.loops])
    a = np.ones(len(graph.loops))
    b = ((later < 100) | (later >= 216)).astype(float)
    b[-1] = 0.0

    def solved(w):
        sub = PoseGraph(graph.dim, dict(graph.initial), list(graph.odometry),
                        [lp for lp, x in zip(graph.loops, w, strict=True) if x > 0.5],
                        set(graph.fixed))
        return graph.gtsam_values(optimize(sub, "none", init="odometry").poses)

    return graph, a, solved(a), b, solved(b)


def test_offer_back_returns_the_noisy_stretch_loops_and_not_the_false_one() -> None:
    from slam.least_squares import StickySolver
    from slam.loop_recheck import _quadratic
    from slam.offer_back import OWN_PRIOR_DOF, mixed_factors, offer_back, shrunk
    from slam.segment_variance import _segment_calibrated, segment_factors

    graph, a, a_values, b, b_values = _offer_back_case()
    offered = np.flatnonzero((a > 0.5) & (b < 0.5))
    assert len(offered) == 30  # 29 true loops of poses 100-215 and the false one
    fa = segment_factors(graph, a_values, a)
    fb = segment_factors(graph, b_values, b, prior_dof=OWN_PRIOR_DOF)
    fb = shrunk(fb, fb.pooled)
    # B's loops give no redundancy to poses 100-199: that segment takes A's factor, near
    # the actual 1 (0.1 m as stated); the quiet ones B's, near (0.003 / 0.1)^2 = 9e-4.
    assert fb.redundancy[1] < 1e-9 and fb.redundancy[[0, 2]].min() > 20
    mixed = mixed_factors(fb, fa)
    assert mixed.factors[1] == fa.factors[1] > 0.5
    assert np.all(mixed.factors[[0, 2]] < 3e-3)
    assert np.all(fa.factors[[0, 2]] > 0.01)  # A's, pulled up by the noisy stretch
    # Each offered loop's innovation against B's graph (c = 0.5 chi2_3^-1(0.99) =
    # 0.5 * 11.345, tables): under the mixed factors the true ones pass and the false one
    # fails; under A's factors alone the false one would pass, under B's alone (the noisy
    # stretch as stiff as the pooled quiet ones) no true one would.
    c = tls_threshold(2)
    assert c == pytest.approx(0.5 * 11.345, abs=1e-3)
    unit = [graph.between_factor(lp) for lp in graph.loops]

    def innovations(factors):
        accepted = _segment_calibrated(graph, factors, unit, b)
        test = InnovationTest(accepted, StickySolver()(accepted, b_values), graph.keys, 3)
        return _quadratic(*test.blocks([unit[k] for k in offered]))

    under_mixed, under_a, under_b = (innovations(f) for f in (mixed, fa, fb))
    assert under_mixed[:-1].max() < c < under_mixed[-1]
    assert under_a[-1] < c
    assert under_b[:-1].min() > c
    # offer_back: every true loop back, the false one not, B's own loops untouched.
    weights = offer_back(graph, b_values, b, a_values, a)
    np.testing.assert_array_equal(weights[:-1], 1.0)
    assert weights[-1] == 0.0


def test_shrunk_factors_match_the_hand_computed_prior() -> None:
    from slam.offer_back import shrunk
    from slam.segment_variance import SegmentFactors

    # Segment 0: raw 0.01 from 7 dof, shrunk with 3 dof toward 0.002:
    # (0.07 + 0.006) / 10 = 0.0076; segment 1 without redundancy: the target.
    f = SegmentFactors(np.array([0.01, 0.5]), np.array([0.01, np.inf]), np.array([7.0, 0.0]),
                       0.3, np.array([0, 1]))
    out = shrunk(f, 0.002, 3.0)
    np.testing.assert_allclose(out.factors, [0.0076, 0.002])
    assert out.pooled == 0.002
