"""LoopClosureDetector: which keyframes may be candidates, detect in any order, submap
versions."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.sim import simulate_run
from loopclosure import candidate_checks
from loopclosure.geometric_check import LoopVerification
from loopclosure.loop_candidate import LoopCandidate
from loopclosure.loop_config import LoopClosureConfig
from loopclosure.loop_detector import LoopClosureDetector
from loopclosure.place_choice import merge_views
from loopclosure.place_match import PlaceMatch


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
              c.covariance.tolist(), c.predicted_distance, c.prior, c.prefilter_distance,
              c.prefilter_rank, c.fused_score, c.verifier_distances))
        for c in candidates
    ]


def _run(keyframes: list, submap, version=None, hold: int | None = None,
         config: LoopClosureConfig | None = None, poses=None):
    """Add and detect every keyframe in order; with `hold`, add `hold + 1` before
    detecting `hold`.  Returns the detector and the candidates per key."""
    poses = np.array([s.odom for s in keyframes]) if poses is None else poses
    det = LoopClosureDetector(
        config or LoopClosureConfig(free_every=1), submap=submap, submap_version=version
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
    assert any(c.source == "appearance" for c in now[60])  # the appearance search ran
    assert _summary(later[60]) == _summary(now[60])
    assert _summary(later[61]) == _summary(now[61])
    for c in now[60]:  # typed figures of each search
        if c.source == "appearance":
            assert c.prefilter_rank >= 0 and 0.0 <= c.fused_score <= 1.0
            assert set(c.verifier_distances) == set(LoopClosureConfig().database.verifiers)
        else:
            assert c.source == "pose" and c.prefilter_rank == -1 and c.prior
        assert np.isfinite(c.predicted_distance)
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
    first = {c.match: c for c in det.detect(60, poses) if c.source == "appearance"}
    assert first and _summary(list(first.values())) == _summary(
        [c for c in found[60] if c.source == "appearance"]
    )
    cand = next(iter(first))
    points[cand] = points[cand] + np.array([0.4, -0.3])  # the host's submap moved...
    stale = {c.match: c for c in det.detect(60, poses)}
    assert stale[cand].verification.fitness == first[cand].verification.fitness
    version[cand] += 1  # ... and now the host says so
    fresh = {c.match: c for c in det.detect(60, poses)}
    # (The fitness may be the same: the correlative search shifts with the submap.)
    assert not np.allclose(fresh[cand].relative[:2], first[cand].relative[:2], atol=0.1)


# -- the two searches ------------------------------------------------------------------


@pytest.fixture(scope="module")
def revisit():
    """The box world's first 70 keyframes (a revisit from keyframe 59 on), their true
    poses and submaps of 7 keyframes placed by those poses, as the pipeline builds them."""
    run = simulate_run("box", seed=0)
    kfs = run.scans[::README_STEP][:70]
    poses = run.ground_truth.xytheta()[::README_STEP][:70]

    def submap(k: int) -> np.ndarray:
        near = range(max(0, k - 3), min(len(kfs), k + 4))
        return np.vstack([se2.transform_points(se2.between(poses[k], poses[j]),
                                               kfs[j].points()) for j in near])

    return kfs, poses, submap


def test_each_search_proposes_alone_and_a_place_both_propose_is_checked_once(revisit):
    kfs, poses, submap = revisit
    found = {
        mode: _run(kfs, submap, config=LoopClosureConfig(search=mode), poses=poses)[1]
        for mode in ("pose", "appearance", "both")
    }
    sources = {mode: {c.source for cs in f.values() for c in cs} for mode, f in found.items()}
    # With both, a place both searches propose is an appearance candidate; pose
    # candidates appear only where the database missed the place.
    assert sources["pose"] == {"pose"} and sources["appearance"] == {"appearance"}
    assert "appearance" in sources["both"] and sources["both"] <= {"pose", "appearance"}
    for f in found.values():
        for cands in f.values():
            shown = [c.match for c in cands]  # each keyframe checked once, either search
            assert len(set(shown)) == len(shown)
            closed = [c for c in cands if c.accepted]  # one loop per place
            sep = LoopClosureConfig().place_separation
            assert all(
                np.hypot(*(poses[a.match, :2] - poses[b.match, :2])) > sep
                or (a.source == "pose" and abs(a.match - b.match) > 5)
                or (b.source == "pose" and abs(a.match - b.match) > 5)
                for i, a in enumerate(closed) for b in closed[i + 1:])
            assert sum(c.accepted for c in cands) <= LoopClosureConfig().max_loops
            # a place outside the pose gate: appearance only, and never once a place
            # inside the gate was accepted (it would contradict the anchored pose)
            free = [i for i, c in enumerate(cands) if not c.prior]
            assert all(cands[i].source == "appearance" for i in free)
            anchored = [i for i, c in enumerate(cands) if c.prior and c.accepted]
            assert not (free and anchored and min(anchored) < min(free))
    accepted = {m: {k for k, cs in f.items() if any(c.accepted for c in cs)}
                for m, f in found.items()}
    assert accepted["pose"] and accepted["appearance"]
    assert accepted["both"] == accepted["pose"] | accepted["appearance"]


def test_a_revisit_the_odometry_cannot_explain_is_found_by_appearance_alone(revisit):
    """The estimates jump 40 m after keyframe 30 (a kidnap): no older keyframe lies
    inside the pose gate of the revisit, so the pose search is silent, and appearance
    candidates are checked from the database's headings, without a prior."""
    kfs, poses, submap = revisit
    jumped = poses.copy()
    jumped[31:, 0] += 40.0
    _, pose_only = _run(kfs, submap, config=LoopClosureConfig(search="pose"), poses=jumped)
    assert not [c for cs in pose_only.values() for c in cs if c.match <= 30 < c.query]
    _, both = _run(kfs, submap, config=LoopClosureConfig(), poses=jumped)
    across = [c for cs in both.values() for c in cs if c.match <= 30 < c.query]
    assert across and all(c.source == "appearance" and not c.prior for c in across)
    assert all(c.predicted_distance > 30.0 for c in across)
    assert any(c.accepted for c in across)
    # Without the periodic check, only candidates the previous keyframes also proposed
    # are checked; without that support either, none is.
    cfg = LoopClosureConfig(free_every=0)
    _, supported = _run(kfs, submap, config=cfg, poses=jumped)
    assert any(c.accepted for cs in supported.values() for c in cs if c.match <= 30 < c.query)
    cfg = LoopClosureConfig(free_every=0, sequence_keyframes=0)
    _, unsupported = _run(kfs, submap, config=cfg, poses=jumped)
    assert not [c for cs in unsupported.values() for c in cs if c.match <= 30 < c.query]


