"""The front end's exact speed-ups give the numbers of the code they replace, to the
bit: scalar ``se2.between``, the odometry noise from a measured step, the float64
odometry path, the local map's crop, the carried nearest neighbours of ICP, the
source check and the remembered matchable grid, the bearings kept by identity."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.types import Scan
from loopclosure.fast_icp import (
    GridTarget,
    _matchable,
    _source_points,
    points_within,
    register_fast,
    within_radius,
)
from loopclosure.grid_nearest import _match, _nearest, _nearest_bound
from loopclosure.registration import IcpConfig
from slam.odometry import MotionNoise, scan_odometry
from slam.odometry.icp2d import Icp2dOdometry, _between


def test_between_is_se2_between_to_the_bit() -> None:
    rng = np.random.default_rng(0)
    poses = rng.uniform(-50, 50, (500, 3))
    poses[:, 2] = rng.uniform(-np.pi, np.pi, 500)
    poses[:5, 2] = [np.pi, -np.pi, np.nextafter(np.pi, 0), 0.0, -0.0]
    for a, b in itertools.pairwise(poses):
        assert np.array(_between(a, b)).tobytes() == se2.between(a, b).tobytes()
    # hand-checked: b is 1 m ahead of a, which faces +y
    x, y, t = _between(np.array([2.0, 3.0, np.pi / 2]), np.array([2.0, 4.0, np.pi / 2]))
    assert (x, y, t) == pytest.approx((1.0, 0.0, 0.0), abs=1e-15)


def test_noise_diagonal_is_the_covariance_of_the_step() -> None:
    noise = MotionNoise()
    # (3, 4, 0): 5 m, no turn -> along 0.1^2 * 5 + 1e-6, lateral and rotation 0.05^2 * 5 + 1e-6
    np.testing.assert_allclose(np.diag(noise.diagonal(5.0, 0.0)),
                               [0.050001, 0.012501, 0.012501], rtol=1e-12)
    rng = np.random.default_rng(1)
    for u in rng.uniform(-2, 2, (200, 3)):
        step, rot = float(np.hypot(u[0], u[1])), abs(se2._wrap(float(u[2])))
        assert noise.diagonal(step, rot).tobytes() == noise.covariance(u).tobytes()


def test_scan_odometry_float_path() -> None:
    odom = np.array([1.0, 2.0, 0.5])
    scan = Scan(stamp=0.0, ranges=np.ones(3), angles=np.zeros(3), max_range=10.0, odom=odom)
    assert scan_odometry(scan) is odom
    bad = Scan(stamp=0.0, ranges=np.ones(3), angles=np.zeros(3), max_range=10.0,
               odom=np.array([1.0, np.nan, 0.0]))
    assert scan_odometry(bad) is None
    listed = Scan(stamp=0.0, ranges=np.ones(3), angles=np.zeros(3), max_range=10.0,
                  odom=[1, 2, 3])
    np.testing.assert_array_equal(scan_odometry(listed), [1.0, 2.0, 3.0])


def test_within_radius_hand_checked_and_as_hypot() -> None:
    pts = np.array([[3.0, 4.0], [0.0, 5.0 + 1e-12], [1.0, 1.0], [np.nan, 0.0], [-5.0, 0.0]])
    # centre (0, 0), radius 5: hypot 5 (in), 5 + 1e-12 (out), sqrt 2 (in), NaN (out), 5 (in)
    assert within_radius(pts, (0.0, 0.0), 5.0).tolist() == [True, False, True, False, True]
    rng = np.random.default_rng(2)
    many = rng.uniform(-10, 10, (5000, 2))
    centre = np.array([0.3, -0.2])
    radius = float(np.hypot(*(many[7] - centre)))  # one point exactly on the border
    ref = np.hypot(*(many - centre).T) <= radius
    np.testing.assert_array_equal(within_radius(many, centre, radius), ref)
    assert points_within(many, centre, radius).tobytes() == many[ref].tobytes()
    assert points_within(many, centre, 100.0) is many  # every row kept: no copy


def test_nearest_bound_hand_checked() -> None:
    grid = GridTarget(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 3.0]]), cell=0.25)
    ox, oy = grid.origin
    nx, ny = grid.shape
    j, d, bound = _nearest_bound(0.1, 0.0, 2.0, ox, oy, grid.cell, nx, ny, grid.start,
                                 grid.points)
    assert grid.points[j].tolist() == [0.0, 0.0] and d == pytest.approx(0.1)
    # the next point (1, 0) is 0.9 away: the bound never exceeds it
    assert 0.0 < bound <= 0.9 + 1e-12
    j, d, bound = _nearest_bound(0.5, 1.5, 0.3, ox, oy, grid.cell, nx, ny, grid.start,
                                 grid.points)
    assert j == -1 and 0.3 <= bound <= np.hypot(0.5, 1.5)  # none within the gate


def test_nearest_bound_answers_as_nearest_and_bounds_the_others() -> None:
    rng = np.random.default_rng(3)
    grid = GridTarget(rng.uniform(0, 5, (300, 2)), cell=0.25)
    ox, oy = grid.origin
    for q in rng.uniform(-1, 6, (300, 2)):
        gate = rng.uniform(0.05, 1.5)
        args = (q[0], q[1], gate, ox, oy, grid.cell, grid.shape[0], grid.shape[1],
                grid.start, grid.points)
        j, d = _nearest(*args)
        j2, d2, bound = _nearest_bound(*args)
        assert (j, d) == (j2, d2)
        dist = np.hypot(*(grid.points - q).T)
        others = np.delete(dist, j) if j >= 0 else dist
        assert bound <= others.min() + 1e-12


def _match_once(grid, src, x, gate, carried):
    n = len(src)
    sel, jdx, dist = (np.zeros(2 * n, np.int64), np.zeros(2 * n, np.int64), np.zeros(2 * n))
    near, bound, last, norms = carried
    out = _match(src, x, gate, grid.origin[0], grid.origin[1], grid.cell, grid.shape[0],
                 grid.shape[1], grid.start, grid.points, grid.kind, sel, jdx, dist,
                 grid.params, grid.normals, grid.anchors, near, bound, last, norms)
    rows = out[0]
    return out, sel[:rows].copy(), jdx[:rows].copy(), dist[:rows].copy()


def test_carried_neighbours_match_a_fresh_search() -> None:
    """Poses that move less and less (as ICP's iterates do) and a shrinking gate: the
    carried correspondences equal a search of every point at every pose."""
    rng = np.random.default_rng(4)
    t = np.linspace(0, 6, 240)
    walls = np.vstack([np.column_stack([t, 0.01 * rng.standard_normal(240)]),
                       np.column_stack([0.01 * rng.standard_normal(240), t]),
                       rng.uniform(1, 5, (60, 2))])
    grid = GridTarget(walls, IcpConfig(point_to_point_clutter=True), lazy=True)
    src = walls[rng.choice(len(walls), 120, replace=False)] + 0.003
    n = len(src)
    carried = (np.zeros(n, np.int64), np.zeros(n), np.zeros(4),
               np.hypot(src[:, 0], src[:, 1]))
    x, gate, reused = np.array([0.05, -0.04, 0.02]), 1.0, 0
    for step in range(8):
        fresh = (np.zeros(n, np.int64), np.zeros(n), np.zeros(4), carried[3])
        got = _match_once(grid, src, x, gate, carried)
        want = _match_once(grid, src, x, gate, fresh)
        assert got[0] == want[0]
        for a, b in zip(got[1:], want[1:], strict=True):
            assert a.tobytes() == b.tobytes()
        if step > 0:
            reused += int(np.sum(carried[1] != fresh[1]))  # a carried bound: no search
        x = x * 0.3
        gate = max(0.1, gate * 0.6)
    assert reused > 0  # the shortcut was taken


def test_register_fast_source_check_and_matchable() -> None:
    t = np.linspace(0, 4, 80)
    walls = np.vstack([np.column_stack([t, 0 * t]), np.column_stack([0 * t, t])])
    grid = GridTarget(walls, lazy=True)
    src = np.ascontiguousarray(walls[::3] + 0.01)
    assert _source_points(src) is src
    with pytest.raises(UserError, match="source points holds non-finite"):
        _source_points(np.array([[0.0, np.inf], [1.0, 1.0]]))
    with pytest.raises(UserError, match="must be an"):
        _source_points(np.zeros((3, 3)))
    first = register_fast(src, grid, (0.0, 0.0, 0.0))
    again = register_fast(src, grid, (0.0, 0.0, 0.0))  # the remembered grid
    assert first.ok and first.pose.tobytes() == again.pose.tobytes()
    assert _matchable(grid)
    lone = GridTarget(np.array([[0.0, 0.0]]), lazy=True)  # too few points for a normal
    assert not _matchable(lone) and not register_fast(src, lone).ok


def test_bearings_kept_for_a_read_only_array_only() -> None:
    odo = Icp2dOdometry()
    angles = np.linspace(-1.0, 1.0, 5)
    angles.flags.writeable = False
    cos1, _ = odo._bearings(angles)
    cos2, _ = odo._bearings(angles)
    assert cos2 is cos1 and odo._trig_source is angles
    equal = np.linspace(-1.0, 1.0, 5)  # another array, the same bearings: still kept
    assert odo._bearings(equal)[0] is cos1
    writable = np.linspace(-0.5, 0.5, 5)
    odo._bearings(writable)
    assert odo._trig_source is None
    writable[0] = 0.5  # changed in place: the cosines follow
    cos3, _ = odo._bearings(writable)
    assert cos3[0] == np.cos(0.5)


def test_the_keyframe_stack_is_the_vstack_of_the_window() -> None:
    """`Icp2dOdometry._add_keyframe` keeps ``np.vstack`` of the last `map_keyframes`
    keyframes: the oldest leaves a full window, the newest comes last."""
    from slam.odometry.icp2d import Icp2dConfig

    odo = Icp2dOdometry(Icp2dConfig(map_keyframes=3))
    frames = [np.full((n, 2), float(k)) + np.arange(n)[:, None] for k, n in
              enumerate([2, 0, 3, 1, 4])]
    for k, f in enumerate(frames):
        odo._add_keyframe(f)
        window = frames[max(0, k - 2):k + 1]
        assert odo._stack is not None and odo._stack.tobytes() == np.vstack(window).tobytes()
    # hand-checked: frames 2, 3, 4 (3 + 1 + 4 rows), their first columns 2, 3, 4, 4, 3, ...
    assert odo._stack[:, 0].tolist() == [2.0, 3.0, 4.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    odo.reset()
    assert odo._stack is None and not odo._keyframes
