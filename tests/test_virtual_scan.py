"""360-degree virtual scans from map points, from scans and from occupancy grids."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from data import se2
from data.errors import DataWarning, UserError
from data.sim import LaserModel, trace
from data.types import Scan
from loopclosure.polygon import polygon_from_scan
from loopclosure.virtual_scan import (
    VirtualScanConfig,
    local_map_points,
    virtual_angles,
    virtual_scan,
    virtual_scan_from_grid,
    virtual_scan_from_scans,
)
from slam.occupancy_map import OccupancyGrid, build_occupancy_grid
from tests.helpers import shared_file

STEP = 2 * np.pi / 360


def loop_segments(*loops) -> np.ndarray:
    """``(S, 2, 2)`` segments of closed polylines."""
    loops = [np.asarray(lp, dtype=float) for lp in loops]
    return np.concatenate([np.stack([lp, np.roll(lp, -1, axis=0)], axis=1) for lp in loops])


# A 6 m x 4 m room with a box standing in it (occlusions on both sides).
ROOM = loop_segments(
    [[0, 0], [6, 0], [6, 4], [0, 4]],
    [[3.5, 2.5], [4.2, 2.5], [4.2, 3.1], [3.5, 3.1]],
)
POSE = np.array([2.0, 1.5, 0.3])


def true_scan(segments, pose, beams=360, max_range=25.0) -> np.ndarray:
    """Exact 360-degree ranges at `pose` (misses read `max_range`)."""
    r = trace(segments, np.asarray(pose)[None], -np.pi, 2 * np.pi / beams, beams, max_range)[0]
    return np.where(np.isfinite(r), r, max_range)


def half_scans(segments, pose, beams=361, noise=0.0, seed=0):
    """Two 180-degree scans at `pose`, looking forward and backward, and their poses."""
    laser = LaserModel(fov_deg=180, beams=beams, max_range=25.0, noise_sigma=noise, dropout=0.0)
    poses = np.array([pose, se2.compose(pose, [0.0, 0.0, np.pi])])
    r = trace(segments, poses, laser.angle_min, laser.angle_increment, beams, 25.0)
    r = np.where(np.isfinite(r), r, 25.0)
    if noise:
        hit = r < 25.0
        r[hit] += np.random.default_rng(seed).normal(0, noise, hit.sum())
    return [laser.scan(ri, stamp=0.0) for ri in r], poses


# ------------------------------------------------------------------ virtual_scan (points)


def test_beam_layout_is_the_360_degree_layout_of_the_simulator():
    np.testing.assert_allclose(virtual_angles(360), LaserModel(beams=360).angles())
    s = virtual_scan(np.array([[1.0, 0.0]]), beams=8)
    np.testing.assert_allclose(s.angles, -np.pi + np.arange(8) * np.pi / 4)
    assert s.fov == pytest.approx(2 * np.pi)


def test_circle_of_points_reads_its_radius_on_every_beam():
    a = np.linspace(-np.pi, np.pi, 3600, endpoint=False) + 0.0123
    pts = 2.0 * np.column_stack([np.cos(a), np.sin(a)])
    s = virtual_scan(pts)
    assert np.all(s.valid)
    # The two points joined across each beam lie up to lateral_tol (5 cm) to its sides:
    # the chord between them sags by at most tol^2 / (2 r) = 0.6 mm towards the sensor.
    assert np.all(s.ranges <= 2.0 + 1e-12)
    np.testing.assert_allclose(s.ranges, 2.0, atol=0.05**2 / (2 * 2.0) + 1e-6)
    # Without the tolerance the chord spans at most the beam's bin (+-0.5 degree).
    bin_sag = 2.0 * (1.0 - math.cos(STEP / 2))
    np.testing.assert_allclose(virtual_scan(pts, lateral_tol=0.0).ranges, 2.0, atol=bin_sag + 1e-9)


def test_single_point_reads_its_along_beam_distance_in_its_bin_only():
    # A point at 1 m, 0.3 degrees off beam 180 (bearing 0): lateral offset 5.2 mm.
    phi = math.radians(0.3)
    s = virtual_scan(np.array([[math.cos(phi), math.sin(phi)]]), lateral_tol=0.0)
    hit = np.flatnonzero(s.valid)
    assert hit.tolist() == [180]
    assert s.ranges[180] == pytest.approx(math.cos(phi))
    assert np.all(s.ranges[np.arange(360) != 180] == s.max_range)
    # With a 2 cm lateral tolerance it also reaches the neighbour beam (0.7 degrees away:
    # 12 mm laterally), and no farther.
    s = virtual_scan(np.array([[math.cos(phi), math.sin(phi)]]), lateral_tol=0.02)
    assert np.flatnonzero(s.valid).tolist() == [180, 181]
    assert s.ranges[181] == pytest.approx(math.cos(math.radians(0.7)))


def test_wall_between_two_points_is_interpolated_exactly():
    # Two points of the wall x = 2, on either side of beam 180 (bearing 0).
    pts = np.array([[2.0, -0.012], [2.0, 0.013]])
    s = virtual_scan(pts, lateral_tol=0.05)
    assert s.ranges[180] == pytest.approx(2.0, abs=1e-12)


def test_nearer_surface_hides_the_one_behind():
    wall = np.column_stack([np.full(400, 5.0), np.linspace(-5, 5, 400)])
    post = np.column_stack([np.full(40, 2.0), np.linspace(-0.2, 0.2, 40)])
    s = virtual_scan(np.vstack([wall, post]), lateral_tol=0.0)
    blocked = np.abs(s.angles) < math.atan2(0.19, 2.0)
    assert blocked.sum() == 11
    np.testing.assert_allclose(s.ranges[blocked], 2.0 / np.cos(s.angles[blocked]), atol=1e-9)
    beside = (np.abs(s.angles) > math.atan2(0.25, 2.0)) & (np.abs(s.angles) < math.atan2(5, 5))
    np.testing.assert_allclose(s.ranges[beside], 5.0 / np.cos(s.angles[beside]), rtol=1e-4)


def test_narrow_gaps_are_filled_and_wide_gaps_stay_open():
    a = np.radians(np.arange(-180.0, 180.0, 0.25)) + 1e-3
    r = 3.0 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a)))  # a 6 m x 6 m square room
    pts = r[:, None] * np.column_stack([np.cos(a), np.sin(a)])
    narrow = (a > np.radians(10)) & (a < np.radians(13))  # 3 degrees missing
    wide = (a > np.radians(100)) & (a < np.radians(120))  # 20 degrees missing
    s = virtual_scan(pts[~(narrow | wide)], max_gap_deg=5.0)
    deg = np.degrees(s.angles)
    in_narrow = (deg > 10.1) & (deg < 12.9)
    assert in_narrow.sum() >= 2
    # Filled on the segment between the gap's neighbours, which are themselves
    # estimated from points on one side only (within a few mm of the wall).
    np.testing.assert_allclose(s.ranges[in_narrow], 3.0 / np.cos(s.angles[in_narrow]), atol=0.01)
    in_wide = (deg > 101) & (deg < 119)
    assert np.all(s.ranges[in_wide] == s.max_range)


def test_depth_jump_is_not_bridged():
    # Near wall on the right half, far wall on the left, a 3-degree gap between them.
    a = np.radians(np.arange(-60.0, 60.0, 0.5)) + 1e-3
    gap = (a > 0) & (a < np.radians(3))
    r = np.where(a < 0, 2.0, 6.0)
    pts = (r[:, None] * np.column_stack([np.cos(a), np.sin(a)]))[~gap]
    s = virtual_scan(pts, max_gap_deg=5.0, lateral_tol=0.0)
    deg = np.degrees(s.angles)
    assert np.all(s.ranges[(deg > 0.6) & (deg < 2.4)] == s.max_range)


def test_virtual_scan_of_two_opposite_half_scans_equals_the_true_360_degree_scan():
    scans, poses = half_scans(ROOM, POSE)
    pts = local_map_points(scans, poses, POSE)
    got = virtual_scan(pts, beams=360, max_range=25.0).ranges
    want = true_scan(ROOM, POSE)
    err = np.abs(got - want)
    # Exact up to the sampling of the half scans: corners and the box's edges.
    assert np.percentile(err, 95) < 0.005
    assert err.max() < 0.05


def test_same_with_noisy_half_scans():
    scans, poses = half_scans(ROOM, POSE, noise=0.01)
    got = virtual_scan(local_map_points(scans, poses, POSE)).ranges
    err = np.abs(got - true_scan(ROOM, POSE, max_range=30.0))
    assert np.median(err) < 0.01
    assert np.percentile(err, 95) < 0.03
    assert err.max() < 0.1


def test_virtual_scan_becomes_a_polygon_without_the_origin_vertex():
    scans, poses = half_scans(ROOM, POSE)
    s = virtual_scan(local_map_points(scans, poses, POSE), max_range=25.0)
    poly = polygon_from_scan(s)
    assert not np.any(np.all(np.abs(poly.vertices) < 1e-9, axis=1))
    # The visible room: 24 m^2 minus the box and the part of the room it hides.
    assert 20.0 < poly.area < 24.0 - 0.7 * 0.6


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.8, 5.2), st.floats(0.8, 3.2), st.floats(-np.pi, np.pi), st.integers(-180, 179)
)
def test_rotating_the_map_by_whole_beams_rolls_the_scan(x, y, theta, k):
    assume(not (3.3 < x < 4.4 and 2.3 < y < 3.3))  # not in or next to the box
    pose = np.array([x, y, theta])
    scans, poses = half_scans(ROOM, pose)
    pts = local_map_points(scans, poses, pose)
    rot = se2.transform_points([0.0, 0.0, k * STEP], pts)
    a = virtual_scan(pts).ranges
    b = virtual_scan(rot).ranges
    same = np.isclose(np.roll(a, k), b, atol=1e-6)
    assert same.mean() > 0.97  # beams at bin edges may flip between neighbours


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 3000), st.sampled_from([36, 180, 360]))
def test_compiled_candidates_give_the_numpy_scan(seed, n, beams):
    """The numba candidates and front-most search equal the numpy sort exactly, ties
    (repeated points, points on a beam) and points near the sensor included."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-12.0, 12.0, (n, 2))
    pts[: n // 5] = np.round(pts[: n // 5])  # repeated points and points on beams
    pts[n // 5 : n // 4] *= 0.01  # close to the sensor: wide candidate fans
    fast = virtual_scan(pts, beams, 10.0)
    slow = virtual_scan(pts, beams, 10.0, compiled=False)
    np.testing.assert_array_equal(fast.ranges, slow.ranges)


def test_compiled_front_most_keeps_the_first_of_equal_candidates():
    """Hand-made: two points at the same along-beam distance on one beam side keep the
    first one's index; the nearer point wins otherwise; beams wrap modulo their count."""
    from loopclosure.virtual_scan_kernel import candidates, front_most

    pos = np.array([0.2, 0.2, 3.9, -0.3])  # beam units
    half = np.full(4, 0.5)
    pid, beam, dphi = candidates(pos, half, STEP)
    assert pid.tolist() == [0, 1, 2, 3] and beam.tolist() == [0, 0, 4, 0]
    np.testing.assert_allclose(dphi, [-0.2 * STEP, -0.2 * STEP, 0.1 * STEP, 0.3 * STEP])
    along = np.array([2.0, 2.0, 1.0, 3.0])
    best_pt, best_along, best_off = front_most(pid, beam - 4, dphi, along, 4)  # wraps
    # Row 2 j + side: on beam 0, side 1 (points counter-clockwise of it) holds points 0
    # and 1 at 2.0 m (the first kept), side 0 points 2 (1.0 m) and 3 (3.0 m).
    assert best_pt.tolist() == [2, 0, -1, -1, -1, -1, -1, -1]
    assert best_along[:2].tolist() == [1.0, 2.0] and np.isinf(best_along[2:]).all()
    assert best_off[0] == pytest.approx(0.1 * STEP) and best_off[1] == pytest.approx(0.2 * STEP)


def test_config_kwargs_and_bad_input():
    cfg = VirtualScanConfig(beams=90, max_range=10.0)
    s = virtual_scan(np.array([[1.0, 0.0], [0.0, 1.0]]), **cfg.kwargs())
    assert len(s.ranges) == 90 and s.max_range == 10.0
    empty = virtual_scan(np.zeros((0, 2)), stamp=3.5, index=7, odom=[1.0, 2.0, 0.5])
    assert np.all(empty.ranges == empty.max_range) and not empty.valid.any()
    assert (empty.stamp, empty.index) == (3.5, 7) and empty.odom.tolist() == [1.0, 2.0, 0.5]
    with pytest.warns(DataWarning, match="1 non-finite"):
        s = virtual_scan(np.array([[1.0, 0.0], [np.nan, 1.0]]))
    assert np.all(np.isfinite(s.ranges)) and s.valid.sum() >= 1
    far = virtual_scan(np.array([[40.0, 0.0], [0.01, 0.0]]), max_range=30.0)
    assert not far.valid.any()  # beyond max range, inside min range
    for bad in ({"beams": 2}, {"max_range": 0.0}, {"min_range": -1.0}, {"lateral_tol": -0.1}):
        with pytest.raises(UserError):
            virtual_scan(np.zeros((1, 2)) + 1.0, **bad)


# ------------------------------------------------------------------ virtual_scan_from_scans


def test_from_scans_of_two_opposite_half_scans_equals_the_true_scan():
    scans, poses = half_scans(ROOM, POSE)
    got = virtual_scan_from_scans(scans, poses, POSE, max_range=25.0)
    err = np.abs(got.ranges - true_scan(ROOM, POSE))
    assert np.percentile(err, 95) < 0.002
    assert err.max() < 0.05
    np.testing.assert_array_equal(got.odom, POSE)


def test_from_scans_does_not_see_through_a_sparsely_sampled_wall():
    # A wall at 3 m sampled every 4 degrees, 10 m wall behind it sampled densely: the
    # point rule sees the far wall between the samples, the segment rule does not.
    near_a = np.radians(np.arange(-40.0, 40.1, 4.0))
    far_a = np.radians(np.arange(-60.0, 60.1, 0.25))
    near = Scan(0.0, 3.0 / np.cos(near_a), near_a, max_range=25.0)
    far = Scan(0.0, 10.0 / np.cos(far_a), far_a, max_range=25.0)
    poses = np.zeros((2, 3))
    inside = np.abs(virtual_angles(360)) < np.radians(38)
    seg = virtual_scan_from_scans([near, far], poses, np.zeros(3), link_dist=0.5).ranges
    np.testing.assert_allclose(seg[inside], 3.0 / np.cos(virtual_angles(360)[inside]), atol=1e-9)
    pts = virtual_scan(local_map_points([near, far], poses, np.zeros(3)), max_gap_deg=0).ranges
    assert np.mean(pts[inside] > 5.0) > 0.5


def test_from_scans_with_no_scans_or_bad_poses():
    s = virtual_scan_from_scans([], np.zeros((0, 3)), np.zeros(3))
    assert not s.valid.any()
    scans, poses = half_scans(ROOM, POSE)
    poses[1] = np.nan  # the backward scan is lost: only the front half remains
    s = virtual_scan_from_scans(scans, poses, POSE)
    front = np.abs(se2.wrap_angle(s.angles)) < np.radians(85)
    assert s.valid[front].all() and not s.valid[np.abs(s.angles) > np.radians(95)].any()
    with pytest.raises(UserError, match="one pose per scan"):
        virtual_scan_from_scans(scans, poses[:1], POSE)


# ------------------------------------------------------------------ virtual_scan_from_grid


def test_grid_ray_marching_hand_checked():
    # 1 x 20 grid of 0.1 m cells from x = 0; one occupied cell, col 12 (x in [1.2, 1.3)).
    hits = np.zeros((3, 20), np.int32)
    hits[1, 12] = 5
    grid = OccupancyGrid(hits, np.zeros_like(hits), origin=[0.0, -0.15], resolution=0.1)
    s = virtual_scan_from_grid(grid, [0.33, 0.0, 0.0], beams=8, max_range=5.0)
    # Beam 4 (bearing 0) reaches the cell centre x = 1.25: 0.92 m.
    assert s.ranges[4] == pytest.approx(1.25 - 0.33)
    assert np.all(s.ranges[np.arange(8) != 4] == 5.0)
    # Turned by pi the sensor sees it with beam 0 (bearing -pi).
    s = virtual_scan_from_grid(grid, [0.33, 0.0, np.pi], beams=8, max_range=5.0)
    assert s.ranges[0] == pytest.approx(0.92) and s.valid.sum() == 1
    # Beyond max range: no return; the occupied cell around the sensor is ignored.
    assert not virtual_scan_from_grid(grid, [0.33, 0.0, 0.0], beams=8, max_range=0.8).valid.any()
    s = virtual_scan_from_grid(grid, [1.24, 0.0, 0.0], beams=8, max_range=5.0)
    assert not s.valid.any()


def test_grid_ray_marching_passes_diagonal_corners_exactly():
    # Occupied cells (r, c) = (0, 1) and (1, 0): a 45-degree beam from the centre of
    # (0, 0) passes exactly through their shared corner point and must go on.
    hits = np.zeros((4, 4), np.int32)
    hits[0, 1] = hits[1, 0] = 1
    hits[3, 3] = 1
    grid = OccupancyGrid(hits, np.zeros_like(hits), origin=[0.0, 0.0], resolution=1.0)
    s = virtual_scan_from_grid(grid, [0.5, 0.5, 0.0], beams=8, max_range=10.0, min_range=0.1)
    beam_45 = int(np.argmin(np.abs(s.angles - np.pi / 4)))
    assert s.ranges[beam_45] == pytest.approx(3.0 * math.sqrt(2))


def test_virtual_scan_from_a_grid_of_the_room_matches_the_true_scan():
    scans, poses = half_scans(ROOM, POSE, noise=0.005)
    grid = build_occupancy_grid(scans * 3, np.vstack([poses] * 3), 0.05)
    got = virtual_scan_from_grid(grid, POSE, max_range=25.0)
    err = np.abs(got.ranges - true_scan(ROOM, POSE))
    assert np.median(err) < 0.025  # half a cell
    assert np.mean(err < 0.1) > 0.95


def test_grid_bad_pose_is_a_user_error():
    grid = OccupancyGrid(np.ones((2, 2), np.int32), np.zeros((2, 2), np.int32), [0, 0], 0.1)
    with pytest.raises(UserError, match="finite"):
        virtual_scan_from_grid(grid, [np.nan, 0.0, 0.0])


# ------------------------------------------------------------------ real data


def test_intel_virtual_scans_from_neighbours_agree_with_the_real_front_half():
    from data.carmen import CarmenLog

    scans = list(CarmenLog(shared_file("carmen-corrected/intel-corrected.log.gz")))
    poses = np.array([s.odom for s in scans])
    errors, covered = [], []
    for kf in range(10, len(scans) - 10, 40):
        near = [i for i in range(kf - 10, kf + 11) if i != kf]  # the keyframe's own scan left out
        sub = [scans[i] for i in near]
        v = virtual_scan_from_scans(sub, poses[near], poses[kf], max_range=30.0)
        s = scans[kf]
        # Real beams (-90..90 deg in steps of pi/179) nearest to each virtual beam.
        j = np.clip(np.round((v.angles - s.angles[0]) / (s.angles[1] - s.angles[0])), 0, 179)
        j = j.astype(int)
        same = (np.abs(s.angles[j] - v.angles) < np.radians(0.3)) & s.valid[j]
        both = same & v.valid
        errors.append(np.abs(v.ranges - s.ranges[j])[both])
        covered.append(both.sum() / same.sum())
    err = np.concatenate(errors)
    assert np.mean(covered) > 0.9
    assert np.median(err) < 0.06
    assert np.mean(err > 0.2) < 0.2
