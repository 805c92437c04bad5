"""The free-space test about each scan's own origin (`loopclosure.free_space` (1')): the
model by hand, the keyframe store that keeps it, the check that uses it."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.sim import simulate_run
from loopclosure.free_space import (
    SCAN_FREE_SPACE,
    RangeImage,
    ScanFreeSpace,
    Submap,
    SubmapPoints,
    consistency,
)
from loopclosure.geometric_check import GeometricCheckConfig, verify
from loopclosure.loop_config import LoopClosureConfig
from loopclosure.loop_detector import LoopClosureDetector
from loopclosure.registration import RegistrationTarget, voxel_downsample
from tests.test_geometric_check import ROOM, _seen_from, _walls

# -- the model, by hand -------------------------------------------------------------------


def test_a_point_is_free_only_along_the_ray_of_the_scan_that_saw_past_it() -> None:
    # One scan at (4, -2) facing +y saw a return 2 m ahead: (4, 0) in the submap frame.
    pose = np.array([4.0, -2.0, np.pi / 2])
    seen = se2.transform_points(se2.inverse(pose), [[4.0, 0.0]])  # (2, 0) in its frame
    free = ScanFreeSpace.of([pose], [seen], bins=720, spread=2)
    pts = np.array([[4.0, -1.0],   # 1 m along its ray: free
                    [4.0, -0.2],   # within the 0.3 m margin of the return: not
                    [4.0, 1.0],    # behind the return: not
                    [2.0, 0.0]])   # in front of (4, 0) as seen from the submap origin:
    #                                no ray of this scan crossed it
    np.testing.assert_array_equal(free.free(pts, margin=0.3), [True, False, False, False])
    # The model about the origin (1) calls the last one free.
    assert RangeImage([[4.0, 0.0]]).free(pts[3:], margin=0.3).tolist() == [True]


def test_a_point_is_free_when_any_scan_saw_through_it() -> None:
    a, b = np.array([0.0, 0.0, 0.0]), np.array([0.0, 3.0, -np.pi / 2])
    # a sees a wall 5 m ahead along +x; b (3 m up, facing -y) sees the floor 5 m down.
    free = ScanFreeSpace.of([a, b], [[[5.0, 0.0]], [[5.0, 0.0]]])
    pts = np.array([[2.0, 0.0], [0.0, 1.0], [0.0, -1.8], [2.0, 2.0]])
    # (2, 0): a's ray; (0, 1): b's ray (2 m ahead of it); (0, -1.8): b's ray, 4.8 m
    # ahead, inside the margin of its 5 m return; (2, 2): neither ray.
    np.testing.assert_array_equal(free.free(pts, margin=0.3), [True, True, False, False])


def test_one_scan_at_the_origin_is_the_range_image() -> None:
    pts = _seen_from(ROOM, np.array([1.0, 1.0, 0.3]))
    image = RangeImage(pts, 720, 2)
    free = ScanFreeSpace([np.zeros(3)], image.ranges[None])
    probe = np.random.default_rng(0).uniform(-6, 6, (500, 2))
    np.testing.assert_array_equal(free.free(probe, 0.3), image.free(probe, 0.3))
    assert free.ranges.dtype == np.float32 and free.nbytes == 3 * 8 + 720 * 4


def test_no_scans_and_no_points() -> None:
    empty = ScanFreeSpace(np.zeros((0, 3)), np.zeros((0, 720)))
    assert empty.free([[1.0, 0.0]], 0.3).tolist() == [False]
    assert ScanFreeSpace.of([np.zeros(3)], [[[1.0, 0.0]]]).free(np.zeros((0, 2)), 0.3).shape == (0,)


def test_consistency_with_each_scans_rays() -> None:
    """The query and the candidate share a point at (0, -1); the query also sees
    (2, 0), the candidate (4, 0), the latter from a scan at (4, -2) facing it."""
    q_pts = np.array([[2.0, 0.0], [0.0, -1.0]])
    c_pts = np.array([[4.0, 0.0], [0.0, -1.0]])
    # (1): (2, 0) lies before the candidate's (4, 0) seen from its origin: a conflict.
    merged = consistency(Submap.of(q_pts), Submap.of(c_pts), np.zeros(3), 0.1, 0.3)
    assert (merged.hits, merged.conflicts) == (2, 1)
    assert merged.consistency == pytest.approx(2 / 3)
    # (1'): the scan that saw (4, 0) looked along x = 4, not through (2, 0).
    side = np.array([4.0, -2.0, np.pi / 2])
    c_free = ScanFreeSpace.of([side, np.zeros(3)],
                              [se2.transform_points(se2.inverse(side), c_pts[:1]), c_pts[1:]])
    q_free = ScanFreeSpace.of([np.zeros(3)], [q_pts])
    per_scan = consistency(Submap.of(q_pts, scans=q_free), Submap.of(c_pts, scans=c_free),
                           np.zeros(3), 0.1, 0.3)
    assert (per_scan.hits, per_scan.conflicts) == (2, 0)
    assert per_scan.consistency == 1.0


def test_submap_points_carry_their_free_space_through_views_only() -> None:
    free = ScanFreeSpace.of([np.zeros(3)], [[[1.0, 0.0]]])
    pts = SubmapPoints([[1.0, 2.0], [3.0, 4.0]], free)
    assert pts.free_space is free and pts.reshape(-1, 2).free_space is free
    assert pts[:1].free_space is free
    assert not hasattr(np.asarray(pts), "free_space")
    np.testing.assert_array_equal(np.asarray(pts), [[1.0, 2.0], [3.0, 4.0]])


# -- the check ----------------------------------------------------------------------------


def _inner_walls_case():
    """`test_prior_free_check`'s partial match that free space rejects: the query's
    extra walls lie where the candidate, from its origin, saw free space."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.2, 1.0, 0.5])
    inner = _walls([((0.5, 3.5), (2.5, 3.5)), ((4.5, 0.5), (4.5, 2.5)), ((2.5, 0.5), (2.5, 1.2)),
                    ((0.3, 0.4), (1.2, 0.4))])
    cand = _seen_from(ROOM, a)
    query = _seen_from(np.vstack([ROOM[ROOM[:, 1] < 2.5], inner]), b)
    return cand, query, se2.between(a, b)


