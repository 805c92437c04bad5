"""Undo hypotheses of the time-ordered admission and their look-ahead (`slam.admission_undo`)."""

from __future__ import annotations

import numpy as np
import pytest

import slam.admission_undo as admission_undo
from data.errors import UserError
from slam.admission import AdmissionPass
from slam.admission_undo import with_loops
from slam.optimize import initial_guess
from slam.pose_graph import PoseGraph
from tests.test_deferral import LAP, loose_lap

TRUE_LOOPS = range(4, 36, 2)  # the return's true loops (k, LAP + k)


def _false_return_a_block_early() -> tuple[PoseGraph, int]:
    """`loose_lap` closed by its true loops and a false loop (8, LAP - 2) in the block
    before them (block 10) that says pose LAP - 2 is where pose 8 is (about 2 m off);
    its ends lie within a block of those of the first true loops (4, LAP + 4) ..."""
    graph, _ = loose_lap(TRUE_LOOPS, False)
    false = graph.add_loop(8, LAP - 2, np.zeros(3), np.diag([400.0, 400.0, 2500.0]))
    return graph, false


def _pass(graph: PoseGraph, undo: bool) -> AdmissionPass:
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, undo=undo)
    run.advance()
    return run


def test_an_early_false_return_bends_the_lap_without_undo() -> None:
    graph, false = _false_return_a_block_early()
    run = _pass(graph, undo=False)
    assert run.weights[false] == 1.0
    assert run.weights.sum() < len(graph.loops) - 1


def test_the_undo_removes_the_false_return_and_admits_the_true_one() -> None:
    graph, false = _false_return_a_block_early()
    run = _pass(graph, undo=True)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert run.undone >= 1
    assert run.weights[false] == 0.0
    assert run.weights[true].all()
    # the kept hypothesis leaves the prefix it reports: the accepted graph's solution
    assert run.result().tls_cost < _pass(graph, undo=False).result().tls_cost


def test_the_undo_changes_nothing_without_a_contradiction() -> None:
    graph, _ = loose_lap(TRUE_LOOPS, False)
    plain, undo = _pass(graph, undo=False), _pass(graph, undo=True)
    assert undo.undone == 0
    np.testing.assert_array_equal(plain.weights, undo.weights)
    assert plain.weights.all()


def test_the_undo_and_the_deferral_do_not_combine() -> None:
    graph, _ = loose_lap(TRUE_LOOPS, False)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    with pytest.raises(UserError):
        AdmissionPass(graph, values, undo=True, defer=True)


def test_the_decided_cost_is_the_tls_objective_once_every_pose_is_added() -> None:
    """`_decided_cost` (anchors, odometry and every loop at min(e, c)) against `tls_cost`
    on the whole graph, at a solution where the false loop is far above ``c``."""
    from slam.admission import tls_cost

    graph, false = _false_return_a_block_early()
    run = _pass(graph, undo=True)
    assert run.unit[false].error(run.current) > run._c
    assert run._decided_cost(run.current) == pytest.approx(tls_cost(graph, run.current))


def _forced_false_loop(long_window: bool) -> tuple[AdmissionPass, AdmissionPass, int]:
    """The lap closed by its true loops and a false loop (40, LAP + 20) that says pose
    LAP + 20 is where pose 40 is (about 4 m off; the plain pass rejects it).  After its
    block a hypothesis is forced by hand: the false loop admitted, the true loop of the
    same block rejected, the look-ahead opened as `test_hypotheses` opens it.  Returns the
    pass so continued, the plain pass, and the false loop's index."""
    graph, _ = loose_lap(TRUE_LOOPS, False)
    false = graph.add_loop(40, LAP + 20, np.zeros(3), np.diag([400.0, 400.0, 2500.0]))
    plain = _pass(graph, undo=False)
    assert plain.weights[false] == 0.0
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, undo=True, prefix_solver="batch")
    while run._step <= run.block_of(false):
        run.advance(blocks=1)
    assert run.weights[false] == 0.0 and run._rival is None
    admission_undo.open_window(run)
    weights = run.weights.copy()
    weights[false] = 1.0
    weights[[k for k in range(len(graph.loops)) if graph.loops[k].j == LAP + 20
             and k != false]] = 0.0
    run.weights = weights
    run._fixed = admission_undo.with_loops(run._base, run.unit, np.flatnonzero(weights > 0.5))
    run.current = run._solve(run._fixed, run.current)
    if long_window:  # still open at the last block
        run._rival_until = run.blocks + 100
    return run, plain, false