def test_the_gate_grows_with_sigma_up_to_prior_max_sigma_then_is_empty() -> None:
    det = LoopClosureDetector(LoopClosureConfig(local_radius=1.5, local_sigmas=3.0,
                                                prior_max_sigma=1.5))
    # sigma is the largest standard deviation of the position: sqrt(max eig) of x, y.
    _, sigma, gate = det._gate(np.diag([1.0, 0.25, 0.01]))
    assert sigma == pytest.approx(1.0) and gate == pytest.approx(1.5 + 3.0 * 1.0)
    _, sigma, gate = det._gate(np.diag([0.25, 2.25, 0.01]))  # sigma 1.5: still a prior
    assert sigma == pytest.approx(1.5) and gate == pytest.approx(6.0)
    _, sigma, gate = det._gate(np.diag([4.0, 1.0, 0.01]))  # sigma 2 > 1.5: no prior
    assert sigma == pytest.approx(2.0) and gate == -np.inf
    assert det._gate(None)[2] == pytest.approx(1.5)
    with pytest.raises(UserError, match=r"loops\.prior_max_sigma"):
        LoopClosureConfig(prior_max_sigma=0.0)


def _detect_with_covariance(kfs, submap, poses, config, covariance):
    det = LoopClosureDetector(config, submap=submap)
    found = []
    for key, scan in enumerate(kfs):
        det.add_keyframe(key, scan.stamp, scan)
        found += det.detect(key, poses[: key + 1], covariance)
    return found


def test_a_loose_pose_estimate_is_no_prior(revisit):
    """A position standard deviation above `prior_max_sigma`: the pose search proposes
    nothing, and the appearance candidates are checked as outside the gate."""
    kfs, poses, submap = revisit
    loose = np.diag([4.0, 4.0, 0.01])  # sigma 2 m
    pose_only = LoopClosureConfig(search="pose")
    assert _detect_with_covariance(kfs, submap, poses, pose_only, loose) == []
    wide = dataclasses.replace(pose_only, prior_max_sigma=1e9)  # the old rule: a 7.5 m gate
    gated = _detect_with_covariance(kfs, submap, poses, wide, loose)
    assert gated and all(c.prior for c in gated)
    both = _detect_with_covariance(kfs, submap, poses, LoopClosureConfig(free_every=1), loose)
    assert both and all(c.source == "appearance" and not c.prior for c in both)
    assert any(c.accepted for c in both)


