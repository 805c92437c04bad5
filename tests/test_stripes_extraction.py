"""Stripe extraction: laser-line images, binary images (thinning, chaining), 3D points."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from data.errors import DataError, DataWarning
from data.stripe_scanner.line_detector import laser_line_positions
from loopclosure.stripes.extraction import (
    chain_pixels,
    stripe_from_binary_image,
    stripe_from_laser_image,
    stripes_from_laser_images,
    stripes_from_points,
    thin,
)


def _laser_image(rows_of_col, shape=(600, 712), sigma=1.5, cols=None):
    """Gaussian laser line at sub-pixel rows (NaN: no line in that column)."""
    r = np.arange(shape[0])[:, None]
    img = np.exp(-0.5 * ((r - rows_of_col[None, :]) / sigma) ** 2)
    img[:, ~np.isfinite(rows_of_col)] = 0.0
    return np.nan_to_num(img)


def test_laser_image_line_found_per_column():
    c = np.arange(712, dtype=float)
    true = 300 + 40 * np.sin(c / 60.0)
    true[100:130] = np.nan  # a gap: those columns have no line
    stripe = stripe_from_laser_image(_laser_image(true), threshold=0.2)
    ok = np.isfinite(true)
    np.testing.assert_array_equal(stripe[:, 0], c[ok])
    # The threshold window is whole rows, so it is slightly asymmetric about an
    # off-pixel centre: the weighted mean is biased by a few hundredths of a pixel.
    np.testing.assert_allclose(stripe[:, 1], true[ok], atol=0.15)
    assert np.mean(np.abs(stripe[:, 1] - true[ok])) < 0.05


def test_threshold_borders_and_weighted_mean_by_hand():
    col = np.zeros((10, 1))
    col[3:7, 0] = [0.5, 2.0, 1.0, 0.1]  # row 6 is below the threshold 0.4 -> end = row 5
    cols, rows = laser_line_positions(col, 0.4)
    assert cols.tolist() == [0]
    assert rows[0] == pytest.approx((3 * 0.5 + 4 * 2.0 + 5 * 1.0) / 3.5)
    # A dim pixel between two bright ones is inside the borders and counts.
    col2 = np.zeros((10, 1))
    col2[[2, 3, 4], 0] = [1.0, 0.1, 1.0]
    assert laser_line_positions(col2, 0.5)[1][0] == pytest.approx((2 + 0.3 + 4) / 2.1)
    assert len(laser_line_positions(np.zeros((5, 4)), 0.1)[0]) == 0


def test_images_without_line_are_reported_once():
    good = _laser_image(np.full(50, 20.0), shape=(40, 50))
    with pytest.warns(DataWarning, match="1 of 3 images"):
        s = stripes_from_laser_images([good, np.zeros((40, 50)), good], 0.3, name="obj")
    assert len(s) == 2
    with pytest.raises(DataError, match="obj: no laser line"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stripes_from_laser_images([np.zeros((40, 50))], 0.3, name="obj")


def test_thinning_a_thick_line_to_one_pixel():
    img = np.zeros((60, 200), np.uint8)
    cv2.line(img, (10, 30), (190, 30), 1, thickness=5)
    sk = thin(img)
    rows = np.nonzero(sk)[0]
    assert set(np.unique(rows)) <= {29, 30, 31}
    # One pixel per column over the interior of the line.
    per_col = sk[:, 15:185].sum(axis=0)
    assert np.all(per_col == 1)


def test_binary_image_chained_in_order():
    img = np.zeros((600, 712), np.uint8)
    t = np.linspace(0, np.pi, 300)
    curve = np.column_stack([356 + 250 * np.cos(t), 300 + 120 * np.sin(t)])  # (x, y)
    cv2.polylines(img, [np.rint(curve).astype(np.int32)], False, 1, thickness=3)
    stripe = stripe_from_binary_image(img)
    steps = np.hypot(*np.diff(stripe, axis=0).T)
    assert steps.max() <= np.sqrt(2) + 1e-9  # consecutive pixels are neighbours
    # It starts at the left end (smallest column) and ends at the right end.
    assert stripe[0, 0] == pytest.approx(106, abs=2) and stripe[-1, 0] == pytest.approx(606, abs=2)
    # Every pixel lies on the drawn curve.
    d = np.min(np.hypot(stripe[:, None, 0] - curve[None, :, 0],
                        stripe[:, None, 1] - curve[None, :, 1]), axis=1)
    assert d.max() < 1.6
    # The per-column method agrees where the curve is a function of the column.
    cols = stripe_from_binary_image(img, method="columns")
    assert np.all(np.diff(cols[:, 0]) > 0)


def test_chaining_jumps_gaps_to_the_nearest_run():
    # Three runs on one row with gaps, given in scrambled order.
    c = np.r_[np.arange(0, 10), np.arange(40, 50), np.arange(15, 30)]
    r = np.zeros_like(c)
    path = chain_pixels(r, c)
    np.testing.assert_array_equal(path[:, 0], np.r_[np.arange(10), np.arange(15, 30),
                                                    np.arange(40, 50)])
    assert chain_pixels([], []).shape == (0, 2)
    assert len(stripe_from_binary_image(np.zeros((5, 5)))) == 0


def test_points_sliced_into_ordered_stripes():
    rng = np.random.default_rng(0)
    # Upper half of a sphere of radius 5 cm, 4000 random points.
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p = 0.05 * p[p[:, 2] > 0]
    stripes = stripes_from_points(p, spacing=0.01, resolution=0.001)
    assert len(stripes) == 10  # 10 cm / 1 cm
    for s in stripes:
        assert np.all(np.diff(s[:, 0]) >= 0)  # ordered along the slice
        assert s[:, 1].max() <= 0  # v = -height
    # The middle slices are the widest: about the sphere's diameter in mm.
    widths = [np.ptp(s[:, 0]) for s in stripes]
    assert max(widths) == pytest.approx(100, abs=8)
    assert widths[0] < 60 and widths[-1] < 60


def test_points_by_ring():
    az = np.linspace(-0.2, 0.2, 50)
    rings = np.repeat([3, 1, 2], 50)
    rng_m = np.repeat([5.0, 5.2, 5.1], 50)
    pts = np.column_stack([rng_m * np.cos(np.tile(az, 3)), rng_m * np.sin(np.tile(az, 3)),
                           np.repeat([0.3, 0.1, 0.2], 50)])
    stripes = stripes_from_points(pts, rings=rings, resolution=0.01)
    assert len(stripes) == 3
    # Ordered by ring number; ring 1 (range 5.2 m) -> v = -520.
    assert stripes[0][0, 1] == pytest.approx(-520, abs=1)
    assert stripes[2][0, 1] == pytest.approx(-500, abs=1)
    with pytest.raises(DataError, match="no finite point"):
        stripes_from_points(np.full((3, 3), np.nan), name="c")
