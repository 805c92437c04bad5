"""`benchmarks/robust_confirm_count.py`: the counts of the admission check's work."""

from __future__ import annotations

import numpy as np

from benchmarks.robust_confirm_count import ConfirmCount, install, restore
from slam.admission import AdmissionPass
from slam.admission_undo import with_loops
from slam.optimize import initial_guess
from tests.test_admission_confirm import _square


def test_a_round_of_two_loops_counts_two_minima_and_the_loop_turned_back() -> None:
    graph, true, false = _square()
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    run = AdmissionPass(graph, values, block=10, prefix_solver="batch")
    run.advance()
    pending = np.array([true, false])
    kept = with_loops(run._base, run.unit, pending)
    current = run._solve(kept, run.current)
    before = run._base.error(run._solve(run._base, run.current))
    count = ConfirmCount()
    originals = install(count)
    try:
        back = run._unconfirmed(run._base, pending, np.ones(2, dtype=bool), np.arange(2),
                                current, before, run.current)
    finally:
        restore(originals)
    # by hand: both loops admitted at a joint cost above c, so each is left out once
    # (two minima, by batch solves: no iSAM2 prefix); the false one is turned back and
    # the true one alone then costs nothing, so no further minimum is computed
    np.testing.assert_array_equal(back, [1])
    assert (count.rounds, count.minima, count.from_isam, count.turned_back) == (1, 2, 0, 1)
    assert count.sizes == {2: 1}
    assert AdmissionPass._unconfirmed is originals[0]
