"""Oriented scan normals and back-face culling of the icp2d local map."""

from __future__ import annotations

import numpy as np

from data import se2
from data.types import Scan
from slam.odometry.facing import facing, scan_normals
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry


def test_scan_normals_face_the_sensor_whatever_the_point_order() -> None:
    """A wall 1 m ahead (y = 1) and one 2 m to the side (x = 2), shuffled, a lone point
    5 m from any other and a zigzag (steps turning by 90 degrees): normals (0, -1) and
    (-1, 0) along the walls (one-sided at their ends, whose other bearing neighbour is
    over 0.25 m away), NaN at the lone point and, with a 30-degree bend limit, inside
    the zigzag (without one, its points have normals)."""
    front = np.column_stack([np.arange(-1.0, 1.01, 0.1), np.ones(21)])
    side = np.column_stack([np.full(11, 2.0), np.arange(-0.5, 0.51, 0.1)])
    lone = np.array([[-6.0, 3.0]])
    zigzag = np.column_stack([np.array([-3.0, -2.9, -3.0, -2.9, -3.0]),
                              -1.0 - 0.1 * np.arange(5)])
    pts = np.vstack([front, side, lone, zigzag])
    order = np.random.default_rng(1).permutation(len(pts))
    normals = np.empty_like(pts)
    normals[order] = scan_normals(pts[order], max_gap=0.25, max_bend=np.pi / 6)
    np.testing.assert_allclose(normals[:21], np.tile([0.0, -1.0], (21, 1)), atol=1e-12)
    np.testing.assert_allclose(normals[21:32], np.tile([-1.0, 0.0], (11, 1)), atol=1e-12)
    assert np.isnan(normals[32]).all()
    assert np.isnan(normals[34:37]).all()
    assert not np.isnan(scan_normals(zigzag, max_gap=0.25)).any()


def test_facing_keeps_only_the_face_a_viewpoint_can_see() -> None:
    """A 0.1 m wall along y: its left face (x = -0.05) seen from (-2, 0) has normals
    (-1, 0), its right face (x = 0.05) seen from (2, 0) has (1, 0).  From (1.5, 0.3)
    only the right face is kept: ``n . (c - p)`` is -1.55 on the left, +1.45 on the
    right; a point without a normal is kept."""
    y = np.linspace(-1.0, 1.0, 9)
    left = np.column_stack([np.full(9, -0.05), y])
    right = np.column_stack([np.full(9, 0.05), y])
    pts = np.vstack([left, right, [[0.0, 5.0]]])
    normals = np.vstack([np.tile([-1.0, 0.0], (9, 1)), np.tile([1.0, 0.0], (9, 1)),
                         [[np.nan, np.nan]]])
    keep = facing(pts, normals, np.array([1.5, 0.3, 0.7]))
    assert not keep[:9].any() and keep[9:].all()


def test_icp2d_map_leaves_out_the_far_face_of_a_thin_wall() -> None:
    """Keyframe A at (-2, 0) facing +x sees a wall's left face (x = -0.05), keyframe B at
    (2, 0) facing -x its right face (x = 0.05).  With `cull_back_faces` the map after B
    holds only the right face; without, both."""
    y = np.arange(-3.0, 3.01, 0.05)
    a_pose, b_pose = np.array([-2.0, 0.0, 0.0]), np.array([2.0, 0.0, np.pi])
    a_pts = se2.transform_points(se2.inverse(a_pose), np.column_stack([np.full(len(y), -0.05), y]))
    b_pts = se2.transform_points(se2.inverse(b_pose), np.column_stack([np.full(len(y), 0.05), y]))
    maps = {}
    for cull in (False, True):
        odo = Icp2dOdometry(Icp2dConfig(cull_back_faces=cull))
        odo._accept(a_pose, np.zeros(3), a_pts, {}, force_keyframe=True)
        odo._accept(b_pose, np.zeros(3), b_pts, {}, force_keyframe=True)
        maps[cull] = odo.map_points
    assert (maps[False][:, 0] < 0).any() and (maps[False][:, 0] > 0).any()
    assert (maps[True][:, 0] > 0).sum() == (maps[False][:, 0] > 0).sum()
    assert not (maps[True][:, 0] < 0).any()


def test_icp2d_facing_view_prediction_culls_from_where_the_scan_is() -> None:
    """Keyframes A (-2, 0) and B (2, 0) on either side of a 0.1 m wall along y, as
    above; then a scan from (-2, 0.5), facing +x, that sees the left face (x = -0.05)
    with its odometry exact.  Culled from the newest keyframe B the map holds only the
    right face (x = +0.05), which the scan cannot see: its registration is pulled
    across, the wall's thickness, to x = -1.9.  With ``facing_view="prediction"`` the map is culled
    from the prediction (-2, 0.5): only the left face, and the pose stays at x = -2."""
    y = np.arange(-3.0, 3.01, 0.05)
    a_pose, b_pose = np.array([-2.0, 0.0, 0.0]), np.array([2.0, 0.0, np.pi])
    c_pose = np.array([-2.0, 0.5, 0.0])
    left = np.column_stack([np.full(len(y), -0.05), y])
    right = np.column_stack([np.full(len(y), 0.05), y])
    # The scan of the left face from C: a 180-degree laser, 361 beams, exact ranges.
    angles = np.radians(np.linspace(-90.0, 90.0, 361))
    ranges = np.full(len(angles), np.inf)
    ahead = np.cos(angles) > 0.05
    ranges[ahead] = (left[0, 0] - c_pose[0]) / np.cos(angles[ahead])
    ranges[ranges > 20.0] = np.inf
    scan = Scan(stamp=1.0, ranges=ranges, angles=angles, max_range=20.0, odom=c_pose,
                index=2)
    xs = {}
    for view in ("keyframe", "prediction"):
        cfg = Icp2dConfig(cull_back_faces=True, facing_view=view, max_step=10.0,
                          max_step_rotation=4.0)
        odo = Icp2dOdometry(cfg)
        for pose, face in ((a_pose, left), (b_pose, right)):
            odo._accept(pose, np.zeros(3), se2.transform_points(se2.inverse(pose), face),
                        {}, force_keyframe=True)
        odo._odom = b_pose.copy()
        est = odo.process(scan)
        xs[view] = (est.pose[0], est.status)
    assert abs(xs["prediction"][0] + 2.0) < 0.005, xs
    assert abs(xs["keyframe"][0] + 1.9) < 0.005, xs
