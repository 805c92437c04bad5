"""A degenerate prior-free check judged again on longer submaps (`loopclosure.longer_check`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from data import se2
from data.sim import simulate_run
from loopclosure import candidate_checks
from loopclosure.geometric_check import GeometricCheckConfig, LoopVerification, verify
from loopclosure.longer_check import (
    departure,
    is_degenerate,
    joined,
    judged,
    longer_fit,
    recheck_longer,
    trailing_count,
)
from loopclosure.loop_detector import LoopClosureConfig, LoopClosureDetector
from loopclosure.registration import RegistrationTarget
from tests.test_geometric_check import _walls
from tests.test_loop_detector import _match, _verdict

# A straight corridor 2 m wide along x (walls y = -1 and y = 1) with one doorway at
# x = 5..6 in the upper wall, opening into a room x = 3..8, y = 1..4.
CORRIDOR = _walls([((-30, -1), (30, -1)), ((-30, 1), (5, 1)), ((6, 1), (30, 1))])
ROOM = _walls([((5, 1), (5, 1.0)), ((3, 1), (5, 1)), ((3, 1), (3, 4)), ((3, 4), (8, 4)),
               ((8, 4), (8, 1)), ((8, 1), (6, 1))])
WORLD = np.vstack([CORRIDOR, ROOM])
PLAIN = CORRIDOR[~((CORRIDOR[:, 1] > 0) & (CORRIDOR[:, 0] > 4) & (CORRIDOR[:, 0] < 7))]
PLAIN = np.vstack([PLAIN, _walls([((4, 1), (7, 1))])])  # the same corridor, no doorway


def _submap(world: np.ndarray, pose: np.ndarray, x_from: float, x_to: float) -> np.ndarray:
    """The points of `world` with x in [x_from, x_to] (world frame), in `pose`'s frame."""
    keep = (world[:, 0] >= x_from) & (world[:, 0] <= x_to)
    return se2.transform_points(se2.inverse(pose), world[keep])


CANDIDATE = np.array([0.0, 0.0, 0.0])
QUERY = np.array([0.4, 0.15, 0.05])  # its true pose in the candidate's frame
CFG = GeometricCheckConfig()


def _short_check(world: np.ndarray) -> LoopVerification:
    """The first check, on 5.5 m of corridor around each keyframe: two walls only."""
    target = RegistrationTarget(_submap(world, CANDIDATE, -3, 2.5))
    return verify(_submap(world, QUERY, -3, 2.5), target, headings=[0.0],
                  max_distance=2.0, config=CFG)


def test_a_few_metres_of_corridor_are_degenerate() -> None:
    first = _short_check(WORLD)
    assert not first.accepted
    assert is_degenerate(first), first.reason
    assert first.degeneracy < CFG.min_degeneracy


def test_the_doorway_in_the_longer_submaps_fixes_the_pose_along_the_corridor() -> None:
    first = _short_check(WORLD)
    # Longer submaps: 10 m of path behind each keyframe (the robot drove towards -x),
    # now holding the doorway and its room 5-8 m ahead of the candidate.
    query = joined(_submap(WORLD, QUERY, -3, 2.5), _submap(WORLD, QUERY, -3, 10))
    cand = joined(_submap(WORLD, CANDIDATE, -3, 2.5), _submap(WORLD, CANDIDATE, -3, 10))
    second = recheck_longer(first, query, cand, max_distance=2.0, config=CFG)
    assert second.accepted, second.reason
    assert second.degeneracy >= CFG.min_degeneracy
    err = se2.between(QUERY, second.relative)
    assert np.hypot(err[0], err[1]) < 0.05
    assert abs(np.degrees(err[2])) < 0.5


def test_the_longer_check_searches_afresh_from_a_fit_slid_along_the_corridor() -> None:
    first = _short_check(WORLD)
    slid = dataclasses.replace(first, relative=first.relative + np.array([1.2, 0.0, 0.0]))
    query = _submap(WORLD, QUERY, -3, 10)
    cand = _submap(WORLD, CANDIDATE, -3, 10)
    second = recheck_longer(slid, query, cand, max_distance=2.0, config=CFG)
    assert second.accepted, second.reason
    err = se2.between(QUERY, second.relative)
    assert np.hypot(err[0], err[1]) < 0.05


def test_a_longer_corridor_with_nothing_across_it_stays_rejected() -> None:
    first = _short_check(PLAIN)
    assert is_degenerate(first), first.reason
    query = _submap(PLAIN, QUERY, -3, 10)
    cand = _submap(PLAIN, CANDIDATE, -3, 10)
    second = recheck_longer(first, query, cand, max_distance=2.0, config=CFG)
    assert not second.accepted
    assert second.reason.startswith(first.reason + "; longer submaps: degenerate")


def test_only_a_degeneracy_rejection_is_degenerate() -> None:
    base = _short_check(WORLD)

    def verdict(accepted: bool, reason: str) -> LoopVerification:
        return dataclasses.replace(base, accepted=accepted, reason=reason)

    assert is_degenerate(verdict(False, "degenerate (corridor-like, 0.010)"))
    assert is_degenerate(verdict(False, "partial overlap 0.30 and degenerate "
                                        "(corridor-like, 0.050)"))
    assert not is_degenerate(verdict(True, "accepted"))
    assert not is_degenerate(verdict(False, "inconsistent free space (0.80 < 0.92)"))


