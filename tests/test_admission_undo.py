"""Undo hypotheses of the time-ordered admission (`slam.admission_undo`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from slam.admission import AdmissionPass
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