def test_search_values_and_small_databases(keyframes) -> None:
    with pytest.raises(UserError, match=r"loops\.search"):
        LoopClosureConfig(search="global")
    det = LoopClosureDetector(submap=lambda key: keyframes[key].points())
    det.add_keyframe(0, 0.0, keyframes[0])
    assert det.detect(0, np.zeros((1, 3))) == []  # one keyframe: nothing to match


# -- candidates checked with no prior must agree ----------------------------------------


@pytest.mark.parametrize(("second_place", "accepted"), [((0.0, 0.0, 0.0), True),
                                                        ((5.0, 0.0, 0.0), False)])
def test_accepted_places_must_agree_on_where_the_query_is(second_place, accepted) -> None:
    # Three keyframes of one scan: the query (key 2) fits both older places at the
    # identity.  The map puts the two places together (the query is at one spot: both
    # loops stand) or 5 m apart (one of them is a look-alike: both are rejected).
    scan = simulate_run("box", seed=0).scans[40]
    det = LoopClosureDetector(LoopClosureConfig(exclude_recent=0, exclude_recent_s=0.0),
                              submap=lambda key: scan.points())
    for key in range(3):
        det.add_keyframe(key, float(key), scan)
    matches = det.database.query(det.database.descriptors(2), allowed=[0, 1])
    poses = np.array([[0.0, 0.0, 0.0], second_place, [0.0, 0.0, 0.0]])
    out = det.verify_places(2, matches, poses)
    assert [c.match for c in out] == [0, 1]
    np.testing.assert_allclose([c.relative for c in out], 0.0, atol=1e-3)
    assert [c.accepted for c in out] == [accepted, accepted]
    if not accepted:
        assert all(c.reason.startswith("ambiguous places") and "5.0 m" in c.reason for c in out)


def test_distinct_places_skip_keys_within_five_of_one_taken() -> None:
    from loopclosure.place_choice import distinct_places
    from loopclosure.place_match import PlaceMatch

    def match(key: int) -> PlaceMatch:
        return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=0, distances={},
                          score=1.0, headings=(), stamp=0.0, pose=None)

    got = distinct_places([match(k) for k in (10, 14, 16, 30, 12, 40)], 3)
    assert [m.key for m in got] == [10, 16, 30]


def test_distinct_places_by_map_position_keep_a_neighbour_key_far_enough() -> None:
    """With map positions, keys 3 apart 1.5 m apart are two places; 0.5 m apart one;
    another frame is always another place."""
    from loopclosure.place_choice import distinct_places
    from loopclosure.place_match import PlaceMatch

    def match(key: int) -> PlaceMatch:
        return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=0, distances={},
                          score=1.0, headings=(), stamp=0.0, pose=None)

    xy = np.zeros((8, 2))
    xy[:, 0] = [0.0, 0.0, 0.0, 1.5, 0.5, 0.4, 9.0, 0.2]
    got = distinct_places([match(k) for k in (0, 3, 4, 5, 7)], 5, xy, separation=1.0)
    assert [m.key for m in got] == [0, 3]  # 4, 5 within 1 m of 0 (and of 3: 1.0, 1.1)
    frames = [0, 0, 0, 0, 0, 0, 0, 1]
    got = distinct_places([match(k) for k in (0, 7, 4)], 5, xy, frames, separation=1.0)
    assert [m.key for m in got] == [0, 7]
    assert [m.key for m in distinct_places([match(k) for k in (0, 3, 7)], 2, xy)] == [0, 3]


