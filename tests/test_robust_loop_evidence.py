"""`benchmarks/robust_loop_evidence.neighbours`: loops close at both ends, counted by hand."""

from __future__ import annotations

import numpy as np

from benchmarks.robust_loop_evidence import neighbours


def test_neighbours_counts_loops_close_at_both_ends() -> None:
    # Loops 0 and 1 are 3 and 4 poses apart at their two ends (within 5); loop 2 shares
    # loop 0's low end but not its high one; loop 3 is far from all.
    ends = np.array([[10, 500], [13, 504], [10, 300], [900, 1500]])
    assert neighbours(ends, 5).tolist() == [1, 1, 0, 0]
    # Within 2 poses loops 0 and 1 no longer meet.
    assert neighbours(ends, 2).tolist() == [0, 0, 0, 0]
