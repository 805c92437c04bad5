"""benchmarks/paper_place_matchers.py: variant parsing and the per-query Bull's eye."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.retrieval import bullseye
from tests.helpers import load_benchmark


def test_parse_variant() -> None:
    parse = load_benchmark("paper_place_matchers").parse_variant
    assert parse("r:ring:norm='l1',n_rings=64") == ("r", "ring", {"norm": "l1", "n_rings": 64})
    assert parse("m:mrm") == ("m", "mrm", {})
    with pytest.raises(SystemExit):
        parse("ring")


def test_bullseye_rows_by_hand_and_against_the_full_score() -> None:
    rows_score = load_benchmark("paper_place_matchers").bullseye_rows
    # Two classes of two: the 2n = 4 nearest are all four shapes, score 100.
    labels = np.array(["a", "a", "b", "b"])
    d = np.array([[0, 5, 1, 2], [5, 0, 1, 2], [1, 1, 0, 9], [2, 2, 9, 0]], dtype=float)
    assert rows_score(d, labels, np.arange(4)) == 100.0
    # Three classes of two (window 4 of 6): query 0 ranks 0, 2, 3, 4 first -> 1 hit of 2.
    labels = np.array(["a", "a", "b", "b", "c", "c"])
    rng = np.random.default_rng(0)
    x = rng.random((6, 2))
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    d[0] = [0, 9, 1, 2, 3, 8]
    hits0 = 1
    assert rows_score(d[:1], labels, np.array([0])) == pytest.approx(100.0 * hits0 / 2)
    # All rows: the same as the benchmark's full score.
    assert rows_score(d, labels, np.arange(6)) == pytest.approx(bullseye(d, labels))


def test_bullseye_by_group_splits_the_queries_by_log() -> None:
    by_group = load_benchmark("paper_place_matchers").bullseye_by_group
    # Classes of two: each query's window is its 4 nearest (itself first).
    labels = np.array(["x/p0", "x/p0", "y/p0", "y/p0", "y/p1", "y/p1"])
    d = np.array([
        [0, 1, 5, 5, 5, 5],
        [1, 0, 5, 5, 5, 5],
        [5, 5, 0, 9, 1, 2],
        [5, 5, 9, 0, 5, 5],
        [5, 5, 1, 5, 0, 1],
        [5, 5, 2, 5, 1, 0],
    ], dtype=float)
    out = by_group(d, labels, np.arange(6))
    # x: query 0 -> 0, 1, 2, 3 and query 1 -> 1, 0, 2, 3: 4 hits of 4.
    assert out["x"] == 100.0
    # y: query 2 -> 2, 4, 5, 0 (1 hit); 3 -> 3, 0, 1, 4 (1); 4 -> 4, 2, 5, 0 (2);
    # 5 -> 5, 4, 2, 0 (2): 6 hits of 8.
    assert out["y"] == pytest.approx(75.0)
    assert set(out) == {"x", "y"}
