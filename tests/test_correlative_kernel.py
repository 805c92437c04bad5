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


def test_correlate_matches_direct_sum_with_points_beyond_every_edge():
    rng = np.random.default_rng(3)
    grid = rng.integers(0, 256, size=(23, 31)).astype(np.uint8)
    # Points spread well past the grid (1 cell = 0.1 m: the grid spans 3.1 x 2.3 m).
    px = rng.uniform(-2.0, 5.0, 60)
    py = rng.uniform(-2.0, 4.0, 60)
    angles = np.array([-0.3, 0.0, 0.7, 3.0])
    for step in (1, 3, 4):
        args = (px, py, angles, grid, -0.45, -0.35, 10.0, 5, step)
        np.testing.assert_array_equal(correlative._correlate(*args), _direct(*args))