def test_places_check_the_grids_extras_after_the_prefilters_places() -> None:
    """An extra of the grids (prefilter rank >= K) with a higher fused score than every
    place of the K is checked after them, and only when it is a place of its own; the
    K's distinct places are capped at `global_verify`, the extras come on top."""
    det = _detector([float(k) for k in range(12)])
    det.config = dataclasses.replace(det.config, global_verify=2)
    k = det.database.config.top_k

    def match(key: int, score: float, rank: int) -> PlaceMatch:
        return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=rank,
                          distances={}, score=score, headings=())

    poses = np.zeros((12, 3))
    poses[:, 0] = 3.0 * np.arange(12)  # every keyframe a place of its own
    poses[9, 0] = poses[1, 0] + 0.3  # keyframe 9 is keyframe 1's place
    matches = [match(8, 0.95, k), match(9, 0.9, k + 1), match(1, 0.6, 0),
               match(2, 0.5, 1), match(3, 0.4, 2), match(7, 0.3, k + 2)]
    got = [m.key for m in det.places(matches, poses)]
    assert got == [1, 2, 8, 7]  # 3: beyond global_verify; 9: keyframe 1's place
    only_k = [m for m in matches if m.prefilter_rank < k]
    assert [m.key for m in det.places(only_k, poses)] == [1, 2]
    assert det.places([], poses) == []


def test_places_keep_the_prefilters_first_place_in_the_budget() -> None:
    """With `prefilter_first` = 1 the own view's prefilter rank 0 (here the lowest fused
    score) takes the last slot of `global_verify` = 3; the wide view's rank 0 does not
    count; a first place already taken, or the same place as one taken, changes
    nothing; 2 reserves ranks 0 and 1, in rank order after the fused places."""
    det = _detector([float(k) for k in range(12)])
    det.config = dataclasses.replace(det.config, global_verify=3, prefilter_first=1)

    def match(key: int, score: float, rank: int, view: int = 0) -> PlaceMatch:
        return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=rank,
                          distances={}, score=score, headings=(), view=view)

    poses = np.zeros((12, 3))
    poses[:, 0] = 3.0 * np.arange(12)  # every keyframe a place of its own
    poses[6, 0] = poses[2, 0] + 0.5  # keyframe 6 is keyframe 2's place
    matches = [match(1, 0.9, 3), match(2, 0.8, 2), match(3, 0.7, 4), match(4, 0.6, 1),
               match(5, 0.1, 0), match(7, 0.05, 0, view=1)]
    assert [m.key for m in det.places(matches, poses)] == [1, 2, 5]
    det.config = dataclasses.replace(det.config, prefilter_first=2)
    assert [m.key for m in det.places(matches, poses)] == [1, 5, 4]
    det.config = dataclasses.replace(det.config, prefilter_first=0)
    assert [m.key for m in det.places(matches, poses)] == [1, 2, 3]
    det.config = dataclasses.replace(det.config, prefilter_first=1)
    same = [match(1, 0.9, 3), match(2, 0.8, 2), match(3, 0.7, 4), match(6, 0.1, 0)]
    assert [m.key for m in det.places(same, poses)] == [1, 2, 3]  # 6: 2's place
    taken = [match(1, 0.9, 0), match(2, 0.8, 2), match(3, 0.7, 4), match(4, 0.6, 1)]
    assert [m.key for m in det.places(taken, poses)] == [1, 2, 3]
    with pytest.raises(UserError, match="prefilter_first"):
        LoopClosureConfig(prefilter_first=9)


def test_a_negative_place_separation_is_a_user_error() -> None:
    with pytest.raises(UserError, match="place_separation"):
        LoopClosureConfig(place_separation=-1.0)


def test_a_non_positive_agree_distance_is_a_user_error() -> None:
    with pytest.raises(UserError, match="agree_distance"):
        LoopClosureConfig(agree_distance=0.0)


# -- the wide view -------------------------------------------------------------------


def _match(key: int, score: float) -> PlaceMatch:
    return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=0, distances={},
                      score=score, headings=())


def test_merge_views_keeps_each_keyframe_once_at_its_best_view() -> None:
    narrow = [_match(1, 0.9), _match(2, 0.5)]
    wide = [_match(2, 0.7), _match(3, 0.6), _match(1, 0.2)]
    merged = merge_views([narrow, wide])
    assert [(m.key, m.score, m.view) for m in merged] == [
        (1, 0.9, 0), (2, 0.7, 1), (3, 0.6, 1)]
    assert merge_views([narrow]) == [dataclasses.replace(m, view=0) for m in narrow]
    assert merge_views([]) == []


@pytest.fixture(scope="module")
def narrow_keyframes() -> list:
    """Every 4th scan of a 180-degree laser in the simulated box world."""
    return simulate_run("box", seed=0, fov_deg=180.0, beams=181).scans[::README_STEP][:60]


