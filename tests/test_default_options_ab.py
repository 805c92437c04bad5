"""benchmarks/default_options_ab.py: the fast-path comparison it prints decides whether
the stall rule changes a cell, so its 'same' must be exact."""

from __future__ import annotations

import gtsam

from tests.helpers import load_benchmark
from tests.test_backend import _square_graph
from tests.test_fast_path_screen import _with_false_loops


def test_same_stage_is_equality_at_tolerance_zero() -> None:
    bench = load_benchmark("default_options_ab")
    a = gtsam.Values()
    a.insert(0, gtsam.Pose2(1.0, 2.0, 0.3))
    b = gtsam.Values()
    b.insert(0, gtsam.Pose2(1.0, 2.0 + 1e-15 * 4, 0.3))
    assert bench.same_stage(None, None)
    assert not bench.same_stage((a, 3), None) and not bench.same_stage(None, (a, 3))
    assert bench.same_stage((a, 3), (gtsam.Values(a), 3))
    assert not bench.same_stage((a, 3), (a, 4))  # other iterations
    assert not bench.same_stage((a, 3), (b, 3))  # 4e-15 m apart


def test_fast_path_stage_passes_a_consistent_graph_and_fails_false_loops() -> None:
    bench = load_benchmark("default_options_ab")
    clean, _ = _square_graph(noise=0.02, laps=3)
    off, _ = bench.fast_path_stage(clean, False)
    on, _ = bench.fast_path_stage(clean, True)
    assert off is not None and bench.same_stage(off, on)
    corrupted, _ = _with_false_loops(60)
    assert bench.fast_path_stage(corrupted, False)[0] is None
    assert bench.fast_path_stage(corrupted, True)[0] is None
