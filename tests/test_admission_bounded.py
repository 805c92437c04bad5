"""A deferred loop waits a bounded number of loop-bearing blocks, then the gate decides."""

from __future__ import annotations

import numpy as np

from slam.consistency import DEFER_MODES, admit_incrementally
from slam.optimize import initial_guess
from tests.test_deferral import loose_lap


def test_bounded_wait_lets_the_return_be_admitted_before_a_false_first_loop() -> None:
    graph, false = loose_lap(range(4, 36, 2), false_loop=True)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = admit_incrementally(graph, values, block=10, defer=True, wait=1)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert result.weights[false] == 0.0
    assert result.weights[true].all()


def test_a_lone_true_loop_is_decided_by_the_gate_after_its_wait() -> None:
    """No consensus ever comes for one loop: waiting to the end rejects it, a bounded
    wait hands it to the plain gate, which admits it."""
    graph, _ = loose_lap(range(4, 5), false_loop=False, bias=0.002)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    forever = admit_incrementally(graph, values, block=10, defer=True)
    bounded = admit_incrementally(graph, values, block=10, defer=True, wait=1)
    plain = admit_incrementally(graph, values, block=10)
    assert plain.weights[0] == 1.0
    assert forever.weights[0] == 0.0
    assert bounded.weights[0] == 1.0


def test_bounded_is_a_deferral_mode() -> None:
    assert {"bounded", "both"} <= set(DEFER_MODES)


def test_both_compares_the_passes_with_and_without_the_bounded_wait() -> None:
    from slam.consistency import incremental_tls

    graph, false = loose_lap(range(4, 36, 2), false_loop=True)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    result = incremental_tls(graph, values, block=10, defer="both", tries=0)
    true = np.ones(len(graph.loops), dtype=bool)
    true[false] = False
    assert result.weights[false] == 0.0
    assert result.weights[true].all()
