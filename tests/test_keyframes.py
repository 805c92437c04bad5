"""Keyframe selection and per-scan poses blended between keyframes."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.types import Scan
from slam.keyframes import (
    GrowingRows,
    KeyframeConfig,
    KeyframeSelector,
    scan_poses_from_keyframes,
)
from slam.odometry import OdometryEstimate

ANGLES = np.linspace(-np.pi, np.pi, 90, endpoint=False)


def _scan(stamp: float, index: int, valid: bool = True) -> Scan:
    ranges = np.full(90, 3.0 if valid else 0.0)
    return Scan(stamp, ranges, ANGLES, 10.0, 0.0, None, index)


def _estimate(stamp: float, index: int, pose: np.ndarray, prev: np.ndarray) -> OdometryEstimate:
    return OdometryEstimate(
        stamp, index, pose, se2.between(prev, pose), np.eye(3) * 1e-4, 1.0, 0.0, "ok"
    )


def _drive(poses: np.ndarray, config: KeyframeConfig, valid=None) -> KeyframeSelector:
    sel = KeyframeSelector(config)
    prev = poses[0]
    for i, p in enumerate(poses):
        ok = True if valid is None else valid[i]
        sel.push(_scan(float(i), i, ok), _estimate(float(i), i, p, prev))
        prev = p
    return sel


def test_keyframes_by_distance_rotation_and_time() -> None:
    # 0.1 m steps along x: a keyframe every 3 steps (>= 0.29 m), the first scan always.
    poses = np.column_stack([0.1 * np.arange(10), np.zeros(10), np.zeros(10)])
    sel = _drive(poses, KeyframeConfig(distance=0.29, rotation_deg=90, max_interval=0))
    assert [k.scan_index for k in sel.keyframes] == [0, 3, 6, 9]
    np.testing.assert_allclose(sel.keyframes[1].delta, [0.3, 0.0, 0.0], atol=1e-12)
    # Three increments of 0.1 m, each with covariance 1e-4 I: x and theta add up; the
    # heading errors of the first two also swing y by their lever arms (0.2 m, 0.1 m).
    expected = np.array([[3e-4, 0, 0], [0, 3e-4 + 1e-4 * (0.2**2 + 0.1**2), 1e-4 * 0.3],
                         [0, 1e-4 * 0.3, 3e-4]])
    np.testing.assert_allclose(sel.keyframes[1].covariance, expected, atol=1e-12)
    turning = np.column_stack([np.zeros(5), np.zeros(5), np.radians(10.0) * np.arange(5)])
    sel = _drive(turning, KeyframeConfig(distance=1.0, rotation_deg=15, max_interval=0))
    assert [k.scan_index for k in sel.keyframes] == [0, 2, 4]
    still = np.zeros((25, 3))
    sel = _drive(still, KeyframeConfig(distance=1.0, rotation_deg=90, max_interval=10.0))
    assert [k.scan_index for k in sel.keyframes] == [0, 10, 20]


def test_scans_without_enough_beams_never_become_keyframes() -> None:
    poses = np.column_stack([0.5 * np.arange(4), np.zeros(4), np.zeros(4)])
    sel = _drive(poses, KeyframeConfig(distance=0.3), valid=[False, True, False, True])
    assert [k.scan_index for k in sel.keyframes] == [1, 3]
    out = scan_poses_from_keyframes(sel, {0: np.array([0.5, 0, 0]), 1: np.array([1.5, 0, 0])})
    np.testing.assert_allclose(out[:, 0], [0.0, 0.5, 1.0, 1.5], atol=1e-12)


def test_scan_poses_spread_a_correction_between_keyframes() -> None:
    poses = np.column_stack([0.1 * np.arange(7), np.zeros(7), np.zeros(7)])
    sel = _drive(poses, KeyframeConfig(distance=0.29, max_interval=0))
    # Optimisation moves keyframe 1 (at x = 0.3) up by 0.3 m and keyframe 2 by 0.6 m.
    opt = {0: np.array([0.0, 0.0, 0.0]), 1: np.array([0.3, 0.3, 0.0]), 2: np.array([0.6, 0.6, 0])}
    out = scan_poses_from_keyframes(sel, opt)
    # Scan 1 is a third of the way from keyframe 0 to 1: its y is a third of the shift.
    np.testing.assert_allclose(out[1], [0.1, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[3], [0.3, 0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[5], [0.5, 0.5, 0.0], atol=1e-12)
    # After the last keyframe, scans follow it rigidly.
    np.testing.assert_allclose(out[6], [0.6, 0.6, 0.0], atol=1e-12)


def test_unchanged_keyframes_give_the_odometry_back() -> None:
    rng = np.random.default_rng(0)
    steps = np.column_stack([rng.uniform(0, 0.2, 40), rng.normal(0, 0.02, 40),
                             rng.normal(0, 0.1, 40)])
    poses = [np.zeros(3)]
    for s in steps:
        poses.append(se2.compose(poses[-1], s))
    poses = np.array(poses)
    sel = _drive(poses, KeyframeConfig(distance=0.3, rotation_deg=15))
    opt = {k.id: k.odom_pose for k in sel.keyframes}
    out = scan_poses_from_keyframes(sel, opt)
    np.testing.assert_allclose(out[:, :2], poses[:, :2], atol=1e-9)
    assert np.abs(se2.wrap_angle(out[:, 2] - poses[:, 2])).max() == pytest.approx(0, abs=1e-9)


def test_growing_rows_keep_every_row_past_their_capacity() -> None:
    rows = GrowingRows(3, capacity=2)
    for i in range(5):
        rows.append((i, 2 * i, -i))
    assert len(rows) == 5
    np.testing.assert_array_equal(rows.data, [[i, 2 * i, -i] for i in range(5)])


def test_per_scan_rows_are_the_stamps_keyframes_and_offsets() -> None:
    poses = np.column_stack([0.1 * np.arange(7), np.zeros(7), np.zeros(7)])
    sel = _drive(poses, KeyframeConfig(distance=0.29, rotation_deg=90, max_interval=0))
    np.testing.assert_array_equal(sel.scan_stamps, np.arange(7.0))
    np.testing.assert_array_equal(sel.scan_keyframe, [0, 0, 0, 1, 1, 1, 2])
    assert sel.scan_keyframe.dtype == np.int64
    np.testing.assert_allclose(sel.scan_offset[:, 0], [0, 0.1, 0.2, 0, 0.1, 0.2, 0], atol=1e-12)


def test_keyframes_share_equal_bearings_and_keep_different_ones() -> None:
    sel = KeyframeSelector(KeyframeConfig(distance=0.05, rotation_deg=90, max_interval=0))
    prev = np.zeros(3)
    for i in range(3):
        pose = np.array([0.1 * i, 0.0, 0.0])
        scan = Scan(float(i), np.full(90, 3.0), ANGLES.copy(), 10.0, 0.0, None, i)
        sel.push(scan, _estimate(float(i), i, pose, prev))
        prev = pose
    other = Scan(3.0, np.full(90, 3.0), ANGLES + 0.01, 10.0, 0.0, None, 3)
    sel.push(other, _estimate(3.0, 3, np.array([0.3, 0.0, 0.0]), prev))
    kfs = sel.keyframes
    assert len(kfs) == 4
    assert kfs[1].scan.angles is kfs[0].scan.angles and kfs[2].scan.angles is kfs[0].scan.angles
    assert kfs[3].scan.angles is other.angles


def test_a_selector_adopting_anothers_selection_holds_the_same_rows_and_keyframes() -> None:
    # 0.1 m steps: keyframes at scans 0, 3, 6 (>= 0.29 m); each scan with its own copy of
    # the bearings, as scans that crossed a pipe in separate messages have.
    poses = np.column_stack([0.1 * np.arange(7), np.zeros(7), np.zeros(7)])
    config = KeyframeConfig(distance=0.29, rotation_deg=90, max_interval=0)
    pushed, adopted = KeyframeSelector(config), KeyframeSelector(config)
    prev = poses[0]
    for i, p in enumerate(poses):
        scan = Scan(float(i), np.full(90, 3.0), ANGLES.copy(), 10.0, 0.0, None, i)
        made = pushed.push(scan, _estimate(float(i), i, p, prev))
        row = pushed.last_row
        assert row[0] == float(i) and row[1] == [0, 0, 0, 1, 1, 1, 2][i]
        assert row[2] == pytest.approx([0, 0.1, 0.2, 0, 0.1, 0.2, 0][i], abs=1e-12)
        got = adopted.adopt(row, made)
        assert (got is None) == (made is None) and (got is None or got.id == made.id)
        prev = p
    np.testing.assert_array_equal(adopted.scan_stamps, pushed.scan_stamps)
    np.testing.assert_array_equal(adopted.scan_keyframe, [0, 0, 0, 1, 1, 1, 2])
    np.testing.assert_array_equal(adopted.scan_offset, pushed.scan_offset)
    assert [k.scan_index for k in adopted.keyframes] == [0, 3, 6]
    for a, b in zip(adopted.keyframes, pushed.keyframes, strict=True):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.delta, b.delta)
        np.testing.assert_array_equal(a.covariance, b.covariance)
    first = adopted.keyframes[0].scan.angles  # equal bearings shared, as `push` does
    assert all(k.scan.angles is first for k in adopted.keyframes)
    poses_k = {k.id: k.odom_pose for k in pushed.keyframes}
    np.testing.assert_array_equal(scan_poses_from_keyframes(adopted, poses_k),
                                  scan_poses_from_keyframes(pushed, poses_k))


def test_adopting_a_keyframe_out_of_order_is_refused() -> None:
    poses = np.column_stack([0.1 * np.arange(4), np.zeros(4), np.zeros(4)])
    pushed = _drive(poses, KeyframeConfig(distance=0.29, rotation_deg=90, max_interval=0))
    sel = KeyframeSelector()
    with pytest.raises(ValueError, match="keyframe 1 adopted after 0"):
        sel.adopt(pushed.last_row, pushed.keyframes[1])
    assert len(sel.scan_stamps) == 0 and not sel.keyframes
