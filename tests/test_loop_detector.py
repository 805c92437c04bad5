"""LoopClosureDetector: which keyframes may be candidates, detect in any order, submap
versions."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from data.sim import simulate_run
from loopclosure.loop_detector import LoopCandidate, LoopClosureConfig, LoopClosureDetector


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


# -- detect in any order; submap versions ---------------------------------------------

README_STEP = 4  # the README's example: every 4th simulated scan is a keyframe


@pytest.fixture(scope="module")
def keyframes() -> list:
    return simulate_run("box", seed=0).scans[::README_STEP][:62]


def _summary(candidates: list[LoopCandidate]) -> list[str]:
    return [
        repr((c.query, c.match, c.source, c.accepted, c.reason, c.relative.tolist(),
              c.covariance.tolist(), c.predicted_distance, c.prefilter_distance,
              c.prefilter_rank, c.fused_score, c.verifier_distances))
        for c in candidates
    ]


def _run(keyframes: list, submap, version=None, hold: int | None = None):
    """Add and detect every keyframe in order; with `hold`, add `hold + 1` before
    detecting `hold`.  Returns the detector and the candidates per key."""
    poses = np.array([s.odom for s in keyframes])
    det = LoopClosureDetector(
        LoopClosureConfig(global_every=1), submap=submap, submap_version=version
    )
    found = {}
    for key, scan in enumerate(keyframes):
        det.add_keyframe(key, scan.stamp, scan)
        if hold is not None and key == hold + 1:
            assert len(det.database) == hold + 2
            found[hold] = det.detect(hold, poses[: key + 1])
        if key != hold:
            found[key] = det.detect(key, poses[: key + 1])
    return det, found


def test_detect_works_for_any_added_key(keyframes) -> None:
    submap = lambda key: keyframes[key].points()  # noqa: E731
    _, now = _run(keyframes, submap)
    _, later = _run(keyframes, submap, hold=60)
    assert any(c.source == "global" for c in now[60])  # the appearance search ran
    assert _summary(later[60]) == _summary(now[60])
    assert _summary(later[61]) == _summary(now[61])
    for c in now[60]:  # typed figures of each search
        if c.source == "global":
            assert c.prefilter_rank >= 0 and 0.0 <= c.fused_score <= 1.0
            assert set(c.verifier_distances) == {"flirt", "mrm"}
            assert np.isnan(c.predicted_distance)
        else:
            assert c.prefilter_rank == -1 and np.isfinite(c.predicted_distance)
    det = LoopClosureDetector(submap=submap)
    det.add_keyframe(0, 0.0, keyframes[0])
    with pytest.raises(UserError, match="never added"):
        det.detect(1, np.zeros((2, 3)))
    with pytest.raises(UserError, match="in order"):
        det.add_keyframe(2, 1.0, keyframes[2])


def test_registration_targets_follow_the_submap_version(keyframes) -> None:
    points = {k: s.points() for k, s in enumerate(keyframes)}
    version = dict.fromkeys(points, 0)
    det, found = _run(keyframes, points.__getitem__, version.__getitem__)
    poses = np.array([s.odom for s in keyframes])
    first = {c.match: c for c in det.detect(60, poses) if c.source == "global"}
    assert first and _summary(list(first.values())) == _summary(
        [c for c in found[60] if c.source == "global"]
    )
    cand = next(iter(first))
    points[cand] = points[cand] + np.array([0.4, -0.3])  # the host's submap moved...
    stale = {c.match: c for c in det.detect(60, poses)}
    assert stale[cand].verification.fitness == first[cand].verification.fitness
    version[cand] += 1  # ... and now the host says so
    fresh = {c.match: c for c in det.detect(60, poses)}
    assert fresh[cand].verification.fitness != first[cand].verification.fitness
    assert not np.allclose(fresh[cand].relative[:2], first[cand].relative[:2], atol=0.1)
