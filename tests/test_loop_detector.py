"""LoopClosureDetector bookkeeping: which keyframes may be candidates."""

from __future__ import annotations

import numpy as np

from data.sim import simulate_run
from loopclosure.loop_detector import LoopClosureConfig, LoopClosureDetector


def _detector(stamps: list[float]) -> LoopClosureDetector:
    scans = simulate_run("box", seed=0).scans[: len(stamps)]
    det = LoopClosureDetector(
        LoopClosureConfig(exclude_recent=5, exclude_recent_s=20.0),
        submap=lambda key: scans[key].points(),
    )
    for key, (scan, stamp) in enumerate(zip(scans, stamps, strict=True)):
        det.add_keyframe(key, stamp, scan)
    return det


def test_recent_keyframes_by_count_and_by_time_are_excluded() -> None:
    det = _detector([float(k) for k in range(40)])  # 1 s apart
    # key 39: count rule excludes 34..38, time rule everything after 19 s.
    np.testing.assert_array_equal(np.flatnonzero(det.eligible(39)), np.arange(20))


def test_repeated_stamps_drop_the_time_rule() -> None:
    det = _detector([0.0] * 40)  # corrected Radish logs: every stamp 0
    np.testing.assert_array_equal(np.flatnonzero(det.eligible(39)), np.arange(34))