def _trailing(keyframes: list, calls: list):
    def trailing_map(key: int, n: int) -> np.ndarray:
        calls.append(n)
        centre = keyframes[key].odom
        return np.vstack([se2.transform_points(se2.between(centre, keyframes[j].odom),
                                               keyframes[j].points())
                          for j in range(max(0, key - n), key + 1)])
    return trailing_map


def test_a_narrow_sensor_is_described_twice_and_queried_in_both_views(narrow_keyframes):
    calls: list[int] = []
    cfg = LoopClosureConfig(exclude_recent=5, wide_keyframes=12, wide_every=3)
    det = LoopClosureDetector(cfg, submap=lambda k: narrow_keyframes[k].points(),
                              trailing_map=_trailing(narrow_keyframes, calls))
    for key, scan in enumerate(narrow_keyframes):
        det.add_keyframe(key, scan.stamp, scan)
    n = len(narrow_keyframes)
    assert det.wide_database is not None
    # Every third keyframe is described wide; the two after it query with its view.
    assert calls == [12] * len(range(0, n, 3))
    assert det.wide_database.keys == list(range(0, n, 3))
    assert [det.wide_key(k) for k in range(n)] == [k - k % 3 for k in range(n)]
    key = n - 1
    asked = det.wide_key(key)
    assert asked == key - 2
    assert not np.array_equal(det.database.descriptors(asked)["pairs"],
                              det.wide_database.descriptors(asked)["pairs"])
    allowed = np.flatnonzero(det.eligible(key))
    found = det.query_places(key, allowed)
    keys = [int(m.key) for m in found]
    assert len(keys) == len(set(keys)) and set(keys) <= set(allowed.tolist())
    assert {m.view for m in found} <= {0, 1}
    assert [m.score for m in found] == sorted((m.score for m in found), reverse=True)
    wide_allowed = allowed[np.isin(allowed, det.wide_database.keys)]
    per_view = [db.query(db.descriptors(k), allowed=a, headings=False)
                for db, k, a in ((det.database, key, allowed),
                                 (det.wide_database, asked, wide_allowed))]
    best = {}
    for matches in per_view:
        for m in matches:
            best[m.key] = max(best.get(m.key, -1.0), m.score)
    assert {m.key: m.score for m in found} == best
    # Candidates of either view are checked with their own view's headings.
    checked = det.verify_places(key, det.places(found, [s.odom for s in narrow_keyframes]),
                                [s.odom for s in narrow_keyframes])
    assert checked and all(c.source == "appearance" for c in checked)


def test_no_wide_view_without_a_trailing_map_or_for_a_full_circle(
        narrow_keyframes, keyframes) -> None:
    off = LoopClosureDetector(LoopClosureConfig(wide_keyframes=0),
                              submap=lambda k: narrow_keyframes[k].points(),
                              trailing_map=_trailing(narrow_keyframes, []))
    assert off.wide_database is None
    calls: list[int] = []
    full = LoopClosureDetector(LoopClosureConfig(), submap=lambda k: keyframes[k].points(),
                               trailing_map=_trailing(keyframes, calls))
    for key, scan in enumerate(keyframes[:10]):
        full.add_keyframe(key, scan.stamp, scan)
    assert calls == [] and len(full.wide_database) == 0
    assert all(len(full.views(k)) == 1 for k in range(10))
    with pytest.raises(UserError, match="wide_keyframes"):
        LoopClosureConfig(wide_keyframes=-1)
    with pytest.raises(UserError, match="wide_every"):
        LoopClosureConfig(wide_every=0)


def _verdict(accepted: bool, reason: str, relative) -> LoopVerification:
    return LoopVerification(accepted=accepted, reason=reason,
                            relative=np.asarray(relative, float), covariance=np.eye(3),
                            fitness=0.5, inlier_ratio=0.5, rms=0.01, degeneracy=0.2,
                            margin=0.3, hypotheses=1)


