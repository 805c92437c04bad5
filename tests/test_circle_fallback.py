"""LoopClosureDetector: the whole-circle re-check of places whose heading hypotheses
all miss (`LoopClosureConfig.circle_fallback`)."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.sim import simulate_run
from loopclosure import candidate_checks
from loopclosure.geometric_check import LoopVerification
from loopclosure.loop_detector import LoopClosureConfig, LoopClosureDetector
from loopclosure.place_match import PlaceMatch

TURN = 0.7  # heading of the query in the stored keyframe's frame [rad]


def _pair(fallback: int) -> LoopClosureDetector:
    """Keyframe 0: a simulated scan; keyframe 1: the same place seen by a sensor turned
    by `TURN` at the same spot (its submap is keyframe 0's points in its own frame)."""
    scan = simulate_run("box", seed=0).scans[40]
    pts = scan.points()
    turned = se2.transform_points(np.array([0.0, 0.0, -TURN]), pts)
    det = LoopClosureDetector(
        LoopClosureConfig(exclude_recent=0, exclude_recent_s=0.0, circle_fallback=fallback),
        submap=lambda key: turned if key == 1 else pts)
    for key in range(2):
        det.add_keyframe(key, float(key), scan)
    return det


def _match(key: int, heading: float) -> PlaceMatch:
    return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=0, distances={},
                      score=0.9, headings=((heading, 1.0),))


@pytest.mark.parametrize("fallback", [0, 1])
def test_wrong_heading_hypotheses_are_recovered_by_the_whole_circle(fallback) -> None:
    # A hypothesis 90 degrees off: the check searches about it and its opposite
    # (both wrong) and fits nothing right; the whole circle finds the turn.
    det = _pair(fallback)
    (cand,) = det.verify_places(1, [_match(0, TURN + np.pi / 2)], np.zeros((2, 3)))
    if fallback == 0:
        assert not cand.accepted
        assert abs(se2.wrap_angle(cand.relative[2] - TURN)) > 0.3
    else:
        assert cand.accepted and cand.match == 0
        np.testing.assert_allclose(cand.relative, [0.0, 0.0, TURN], atol=0.02)
        assert cand.fused_score == 0.9


def _verdict(accepted: bool, reason: str) -> LoopVerification:
    return LoopVerification(accepted=accepted, reason=reason, relative=np.zeros(3),
                            covariance=np.eye(3), fitness=0.5, inlier_ratio=0.5, rms=0.01,
                            degeneracy=0.2, margin=0.3, hypotheses=1)


def _calls(monkeypatch, verdicts: dict[tuple[int, bool], LoopVerification]) -> list:
    """Replace `verify` by one answering `verdicts[(candidate, whole circle)]`."""
    calls: list[tuple[int, bool]] = []
    points = {}

    def fake_verify(query_points, target, headings=None, **kwargs):
        key = (points[id(target)], headings is None)
        calls.append(key)
        return verdicts[key]

    real_target = LoopClosureDetector._target

    def target(self, key):
        t = real_target(self, key)
        points[id(t)] = key
        return t

    monkeypatch.setattr(candidate_checks, "verify", fake_verify)
    monkeypatch.setattr(LoopClosureDetector, "_target", target)
    return calls


def _three(fallback: int) -> LoopClosureDetector:
    scans = simulate_run("box", seed=0).scans[:4]
    det = LoopClosureDetector(
        LoopClosureConfig(exclude_recent=0, exclude_recent_s=0.0, circle_fallback=fallback),
        submap=lambda key: scans[key].points())
    for key, scan in enumerate(scans):
        det.add_keyframe(key, float(key), scan)
    return det


def _apart() -> np.ndarray:
    """Map poses of the four keyframes, 10 m apart (no keyframe near another)."""
    return np.array([[10.0 * k, 0.0, 0.0] for k in range(4)])


def test_the_fallback_skips_not_a_revisit_and_stops_after_n_places(monkeypatch) -> None:
    fail = _verdict(False, "inconsistent free space (0.50 < 0.92)")
    far = _verdict(False, "not a revisit (3.0 m apart)")
    calls = _calls(monkeypatch, {(0, False): far, (1, False): fail, (2, False): fail,
                                 (0, True): fail, (1, True): fail, (2, True): fail})
    det = _three(1)
    out = det.verify_places(3, [_match(k, 0.0) for k in range(3)], _apart())
    # Place 0 fitted too far (not re-checked), place 1 is the one re-check allowed.
    assert calls == [(0, False), (1, False), (2, False), (1, True)]
    assert [c.reason for c in out] == [far.reason, fail.reason, fail.reason]


def test_no_fallback_once_a_place_is_accepted_and_its_acceptance_counts(monkeypatch) -> None:
    fail = _verdict(False, "registration failed")
    calls = _calls(monkeypatch, {(0, False): fail, (1, False): _verdict(True, "accepted"),
                                 (2, False): fail, (0, True): _verdict(True, "accepted")})
    det = _three(3)
    out = det.verify_places(3, [_match(k, 0.0) for k in range(3)], _apart())
    assert (0, True) not in calls and [c.accepted for c in out] == [False, True, False]
    # Nothing accepted from the hypotheses: place 0's whole-circle check is.
    calls = _calls(monkeypatch, {(0, False): fail, (1, False): fail,
                                 (0, True): _verdict(True, "accepted"), (1, True): fail})
    out = det.verify_places(3, [_match(k, 0.0) for k in range(2)], _apart())
    assert calls == [(0, False), (1, False), (0, True), (1, True)]
    assert [c.accepted for c in out] == [True, False]


def test_circle_fallback_must_not_be_negative() -> None:
    with pytest.raises(UserError, match=r"loops\.circle_fallback"):
        LoopClosureConfig(circle_fallback=-1)
