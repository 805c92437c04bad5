"""The correlative search's compiled sums against a direct numpy sum of (1)."""

import numpy as np

from loopclosure import correlative


def _direct(px, py, angles, grid, x0, y0, inv_res, half, step):
    """Every lattice pose, one point at a time: the grid value of the cell each
    moved point falls in, 0 outside the grid."""
    h, w = grid.shape
    t = 2 * half + 1
    out = np.zeros((len(angles), t, t))
    for a, ang in enumerate(angles):
        x = np.cos(ang) * px - np.sin(ang) * py
        y = np.sin(ang) * px + np.cos(ang) * py
        ix = np.floor((x - x0) * inv_res).astype(int)
        iy = np.floor((y - y0) * inv_res).astype(int)
        for j in range(t):
            for i in range(t):
                gx = ix + (i - half) * step
                gy = iy + (j - half) * step
                inside = (gx >= 0) & (gx < w) & (gy >= 0) & (gy < h)
                out[a, j, i] = grid[gy[inside], gx[inside]].astype(float).sum()
    return out


def _compiled(px, py, angles, grid, x0, y0, inv_res, half, step, kind=np.int32):
    t = 2 * half + 1
    return correlative._correlate(px, py, angles, grid,
                                  correlative._split_columns(grid, step), x0, y0, inv_res,
                                  half, step, np.zeros((len(angles), t, t), dtype=kind))


def test_correlate_matches_direct_sum_with_points_beyond_every_edge():
    rng = np.random.default_rng(3)
    grid = rng.integers(0, 256, size=(23, 31)).astype(np.uint8)
    # Points spread well past the grid (1 cell = 0.1 m: the grid spans 3.1 x 2.3 m).
    px = rng.uniform(-2.0, 5.0, 60)
    py = rng.uniform(-2.0, 4.0, 60)
    angles = np.array([-0.3, 0.0, 0.7, 3.0])
    for step in (1, 3, 4):
        args = (px, py, angles, grid, -0.45, -0.35, 10.0, 5, step)
        # The means, bit for bit the direct sums divided by 255 N.
        np.testing.assert_array_equal(_compiled(*args), _direct(*args) / (255.0 * len(px)))


def test_correlate_inside_and_across_the_edges_of_a_large_grid():
    """Points whose whole window of shifts lies inside the grid (summed without
    bounds tests from the split columns) and points near or past its edges, with
    int32 and int64 sums: every mean the direct sum's."""
    rng = np.random.default_rng(5)
    grid = rng.integers(0, 256, size=(97, 123)).astype(np.uint8)  # 12.3 x 9.7 m
    px = rng.uniform(-1.0, 13.0, 300)
    py = rng.uniform(-1.0, 10.5, 300)
    angles = np.array([-0.05, 0.0, 0.02])
    for step, half in ((1, 4), (4, 6), (3, 5)):
        args = (px, py, angles, grid, 0.0, 0.0, 10.0, half, step)
        direct = _direct(*args) / (255.0 * len(px))
        for kind in (np.int32, np.int64):
            np.testing.assert_array_equal(_compiled(*args, kind=kind), direct)


def test_split_columns_by_remainder():
    values = np.arange(2 * 7, dtype=np.uint8).reshape(2, 7)
    split = correlative._split_columns(values, 3)
    assert split.shape == (3, 2, 3)
    # Row 0 is 0..6: remainder 0 holds columns 0, 3, 6; remainder 1 holds 1, 4 and a 0
    # past the last column; remainder 2 holds 2, 5 and a 0.
    np.testing.assert_array_equal(split[:, 0], [[0, 3, 6], [1, 4, 0], [2, 5, 0]])
    np.testing.assert_array_equal(split[:, 1], [[7, 10, 13], [8, 11, 0], [9, 12, 0]])
    assert correlative._split_columns(values, 1).shape == (1, 2, 7)