def test_a_check_that_fits_beyond_a_revisit_is_repeated_at_the_nearest_keyframe(
        narrow_keyframes, monkeypatch) -> None:
    det = LoopClosureDetector(LoopClosureConfig(exclude_recent=1, exclude_recent_s=0.0),
                              submap=lambda k: narrow_keyframes[k].points())
    for key, scan in enumerate(narrow_keyframes[:12]):
        det.add_keyframe(key, scan.stamp, scan)
    poses = np.zeros((12, 3))
    poses[:, 0] = np.arange(12) * 0.8  # keyframes 0.8 m apart along x
    poses[5] = [4.0, 0.0, 0.5]
    calls = []

    def fake_verify(query_points, target, prior=None, headings=None, translation=None,
                    **kwargs):
        assert prior is None  # both checks are prior-free, judged alike
        calls.append((list(headings), None if translation is None else list(translation)))
        if len(calls) == 1:  # the appearance check of keyframe 2: 2.5 m beyond it
            return _verdict(False, "not a revisit (2.5 m apart)", [2.5, 0.0, 0.1])
        return _verdict(True, "accepted", [*translation, headings[0]])

    monkeypatch.setattr(candidate_checks, "verify", fake_verify)
    (cand,) = det.verify_places(11, [_match(2, 0.9)], poses)
    # The query is at (1.6 + 2.5, 0, 0.1): keyframe 5 at (4.0, 0, 0.5) is the nearest;
    # its check searches about the heading and translation that position implies.
    implied = se2.between(poses[5], [4.1, 0.0, 0.1])
    assert cand.accepted and cand.match == 5
    np.testing.assert_allclose(calls[1][0], [implied[2]])
    np.testing.assert_allclose(calls[1][1], implied[:2])
    np.testing.assert_allclose(cand.relative, implied)
    # A keyframe 1.2 m from where the query is (beyond place_separation, within
    # max_distance) is re-checked too.
    calls.clear()
    moved = poses.copy()
    moved[5] = [4.1, 1.2, 0.5]
    moved[[4, 6]] += [0.0, 5.0, 0.0]
    (cand,) = det.verify_places(11, [_match(2, 0.9)], moved)
    assert cand.accepted and cand.match == 5 and len(calls) == 2
    # Nothing within max_distance of where the query is: the verdict stands.
    calls.clear()
    (far,) = det.verify_places(11, [_match(2, 0.9)], poses + [[0.0, 5.0, 0.0]] * (
        np.arange(12)[:, None] != 2))
    assert not far.accepted and far.match == 2 and len(calls) == 1
    # Keyframe 5 not allowed (a benchmark's keyframe without a reference pose): the
    # nearest allowed one, keyframe 6 at 0.7 m from where the query is, is re-checked.
    calls.clear()
    (cand,) = det.verify_places(11, [_match(2, 0.9)], poses,
                                allowed=[k for k in range(12) if k != 5])
    assert cand.accepted and cand.match == 6 and len(calls) == 2