def test_a_hypothesis_the_next_blocks_contradict_is_reverted() -> None:
    run, plain, false = _forced_false_loop(False)
    run.advance(blocks=1)
    assert run._rival is not None  # the window is still open after one loop-bearing block
    run.advance()
    assert run.examined == 1 and run.reverted == 1
    assert run.weights[false] == 0.0
    np.testing.assert_array_equal(run.weights, plain.weights)


def test_an_open_look_ahead_is_settled_at_the_last_block() -> None:
    run, plain, _ = _forced_false_loop(True)
    run.advance()
    assert run._rival is None and run.examined == 1 and run.reverted == 1
    np.testing.assert_array_equal(run.weights, plain.weights)


def test_a_hypothesis_the_next_blocks_confirm_is_kept() -> None:
    graph, false = _false_return_a_block_early()
    run = _pass(graph, undo=True)
    assert run.undone >= 1 and run.examined >= 1 and run.reverted == 0
    assert run.weights[false] == 0.0


def test_hypotheses_solved_on_the_isam2_prefix_decide_as_the_batch_solves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`BY_ISAM`: the undo hypothesis of the early false return solved on a copy of the
    pass's iSAM2 prefix keeps the same loops as the batch-solved one, and the pass goes
    on with that copy as its prefix (the accepted graph's solution)."""
    graph, false = _false_return_a_block_early()
    monkeypatch.setattr(admission_undo, "BY_ISAM", False)
    batch = _pass(graph, undo=True)
    monkeypatch.setattr(admission_undo, "BY_ISAM", True)
    by_isam = _pass(graph, undo=True)
    assert by_isam.undone == batch.undone >= 1
    np.testing.assert_array_equal(by_isam.weights, batch.weights)
    assert by_isam.weights[false] == 0.0
    assert by_isam._isam is not None
    positions = np.array([by_isam.current.atPose2(k).translation() for k in graph.keys])
    expected = np.array([batch.current.atPose2(k).translation() for k in graph.keys])
    assert np.abs(positions - expected).max() < 1e-3


def _poses(values) -> np.ndarray:  # type: ignore[no-untyped-def]
    return np.array([values.atPose2(k).matrix() for k in values.keys()])


def test_hypotheses_that_take_out_the_same_loops_share_their_first_solve() -> None:
    """`_SharedSolve`: the second request with the same kept loops costs no iSAM2 solve,
    returns the first's estimate bit for bit and an independent copy of its iSAM2 that
    goes on as a fresh solve's would (bit for bit); other kept loops are solved."""
    from slam.admission_undo import _isam_solved, _SharedSolve, _trial_prefix

    graph, _ = loose_lap(TRUE_LOOPS, False)
    run = _pass(graph, undo=False)
    admitted = np.flatnonzero(run.weights > 0.5)
    keep, out = admitted[:-3], admitted[-3:]
    shared = _SharedSolve()
    first, first_isam = shared.solved(run, _trial_prefix(run, out), keep)
    again, again_isam = shared.solved(run, _trial_prefix(run, out), keep)
    assert shared.hits == 1 and again_isam is not first_isam
    np.testing.assert_array_equal(_poses(again), _poses(first))
    fresh, fresh_isam = _isam_solved(run, _trial_prefix(run, out),
                                     with_loops(run._base, run.unit, keep), run.current)
    np.testing.assert_array_equal(_poses(fresh), _poses(first))
    for isam in (again_isam, fresh_isam):  # the next round of the hypothesis on each
        isam.add(run.unit[out[0]], int(out[0]))
    np.testing.assert_array_equal(_poses(again_isam.solve()), _poses(fresh_isam.solve()))
    shared.solved(run, _trial_prefix(run, admitted[-2:]), admitted[:-2])
    assert shared.hits == 1  # another kept set: solved

