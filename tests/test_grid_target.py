"""`loopclosure.grid_target`: the lazy grid resolves every point as the eager grid
computes it, and the front end on lazy grids gives the same estimates."""

import numpy as np
import pytest

from data.errors import UserError
from data.sim import MotionConfig, simulate_run
from loopclosure import fast_icp
from loopclosure.grid_target import (
    KIND_UNKNOWN,
    GridTarget,
    _cells,
    _cells_sorted,
    _counting_sort,
    _target_points,
    estimate_normals_fast,
)
from loopclosure.registration import IcpConfig, estimate_normals
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry


def _room_with_clutter(seed: int = 0) -> np.ndarray:
    """Walls of a 6 x 4 m room at 5 cm, with noise, plus a scatter of clutter."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 6.0, 0.05)
    s = np.arange(0.0, 4.0, 0.05)
    walls = np.vstack([np.column_stack([t, 0 * t]), np.column_stack([t, 0 * t + 4.0]),
                       np.column_stack([0 * s, s]), np.column_stack([0 * s + 6.0, s])])
    walls = walls + rng.normal(0.0, 0.005, walls.shape)
    clutter = rng.uniform([2.0, 1.5], [3.0, 2.5], (60, 2))
    return np.vstack([walls, clutter])


def test_counting_sort_is_the_stable_argsort_and_its_offsets():
    flat = np.array([3, 1, 3, 0, 1, 3])
    start, order = _counting_sort(flat, 5)
    assert order.tolist() == [3, 1, 4, 0, 2, 5]  # cell 0: point 3; cell 1: 1, 4; ...
    assert start.tolist() == [0, 1, 3, 3, 6, 6]
    rng = np.random.default_rng(1)
    flat = rng.integers(0, 40, 500)
    start, order = _counting_sort(flat, 50)
    assert np.array_equal(order, np.argsort(flat, kind="stable"))
    assert np.array_equal(start, np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=50))]))


def test_the_compiled_cell_layout_hand_checked_and_as_numpy_computes_it():
    # lo = min - cell = (-0.25, -0.25); cells (1, 1), (2, 1), (1, 3); shape (2 + 2, 3 + 2)
    pts = np.array([[0.0, 0.0], [0.3, 0.1], [0.05, 0.6]])
    origin, shape, start, order, ordered = _cells_sorted(pts, 0.25)
    assert origin.tolist() == [-0.25, -0.25] and shape == (4, 5)
    assert order.tolist() == [0, 2, 1]  # flat cells 6, 11, 8
    assert np.array_equal(ordered, pts[[0, 2, 1]]) and ordered.flags.c_contiguous
    assert start[:7].tolist() == [0] * 7 and start[7:9].tolist() == [1, 1]
    assert start[9:12].tolist() == [2, 2, 2] and start[12:].tolist() == [3] * 9
    rng = np.random.default_rng(2)
    for cell in (0.05, 0.25, 0.5):
        # on and off the cell borders, far from the origin
        pts = np.vstack([np.round(rng.normal(0, 8, (300, 2)) / 0.05) * 0.05,
                         rng.normal(0, 8, (300, 2))]) + np.array([500.0, -300.0])
        lo = pts.min(axis=0) - cell
        cells = np.floor((pts - lo) / cell).astype(np.int64)
        nx, ny = int(cells[:, 0].max()) + 2, int(cells[:, 1].max()) + 2
        flat = cells[:, 0] * ny + cells[:, 1]
        origin, shape, start, order, ordered = _cells_sorted(pts, cell)
        assert origin.tobytes() == lo.tobytes() and shape == (nx, ny)
        assert np.array_equal(order, np.argsort(flat, kind="stable"))
        assert np.array_equal(start, _counting_sort(flat, nx * ny)[0])
        assert np.array_equal(ordered, pts[order])
        assert all(np.array_equal(a, b) for a, b in
                   zip(_cells(pts, cell), (origin, shape, start, order), strict=True))


def test_target_points_checks_as_as_points_does():
    pts = np.array([[0.0, 1.0], [2.0, 3.0]])
    assert _target_points(pts) is pts  # no copy of a contiguous float64 array
    assert _target_points([[0, 1], [2, 3]]).tolist() == pts.tolist()
    assert _target_points(np.asfortranarray(pts)).flags.c_contiguous
    with pytest.raises(UserError, match="target points holds non-finite coordinates"):
        _target_points(np.array([[0.0, 1.0], [np.inf, 3.0]]))
    with pytest.raises(UserError, match="target points must be an"):
        _target_points(np.zeros((3, 3)))


@pytest.mark.parametrize("anchor", ["point", "mean"])
@pytest.mark.parametrize("clutter", [True, False])
def test_a_lazy_grid_resolves_each_point_as_the_eager_grid(anchor, clutter):
    cfg = IcpConfig(point_to_point_clutter=clutter)
    pts = _room_with_clutter()
    eager = GridTarget(pts, cfg, anchor=anchor)
    lazy = GridTarget(pts, cfg, anchor=anchor, lazy=True)
    assert np.all(lazy.kind == KIND_UNKNOWN)
    assert lazy.matchable() and np.count_nonzero(lazy.kind != KIND_UNKNOWN) < 5
    assert len(lazy) == len(eager) > 0  # resolves every point
    for name in ("points", "normals", "kind", "anchors", "start", "origin"):
        assert np.array_equal(getattr(lazy, name), getattr(eager, name)), name


def test_icp_on_a_lazy_grid_resolves_only_the_points_it_meets():
    pts = _room_with_clutter()
    cfg = IcpConfig(point_to_point_clutter=True)
    eager = GridTarget(pts, cfg)
    lazy = GridTarget(pts, cfg, lazy=True)
    source = pts[pts[:, 1] < 0.5][::2] - [0.05, -0.03]  # the south wall, moved
    a = fast_icp.register_fast(source, eager, (0.0, 0.0, 0.0))
    b = fast_icp.register_fast(source, lazy, (0.0, 0.0, 0.0))
    assert a.ok and np.array_equal(a.pose, b.pose) and np.array_equal(a.covariance,
                                                                       b.covariance)
    known = lazy.kind != KIND_UNKNOWN
    assert 0 < known.sum() < len(pts) / 2
    assert np.array_equal(lazy.kind[known], eager.kind[known])
    guesses = np.array([[0.0, 0.0, 0.0], [0.3, 0.2, 0.1]])
    screens = [fast_icp.overlap_screen(source, g, guesses, 0.5, 0.5) for g in (eager, lazy)]
    assert np.array_equal(screens[0][0], screens[1][0])


def test_skipping_far_cells_keeps_the_normals_of_the_kd_tree():
    pts = _room_with_clutter(2)
    cfg = IcpConfig()
    from scipy.spatial import cKDTree

    ref_n, ref_line, ref_ratio = estimate_normals(pts, cKDTree(pts), cfg)
    n, line, ratio = estimate_normals_fast(pts, cfg)
    assert np.array_equal(line, ref_line)
    assert np.allclose(np.abs(np.sum(n * ref_n, axis=1))[line], 1.0)
    assert np.allclose(ratio, ref_ratio)
    _, (nx, ny), start, order = _cells(pts, 0.25)
    assert start[-1] == len(pts) and len(start) == nx * ny + 1 and len(order) == len(pts)


def test_the_front_end_on_lazy_grids_gives_the_estimates_of_eager_grids(monkeypatch):
    run = simulate_run("box", seed=1, motion=MotionConfig(laps=0.2))
    scans = run.scans[:60]
    cfg = Icp2dConfig(keyframe_distance=0.1)  # a new map at nearly every scan

    def estimates(lazy: bool) -> list:
        real = fast_icp.GridTarget

        def made(*args, **kwargs):
            kwargs["lazy"] = lazy
            return real(*args, **kwargs)

        monkeypatch.setattr(fast_icp, "GridTarget", made)
        odo = Icp2dOdometry(cfg)
        out = [odo.process(s) for s in scans]
        monkeypatch.setattr(fast_icp, "GridTarget", real)
        assert odo.map_rebuilds > 30
        return out

    for a, b in zip(estimates(True), estimates(False), strict=True):
        assert a.status == b.status
        for name in ("pose", "delta", "covariance"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