def test_the_check_uses_the_scans_free_space_when_both_submaps_carry_it() -> None:
    cand, query, truth = _inner_walls_case()
    keyframe = GeometricCheckConfig()
    scans = GeometricCheckConfig(free_space_origins="scans")
    base = verify(query, RegistrationTarget(cand), headings=[truth[2]], config=keyframe)
    assert not base.accepted and base.consistency < keyframe.min_consistency
    # One scan at each origin, its returns the submap: the same figures as (1).
    same = RegistrationTarget(cand)
    # (the images of the points the check tests: the query at `source_voxel`, the
    # candidate at the search's `submap_voxel`)
    c_image = RangeImage(voxel_downsample(cand, scans.search.submap_voxel))
    q_image = RangeImage(voxel_downsample(query, scans.source_voxel))
    same.derived[SCAN_FREE_SPACE] = ScanFreeSpace([np.zeros(3)], c_image.ranges[None])
    q_same = SubmapPoints(query, ScanFreeSpace([np.zeros(3)], q_image.ranges[None]))
    again = verify(q_same, same, headings=[truth[2]], config=scans)
    assert again.consistency == pytest.approx(base.consistency, abs=1e-3)
    # Scans that observed nothing: no conflicts, the hits alone.
    blind = RegistrationTarget(cand)
    blind.derived[SCAN_FREE_SPACE] = ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720)))
    q_blind = SubmapPoints(query, ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720))))
    assert verify(q_blind, blind, headings=[truth[2]], config=scans).consistency == 1.0
    # The default ignores them; a query without them keeps (1).
    assert verify(q_blind, blind, headings=[truth[2]], config=keyframe).consistency == \
        pytest.approx(base.consistency)
    assert verify(query, blind, headings=[truth[2]], config=scans).consistency == \
        pytest.approx(base.consistency)


