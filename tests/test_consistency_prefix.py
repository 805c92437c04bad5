"""The iSAM2-kept prefix of the time-ordered admission decides as the batch solves do."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from evaluation.robustness import aligned_position_error, inject_false_loops
from slam.consistency import admit_incrementally, incremental_tls
from slam.isam_prefix import IsamPrefix, isam_or_batch
from slam.least_squares import StickySolver
from slam.optimize import initial_guess, optimize
from slam.pose_graph import Constraint, poses_from_values
from tests.test_backend import _square_graph


def test_isam2_prefix_decides_as_the_batch_prefix() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    corrupted, _ = inject_false_loops(graph, 0.5, np.random.default_rng(2))
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    runs = {
        mode: admit_incrementally(corrupted, values, block=10, prefix_solver=mode,
                                  solver=StickySolver())
        for mode in ("batch", "isam2")
    }
    np.testing.assert_array_equal(runs["batch"].weights, runs["isam2"].weights)
    poses = {m: poses_from_values(r.values, 2) for m, r in runs.items()}
    assert aligned_position_error(poses["isam2"], poses["batch"], 2) < 1e-6
    assert abs(runs["isam2"].tls_cost - runs["batch"].tls_cost) < 1e-6


def test_incremental_tls_ends_at_the_plain_optimum_without_outliers() -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = incremental_tls(graph, values, block=10)
    assert result.weights.all()
    plain = optimize(graph, "none").poses
    assert aligned_position_error(poses_from_values(result.values, 2), plain, 2) < 1e-6


def test_lm_budget_hands_an_unconverged_solve_to_dogleg() -> None:
    graph, _ = _square_graph(noise=0.05, laps=3)
    factors, _ = graph.factor_graph()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    capped = StickySolver(lm_budget=1)
    result = capped(factors, values)
    assert capped.dogleg  # one LM iteration cannot converge from the odometry chain
    free = StickySolver()(factors, values)
    assert abs(factors.error(result) - factors.error(free)) < 1e-6 * max(1.0, factors.error(free))


def square_chain_prefix(isam: IsamPrefix):
    """The square graph (three laps, 0.02 noise), its anchor and odometry added to
    `isam` with the odometry chain's poses: ``(graph, factors)``, `factors` the same
    anchor and odometry factors."""
    graph, _ = _square_graph(noise=0.02, laps=3)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    factors = gtsam.NonlinearFactorGraph()
    for key in graph.anchor_keys():
        factors.add(graph.prior_factor(key))
    for o in graph.odometry:
        factors.add(graph.between_factor(o))
    for k in range(factors.size()):
        isam.add(factors.at(k))
    for key in graph.keys:
        isam.insert(key, values.atPose2(key))
    return graph, factors


def _chain_with_loop(false_loop: bool):
    """The square graph's anchor and odometry in an `IsamPrefix`, one loop added after
    the chain is solved: the given first loop, or the same loop moved 5 m off."""
    isam = IsamPrefix(max_updates=1)
    graph, factors = square_chain_prefix(isam)
    current = isam.solve()
    loop = graph.loops[0]
    if false_loop:
        loop = Constraint(loop.i, loop.j, loop.measurement + np.array([5.0, 0.0, 1.0]),
                          loop.information)
    factor = graph.between_factor(loop)
    factors.add(factor)
    isam.add(factor)
    return isam, factors, current


def test_isam2_prefix_hands_over_to_batch_when_its_updates_do_not_converge() -> None:
    isam, factors, current = _chain_with_loop(false_loop=True)
    solved, nxt = isam_or_batch(isam, StickySolver(), factors, current)
    assert not isam.converged  # one update cannot absorb a loop 5 m off
    assert nxt is None
    batch = StickySolver()(factors, current)
    assert abs(factors.error(solved) - factors.error(batch)) < 1e-6 * factors.error(batch)


def test_isam2_prefix_keeps_isam2_while_its_updates_converge() -> None:
    isam, factors, current = _chain_with_loop(false_loop=False)
    isam.max_updates = 20
    solved, nxt = isam_or_batch(isam, StickySolver(), factors, current)
    assert isam.converged and nxt is isam
    batch = StickySolver()(factors, current)
    assert abs(factors.error(solved) - factors.error(batch)) < 1e-6 * max(1.0, factors.error(batch))


def test_a_pass_stopped_at_its_fold_resumes_to_the_same_decisions() -> None:
    from slam.consistency import AdmissionPass, tls_cost

    graph, _ = _square_graph(noise=0.02, laps=3)
    corrupted, _ = inject_false_loops(graph, 0.5, np.random.default_rng(2))
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    whole = admit_incrementally(corrupted, values, block=10, solver=StickySolver())
    run = AdmissionPass(corrupted, values, block=10, solver=StickySolver())
    run.advance(blocks=2)
    assert not run.done and run.last == 19
    run.advance(until_fold=True)
    run.advance()
    np.testing.assert_array_equal(run.result().weights, whole.weights)
    assert abs(run.result().tls_cost - whole.tls_cost) < 1e-6
    stated = corrupted.factor_graph()
    assert run.prefix_cost(run.current, stated) == pytest.approx(
        tls_cost(corrupted, run.current, factors=stated))


def _same_pass(a, b) -> None:
    """Two finished passes with the same decisions and the same solution, bit for bit."""
    np.testing.assert_array_equal(a.weights, b.weights)
    pa, pb = poses_from_values(a.current, 2), poses_from_values(b.current, 2)
    assert all(np.array_equal(pa[k], pb[k]) for k in pa)
    assert a.blocks == b.blocks


def test_a_resumed_pass_equals_a_new_one_with_the_loop_barred() -> None:
    from slam.consistency import AdmissionPass

    graph, _ = _square_graph(noise=0.02, laps=3)
    corrupted, _ = inject_false_loops(graph, 0.5, np.random.default_rng(2))
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    solve = StickySolver()
    source = AdmissionPass(corrupted, values, block=10, solver=solve, record=True)
    source.advance()
    late = int(np.flatnonzero(source.weights > 0.5)[-1])  # an accepted loop of a late block
    assert source.block_of(late) > 1 and len(source.snapshots) > 1
    for barred in ([late], [0]):
        fresh = AdmissionPass(corrupted, values, block=10, solver=solve, barred=barred)
        fresh.advance()
        resumed = source.resumed(source.block_of(barred[0]), barred=barred)
        resumed.advance()
        _same_pass(resumed, fresh)
    # The source is untouched by its resumed passes: resuming it again gives it back.
    again = source.resumed(source.block_of(late))
    again.advance()
    _same_pass(again, source)


def _stated_pass_on_loose_odometry():
    """A 3-lap square with odometry stated 100 times looser than it is (the calibrated
    gate far lower than the stated one) and 50% local false loops; its recorded stated
    pass, advanced to the end. Returns (graph, start, solver, pass)."""
    from slam.consistency import AdmissionPass
    from slam.variance_components import with_information_scaled

    graph, _ = _square_graph(noise=0.02, laps=3)
    corrupted, _ = inject_false_loops(with_information_scaled(graph, 0.01), 0.5,
                                      np.random.default_rng(1), "local")
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    solve = StickySolver()
    stated = AdmissionPass(corrupted, values, block=10, solver=solve, record=True)
    stated.advance()
    return corrupted, values, solve, stated


def test_the_calibrated_pass_forks_from_the_stated_one_where_it_first_admits_less(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from slam.consistency import AdmissionPass

    monkeypatch.setattr("slam.admission.SNAPSHOTS", 12)  # a snapshot before every block
    corrupted, values, solve, stated = _stated_pass_on_loose_odometry()
    fresh = AdmissionPass(corrupted, values, block=10, solver=solve, gate="calibrated")
    fresh.advance()
    assert stated.calibrated_step == 2  # blocks 0 and 1 are decided alike
    assert not np.array_equal(fresh.weights, stated.weights)
    fork = stated.resumed(stated.calibrated_step, gate="calibrated")
    assert fork.last == 19
    fork.advance()
    _same_pass(fork, fresh)


@pytest.mark.parametrize("fork", [True, False])
def test_the_stated_pass_keeps_the_snapshot_where_the_calibrated_pass_forks(
    monkeypatch: pytest.MonkeyPatch, fork: bool,
) -> None:
    """`FORK_SNAPSHOT`: with one evenly spaced snapshot (before block 0) the stated pass
    also keeps the one before block 2, where the calibrated gate first admits less, and
    the calibrated pass resumed from it starts there (pose 19 added) and ends as a new
    calibrated pass, bit for bit; without it the fork re-decides from block 0."""
    from slam.consistency import AdmissionPass

    monkeypatch.setattr("slam.admission.SNAPSHOTS", 1)
    monkeypatch.setattr("slam.admission.FORK_SNAPSHOT", fork)
    corrupted, values, solve, stated = _stated_pass_on_loose_odometry()
    assert stated.calibrated_step == 2
    assert [snap.step for snap in stated.snapshots] == ([0, 2] if fork else [0])
    resumed = stated.resumed(stated.calibrated_step, gate="calibrated")
    assert resumed.last == (19 if fork else -1)
    resumed.advance()
    fresh = AdmissionPass(corrupted, values, block=10, solver=solve, gate="calibrated")
    fresh.advance()
    _same_pass(resumed, fresh)
