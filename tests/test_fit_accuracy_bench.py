"""The fit-accuracy and consistency-diagnosis benchmark scripts' own figures, on
hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.free_space import RangeImage
from tests.helpers import load_benchmark


def test_split_error_projects_on_the_weak_axis_and_its_left_normal() -> None:
    split = load_benchmark("fit_accuracy").split_error
    # reference 0.3 m further along x and 0.1 m to the left (+y) than the fit
    along, across, turn = split(np.array([1.3, 0.1, np.radians(1.0)]),
                                np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0]))
    assert along == pytest.approx(0.3) and across == pytest.approx(0.1)
    assert turn == pytest.approx(1.0)
    # the same error on an axis along y: along 0.1, across -0.3 (left of +y is -x)
    along, across, _ = split(np.array([1.3, 0.1, 0.0]), np.array([1.0, 0.0, 0.0]),
                             np.array([0.0, 1.0]))
    assert along == pytest.approx(0.1) and across == pytest.approx(-0.3)


def test_split_error_wraps_the_heading() -> None:
    split = load_benchmark("fit_accuracy").split_error
    _, _, turn = split(np.array([0.0, 0.0, np.radians(179.0)]),
                       np.array([0.0, 0.0, np.radians(-179.0)]), np.array([1.0, 0.0]))
    assert turn == pytest.approx(-2.0)


def test_maker_tells_the_own_scan_from_another_keyframes_points() -> None:
    maker = load_benchmark("consistency_diagnosis").maker
    # own scan: a wall 5 m ahead (+x); another keyframe's point 2 m behind (-x)
    pts = np.array([[5.0, 0.0], [-2.0, 0.0]])
    own = np.array([True, False])
    image = RangeImage(pts, bins=720)
    where = np.array([[3.0, 0.0], [-1.0, 0.0]])
    assert maker(image, pts, own, where).tolist() == [True, False]


def test_decompose_counts_a_point_in_front_of_a_wall_as_a_far_conflict() -> None:
    bench = load_benchmark("consistency_diagnosis")
    wall = np.column_stack([np.full(41, 5.0), np.linspace(-2, 2, 41)])
    q_pts = np.vstack([wall, [[3.0, 0.0]]])  # one stray point 2 m before the wall
    c_pts = wall.copy()
    fig = bench.decompose(q_pts, np.zeros(len(q_pts), int), 0, c_pts,
                          np.ones(len(c_pts), int), 1, np.zeros(3), 0.1, 0.3, 720)
    assert fig["hits"] == 82 and fig["conflicts"] == 1
    assert fig["q_in_c_conf"] == 1 and fig["q_in_c_conf_near"] == 0
    assert fig["q_in_c_conf_own_made"] == 1 and fig["c_in_q_conf"] == 0
    assert fig["consistency"] == pytest.approx(82 / 83) and fig["own"] == pytest.approx(82 / 83)


def test_union_free_uses_each_scans_own_origin() -> None:
    bench = load_benchmark("consistency_diagnosis")
    # a scan at the origin sees a wall 5 m ahead; a second scan 10 m ahead (facing
    # +x) sees a wall 2 m ahead of it, at x = 12
    first = (np.zeros(3), RangeImage(np.array([[5.0, 0.0]]), 720))
    second = (np.array([10.0, 0.0, 0.0]), RangeImage(np.array([[2.0, 0.0]]), 720))
    pts = np.array([[3.0, 0.0], [8.0, 0.0], [11.0, 0.0]])
    # 3: before the first wall; 8: behind it and behind the second scan (unseen by
    # both); 11: before the second scan's wall
    assert bench.union_free([first, second], pts, 0.3).tolist() == [True, False, True]


class _Keyframe:
    def __init__(self, pose, points):
        self.odom_pose = np.asarray(pose, float)
        self.points = np.asarray(points, float)


class _Mapper:
    """Two keyframes 1 m apart along x, each seeing one point 1 m ahead."""

    def __init__(self):
        self.kfs = [_Keyframe([0.0, 0.0, 0.0], [[1.0, 0.0]]),
                    _Keyframe([1.0, 0.0, 0.0], [[1.0, 0.0]])]

    def _keyframe(self, key):
        return self.kfs[key]


def test_labelled_names_the_keyframe_that_saw_each_point() -> None:
    bench = load_benchmark("consistency_diagnosis")
    # in keyframe 0's frame: keyframe 0's point at x = 1, keyframe 1's at x = 2
    got = bench.labelled(_Mapper(), 0, 0, 1, np.array([[2.02, 0.0], [0.98, 0.0]]))
    assert got.tolist() == [1, 0]


def test_scans_of_gives_each_scan_its_pose_in_the_keys_frame() -> None:
    bench = load_benchmark("consistency_diagnosis")
    scans = bench.scans_of(_Mapper(), 1, 0, 1, 720)
    assert np.allclose(scans[0][0], [-1.0, 0.0, 0.0]) and np.allclose(scans[1][0], 0.0)
    # in keyframe 1's frame keyframe 0 (at x = -1) saw free space up to x = -0.3, keyframe
    # 1 up to x = 0.7 (the 0.3 m margin): x = -0.5 lies in keyframe 0's, x = 0.5 in
    # keyframe 1's; x = 0.8 within the margin of both walls
    assert bench.union_free(scans, np.array([[-0.5, 0.0], [0.5, 0.0]]), 0.3).tolist() == [
        True, True]
    assert bench.union_free(scans, np.array([[0.8, 0.0]]), 0.3).tolist() == [False]


def test_multi_consistency_counts_conflicts_in_any_scans_free_space() -> None:
    from loopclosure.free_space import Submap

    bench = load_benchmark("multi_origin_consistency")
    wall = np.column_stack([np.full(21, 5.0), np.linspace(-1, 1, 21)])
    cand = Submap.of(wall)
    # the query: the same wall plus a stray point at x = 2 (before the wall)
    query = Submap.of(np.vstack([wall, [[2.0, 0.0]]]))
    seen_from_origin = [(np.zeros(3), RangeImage(wall, 720))]
    # a scan 4 m behind the wall's side, seeing nothing towards x = 2: no conflict
    seen_elsewhere = [(np.array([0.0, 10.0, 0.0]), RangeImage(np.array([[1.0, 0.0]]), 720))]
    got = bench.multi_consistency(query, cand, np.zeros(3), q_scans=seen_from_origin,
                                  c_scans=seen_from_origin)
    assert (got.hits, got.conflicts) == (42, 1)
    got = bench.multi_consistency(query, cand, np.zeros(3), q_scans=seen_from_origin,
                                  c_scans=seen_elsewhere)
    assert (got.hits, got.conflicts) == (42, 0)