def test_an_unknown_origin_mode_is_a_user_error() -> None:
    with pytest.raises(UserError, match="free_space_origins"):
        GeometricCheckConfig(free_space_origins="scan")


# -- the keyframe store -------------------------------------------------------------------


def _store(n: int = 4, origins: bool = True) -> tuple[LoopClosureDetector, list]:
    scans = simulate_run("box", seed=0).scans[:n]
    cfg = LoopClosureConfig()
    cfg.check.free_space_origins = "scans"
    det = LoopClosureDetector(cfg, submap=lambda key: scans[key].points())
    if origins:  # submap(key) made of keys key-1 .. key+1, 1 m apart along x
        det.set_submap_origins(lambda key: (
            np.arange(max(0, key - 1), min(n - 1, key + 1) + 1),
            np.array([[j - key, 0.0, 0.0] for j in range(max(0, key - 1),
                                                          min(n - 1, key + 1) + 1)])))
    for key, scan in enumerate(scans):
        det.add_keyframe(key, float(key), scan)
    return det, scans


def test_the_store_keeps_each_scans_ranges_and_gives_a_submaps_scans() -> None:
    det, scans = _store()
    free = det.submap_free_space(2)
    np.testing.assert_allclose(free.poses, [[-1, 0, 0], [0, 0, 0], [1, 0, 0]])
    for row, key in zip(free.ranges, (1, 2, 3), strict=True):
        np.testing.assert_array_equal(row, RangeImage(scans[key].points()).ranges
                                      .astype(np.float32))
    older = det.submap_free_space(2, last=2)  # as it was when 2 was the newest
    np.testing.assert_allclose(older.poses, [[-1, 0, 0], [0, 0, 0]])
    target = det._target(2)
    assert target.derived[SCAN_FREE_SPACE].poses.shape == (3, 3)
    pts = det._submap_points(2)
    assert isinstance(pts, SubmapPoints) and pts.free_space.poses.shape == (3, 3)


def test_the_option_without_the_hosts_origins_is_a_user_error() -> None:
    det, _ = _store(origins=False)
    with pytest.raises(UserError, match="submap_origins"):
        det.submap_free_space(1)


def test_the_default_keeps_nothing_and_hands_plain_points() -> None:
    scans = simulate_run("box", seed=0).scans[:3]
    det = LoopClosureDetector(submap=lambda key: scans[key].points())
    for key, scan in enumerate(scans):
        det.add_keyframe(key, float(key), scan)
    assert det._scan_ranges == []
    assert type(det._submap_points(1)) is np.ndarray
    assert SCAN_FREE_SPACE not in det._target(1).derived


# -- the pipeline's host side ---------------------------------------------------------


def test_the_mapper_gives_each_submaps_scan_origins_and_maps_with_the_option() -> None:
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    run = simulate_run("box", seed=0)
    cfg = PipelineConfig()
    cfg.loops.check.free_space_origins = "scans"
    mapper = Mapper(cfg)
    result = mapper.run(run.scans[:120])
    n = cfg.submap_neighbours()
    key = len(result.keyframes) // 2
    keys, poses = mapper.submap_origins(key)
    np.testing.assert_array_equal(keys, np.arange(key - n, key + n + 1))
    centre = result.keyframes[key].odom_pose
    for j, pose in zip(keys, poses, strict=True):  # each keyframe seen from `key`'s frame
        np.testing.assert_allclose(
            se2.compose(centre, pose), result.keyframes[j].odom_pose, atol=1e-12)
    np.testing.assert_allclose(poses[keys == key], [[0.0, 0.0, 0.0]], atol=1e-12)
    free = mapper.detector.submap_free_space(key)  # the callback the mapper set
    assert free.poses.shape == (len(keys), 3)
    assert len(mapper.detector._scan_ranges) == len(result.keyframes)
