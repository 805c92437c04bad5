"""The truth-free bar rule of `benchmarks/consistency_bar_rule.py`, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import load_benchmark


def test_the_matched_bar_refuses_the_same_share_of_pairs() -> None:
    matched_bar = load_benchmark("consistency_bar_rule").matched_bar
    keyframe = np.array([0.80, 0.90, 0.95, 0.99])  # half of them below 0.92
    scans = np.array([0.40, 0.10, 0.30, 0.20])
    assert matched_bar(keyframe, scans, 0.92) == pytest.approx(0.25)  # the median
    assert matched_bar(keyframe, scans, 0.5) == pytest.approx(0.10)  # none below: the least
    assert matched_bar(keyframe, scans, 1.0) == pytest.approx(0.40)  # all below: the most