def test_trail_joins_the_answers_of_keyframes_near_the_query(keyframes) -> None:
    """Keyframe 5 asks with its own matches and the answer of keyframe 4 (1 m behind it),
    not of keyframe 3 (2 m: beyond `trail_radius`); a keyframe answered twice counts at its
    best score; a trail's wide-view matches and keys not allowed stay out."""
    from loopclosure.place_match import PlaceMatch

    det = LoopClosureDetector(LoopClosureConfig(trail_radius=1.5, trail_keyframes=10),
                              submap=lambda key: keyframes[key].points())
    for key in range(6):
        det.add_keyframe(key, float(key), keyframes[key])

    def match(key: int, score: float, view: int = 0) -> PlaceMatch:
        return PlaceMatch(key=key, prefilter_distance=0.0, prefilter_rank=0, distances={},
                          score=score, headings=(), view=view)

    poses = np.array([[9.0, 9.0, 0.0]] * 3 + [[2.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    own = [match(2, 0.6), match(0, 0.5)]
    answers = {3: [match(1, 0.99)], 4: [match(0, 0.9), match(1, 0.95, view=1), match(2, 0.1)]}
    got = det.with_trail(5, own, poses, answers, allowed=[0, 1, 2])
    trail_view = len(det.views(5)) - 1
    assert [(m.key, m.score, m.view) for m in got] == [(0, 0.9, trail_view), (2, 0.6, 0)]
    assert det.views(5)[trail_view] == (det.database, 4)
    got = det.with_trail(5, own, poses, answers, allowed=[2])
    assert [(m.key, m.view) for m in got] == [(2, 0), (0, 0)]
    off = LoopClosureDetector(LoopClosureConfig(trail_radius=0.0),
                              submap=lambda key: keyframes[key].points())
    for key in range(6):
        off.add_keyframe(key, float(key), keyframes[key])
    assert off.with_trail(5, own, poses, answers) is own


def test_per_view_calibration_scores_the_wide_view_by_its_own_model(narrow_keyframes) -> None:
    from loopclosure.place_config import DEFAULT_LOGISTIC, WIDE_LOGISTIC, PlaceDatabaseConfig

    shared = LoopClosureConfig(exclude_recent=5, wide_keyframes=12, wide_every=3)
    per_view = dataclasses.replace(shared, view_calibration="per-view")
    assert shared.wide_database is shared.database
    assert per_view.wide_database.logistic == WIDE_LOGISTIC
    assert per_view.database.logistic == DEFAULT_LOGISTIC
    dets = [LoopClosureDetector(c, submap=lambda k: narrow_keyframes[k].points(),
                                trailing_map=_trailing(narrow_keyframes, []))
            for c in (shared, per_view)]
    for det in dets:
        for key, scan in enumerate(narrow_keyframes):
            det.add_keyframe(key, scan.stamp, scan)
    key = len(narrow_keyframes) - 1
    allowed = np.flatnonzero(dets[0].eligible(key))
    wide_allowed = allowed[np.isin(allowed, dets[0].wide_database.keys)]
    a, b = (d.wide_database.query_stored(d.wide_key(key), allowed=wide_allowed) for d in dets)
    # The same candidates and distances; the score is the wide model's probability.
    assert [m.key for m in a] == sorted([m.key for m in b], key=[m.key for m in a].index)
    scales = dets[1].wide_database.scales
    for m in b:
        d = [[m.distances[s] for s in WIDE_LOGISTIC.names]]
        expected = WIDE_LOGISTIC.score(d, [scales[s] for s in WIDE_LOGISTIC.names])[0]
        assert m.score == pytest.approx(expected)
    # The own view is untouched.
    own = [d.database.query(d.database.descriptors(key), allowed=allowed, headings=False)
           for d in dets]
    assert [(m.key, m.score) for m in own[0]] == [(m.key, m.score) for m in own[1]]
    with pytest.raises(UserError, match="view_calibration"):
        LoopClosureConfig(view_calibration="best")
    with pytest.raises(UserError, match="per-view"):
        LoopClosureConfig(view_calibration="per-view",
                          database=PlaceDatabaseConfig(fusion="rank"))


def test_checks_from_a_prior_keep_one_lazy_grid_per_submap_version() -> None:
    """`_prior_grid` builds a candidate's grid once per submap version and drops it with
    the other caches."""
    import numpy as np

    from loopclosure.loop_detector import LoopClosureDetector

    version = {"v": 0}
    pts = np.column_stack([np.linspace(0, 3, 200), np.zeros(200)])
    det = LoopClosureDetector(submap=lambda key: pts, submap_version=lambda key: version["v"])
    first = det._prior_grid(0)
    assert first is not None and det._prior_grid(0) is first
    version["v"] = 1
    second = det._prior_grid(0)
    assert second is not first and det._prior_grid(0) is second
    det.release_caches()
    assert det._prior_grid(0) is not second


def test_a_pair_joined_by_the_previous_keyframes_loop_is_not_checked_again(revisit) -> None:
    kfs, poses, submap = revisit
    _, every = _run(kfs, submap, config=LoopClosureConfig(search="pose"), poses=poses)
    _, joined = _run(kfs, submap, poses=poses,
                     config=LoopClosureConfig(search="pose", joined_keyframes=1))
    accepted = {k: [c.match for c in cs if c.accepted and c.prior] for k, cs in every.items()}
    assert sum(map(bool, accepted.values())) >= 4  # a revisit of several keyframes
    for key in sorted(joined):
        checked = [c.match for c in joined[key] if c.prior]
        before = [c.match for c in joined.get(key - 1, []) if c.accepted and c.prior]
        # Never a candidate within one key of what the previous keyframe joined ...
        assert not any(abs(c - b) <= 1 for c in checked for b in before)
        # ... and the same checks as without the rule when the previous joined nothing.
        if not before:
            assert checked == [c.match for c in every[key] if c.prior]
    # Along the revisit the loops then alternate: checked, skipped, checked.
    with_loop = [k for k, cs in joined.items() if any(c.accepted for c in cs)]
    assert with_loop and all(b - a >= 2 for a, b in itertools.pairwise(with_loop))
    with pytest.raises(UserError):
        LoopClosureConfig(joined_keyframes=-1)