@pytest.mark.parametrize(("longer_keyframes", "longer_path_m", "counts"), [
    (30, 0.0, [(11, 30), (2, 30)]),
    (0, 0.0, []),
    # Keyframes 0.5 m apart: 2 m of path is 4 keyframes behind the query, the whole
    # 1 m behind keyframe 2.
    (0, 2.0, [(11, 4), (2, 2)]),
])
def test_the_detector_rechecks_a_degenerate_verdict_on_longer_submaps(
        longer_keyframes, longer_path_m, counts, monkeypatch) -> None:
    scans = simulate_run("box", seed=0).scans[:12]
    trailing: list[tuple[int, int]] = []

    def trailing_map(key: int, n: int) -> np.ndarray:
        trailing.append((key, n))
        return np.full((3, 2), 100.0 + key)

    config = LoopClosureConfig(exclude_recent=1, exclude_recent_s=0.0)
    config.check.longer_keyframes = longer_keyframes
    config.check.longer_path_m = longer_path_m
    det = LoopClosureDetector(config, submap=lambda k: scans[k].points(),
                              trailing_map=trailing_map)
    for key, scan in enumerate(scans):
        det.add_keyframe(key, scan.stamp, scan)
    trailing.clear()
    first = _verdict(False, "degenerate (corridor-like, 0.010)", [0.5, 0.0, 0.1])
    monkeypatch.setattr(candidate_checks, "verify", lambda *args, **kwargs: first)
    seen = []

    def fake_recheck(result, query, cand, *, max_distance, config):
        seen.append((result, query, cand))
        return _verdict(True, "accepted", [0.4, 0.0, 0.1])

    monkeypatch.setattr(candidate_checks, "recheck_longer", fake_recheck)
    poses = np.c_[0.5 * np.arange(12.0), np.zeros((12, 2))]
    (cand,) = det.verify_places(11, [_match(2, 0.9)], poses)
    if not counts:
        assert cand.reason == first.reason and not seen and not trailing
        return
    assert cand.accepted and cand.match == 2
    np.testing.assert_allclose(cand.relative, [0.4, 0.0, 0.1])
    # The query's submap and the keyframes behind it; the candidate's likewise.
    assert trailing == counts
    ((result, query, candidate),) = seen
    assert result is first
    np.testing.assert_allclose(query, np.vstack([scans[11].points(), np.full((3, 2), 111.0)]))
    np.testing.assert_allclose(candidate, np.vstack([scans[2].points(),
                                                     np.full((3, 2), 102.0)]))


def test_the_longer_fit_moves_the_first_one_along_its_axis_only() -> None:
    first = _short_check(WORLD)
    np.testing.assert_allclose(np.abs(first.degenerate_axis), [1.0, 0.0], atol=1e-3)
    # A first fit slid 1.2 m along the corridor and 3 cm across it: the longer fit
    # takes back the slide, the 3 cm across stay (the first fit's own figure).
    off = dataclasses.replace(first, relative=first.relative + np.array([1.2, 0.03, 0.0]))
    query = _submap(WORLD, QUERY, -3, 10)
    cand = _submap(WORLD, CANDIDATE, -3, 10)
    second = recheck_longer(off, query, cand, max_distance=2.0, config=CFG)
    assert second.accepted, second.reason
    np.testing.assert_allclose(second.relative, QUERY + np.array([0.0, 0.03, 0.0]), atol=0.02)
    # 0.8 m across the axis: the longer fit is another answer.
    far = dataclasses.replace(first, relative=first.relative + np.array([0.0, 0.8, 0.0]))
    rejected = recheck_longer(far, query, cand, max_distance=2.0, config=CFG)
    assert not rejected.accepted
    assert "longer submaps fit elsewhere (0.80 m across" in rejected.reason


def test_the_longer_submaps_reach_a_path_length_not_a_count_of_keyframes() -> None:
    # Keyframes 0.3 m apart for 20 keyframes (indoors), then 2.5 m apart (outdoors).
    steps = np.r_[np.full(20, 0.3), np.full(20, 2.5)]
    xy = np.c_[np.r_[0.0, np.cumsum(steps)], np.zeros(len(steps) + 1)]
    poses = np.c_[xy, np.zeros(len(xy))]
    by_path = dataclasses.replace(CFG, longer_keyframes=30, longer_path_m=5.0)
    assert trailing_count(poses, 19, by_path) == 17  # 17 x 0.3 m = 5.1 m
    assert trailing_count(poses, 40, by_path) == 2  # 2 x 2.5 m
    assert trailing_count(poses, 3, by_path) == 3  # 0.9 m of path in all: every one
    assert trailing_count(poses, 0, by_path) == 0
    # No path length (or no poses reaching the key): the count of keyframes.
    assert trailing_count(poses, 40, dataclasses.replace(by_path, longer_path_m=0.0)) == 30
    assert trailing_count(None, 40, by_path) == 30
    assert trailing_count(poses[:10], 40, by_path) == 30


def test_the_verdict_is_the_longer_fit_judged_against_the_first() -> None:
    first = _short_check(WORLD)
    off = dataclasses.replace(first, relative=first.relative + np.array([1.2, 0.03, 0.0]))
    query = _submap(WORLD, QUERY, -3, 10)
    cand = _submap(WORLD, CANDIDATE, -3, 10)
    whole = longer_fit(off, query, cand, max_distance=2.0, config=CFG)
    along, across, turn = departure(off, whole)
    # The longer fit takes back the 1.2 m slide along the corridor (x) and the 3 cm
    # across it; the heading is the first fit's.
    assert abs(abs(along) - 1.2) < 0.02 and abs(across - 0.03) < 0.02 and turn < 0.5
    np.testing.assert_allclose(
        judged(off, whole, CFG).relative,
        recheck_longer(off, query, cand, max_distance=2.0, config=CFG).relative)
