"""The offline prefilter replay's smoothed descriptor (benchmarks/prefilter_misses.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from prefilter_misses import smoothed


def test_smoothed_is_the_weighted_mean_of_own_and_viewpoints() -> None:
    keys = np.array([3, 5, 7])
    own = {3: np.array([1.0, 0.0]), 5: np.array([0.0, 1.0])}  # 7: no own vector
    vecs = np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    owner = np.array([0, 0, 2])  # two viewpoints of key 3, one of key 7
    out = smoothed(own, keys, (vecs, owner))
    assert sorted(out) == [3, 5]
    # key 3: ([1, 0] + [0, 1] + [0, 1]) / 3 = [1/3, 2/3], then unit length
    np.testing.assert_allclose(out[3], np.array([1.0, 2.0]) / np.sqrt(5.0))
    np.testing.assert_allclose(out[5], [0.0, 1.0])  # no viewpoint: unchanged
    raw = smoothed(own, keys, (vecs, owner), self_weight=2.0, unit=False)
    np.testing.assert_allclose(raw[3], [2.0 / 4, 2.0 / 4])  # (2 [1, 0] + 2 [0, 1]) / 4
