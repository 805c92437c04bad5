"""The offline replay of the viewpoints' re-ranking (benchmarks/viewpoint_rerank.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from viewpoint_rerank import per_key_min, variants


def test_per_key_min_takes_each_owners_smallest() -> None:
    got = per_key_min(np.array([3.0, 1.0, 2.0, 5.0]), np.array([0, 0, 2, 2]), 4)
    np.testing.assert_array_equal(got, [1.0, np.inf, 2.0, np.inf])


def test_variants_rank_the_pool_only() -> None:
    """Rows 0-3 eligible, own distances d0; the query's viewpoint (row 1 of P) is
    near rows 2 and 3.  The pool of 2 holds the own description's two nearest (rows
    0, 1): min-2 leaves rows 2-3 at d0; rerank-2-1 scales the viewpoint's row by
    s_0 / s_1 = 0.1 / 0.5 (the smallest over the pool of each)."""
    d0 = np.array([0.1, 0.2, 0.9, 1.0])
    P = np.vstack([d0, [0.5, 0.6, 0.05, 0.01]])
    rows = np.arange(4)
    fns = variants([2], [1], full_rank=True)
    np.testing.assert_allclose(fns["default"](P, d0, rows), d0)
    np.testing.assert_allclose(fns["min"](P, d0, rows), [0.1, 0.2, 0.05, 0.01])
    np.testing.assert_allclose(fns["min-2"](P, d0, rows), d0)
    np.testing.assert_allclose(fns["rerank-2-1"](P, d0, rows), [0.1, 0.12, 0.9, 1.0])
    # over every row: s_0 = 0.1, s_1 = 0.01, the viewpoint's row times 10
    np.testing.assert_allclose(fns["norm-1"](P, d0, rows), [0.1, 0.2, 0.5, 0.1])
