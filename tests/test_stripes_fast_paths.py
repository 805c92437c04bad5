"""The fast paths of the stripes benchmark give the numbers of the plain rules, to the bit.

`evaluation.stripes_objects.silhouette_polygon` closes and traces the footprint on its
bounding box and `range_image` / `height_map` fill the range image in one assignment;
the references here are the plain rules on the whole image (`StripeScan.silhouette`,
``scipy.ndimage.binary_closing``, `data.mpeg7.contour_from_image`) and the scan's own
methods.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from data.mpeg7 import contour_from_image
from data.stripe_scanner import ScannerConfig, StripeScan
from evaluation.stripes_objects import (
    daily_objects,
    height_map,
    range_image,
    scan_objects,
    silhouette_polygon,
)


def whole_image_silhouette(scan: StripeScan, cfg: ScannerConfig, smooth: float) -> np.ndarray:
    """The silhouette's vertices [mm] by the rule on the whole image."""
    mask = ndimage.binary_closing(np.pad(scan.silhouette(), 2), structure=np.ones((3, 3), bool))
    contour = contour_from_image(mask.astype(np.uint8) * 255, smooth=smooth)
    if contour is None:
        rows, cols = np.nonzero(mask)
        y = (mask.shape[0] - 1) - rows
        x0, x1, y0, y1 = cols.min() - 0.5, cols.max() + 0.5, y.min() - 0.5, y.max() + 0.5
        contour = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    return contour * np.array([1000.0 * scan.field_of_view / cfg.width, 1000.0 * cfg.step])


def hand_made_scans() -> list[StripeScan]:
    """A block with a one-pixel gap and a notch, a single stripe, a stripe at the image's
    edge, one column written twice in a frame (the last point counts), and a point off
    the image."""
    rng = np.random.default_rng(0)
    stripes = []
    for r in range(30):
        x = np.arange(100, 160, dtype=float) + rng.normal(0, 0.3, 60)
        keep = (np.arange(60) != 20) & ~((r > 10) & (r < 15) & (np.arange(60) > 50))
        stripes.append(np.column_stack([x[keep], 300.0 + rng.normal(0, 1, keep.sum())]))
    block = StripeScan("block", stripes, np.zeros(30), np.arange(30) + 1, 33, 0,
                       (0.0, 0.0, 0.0), (600, 712))
    single = StripeScan("one", [np.column_stack([np.arange(5.0, 45.0), np.full(40, 250.0)])],
                        np.zeros(1), np.array([0]), 1, 0, (0.0, 0.0, 0.0), (600, 712))
    edge = StripeScan("edge", [np.column_stack([np.arange(690.0, 712.0), np.full(22, 200.0)])
                               for _ in range(6)], np.zeros(6), np.arange(6), 6, 0,
                      (0.0, 0.0, 0.0), (600, 712))
    twice = StripeScan("twice", [np.array([[10.0, 5.0], [10.2, 7.0], [11.0, 6.0]])] * 3,
                       np.zeros(3), np.arange(3), 3, 0, (0.0, 0.0, 0.0), (600, 712))
    # A point left of the image (column -1, which the method's indexing wraps around).
    off = StripeScan("off", [np.array([[-0.7, 5.0], [0.0, 6.0], [1.0, 6.0]])] * 2,
                     np.zeros(2), np.arange(2), 2, 0, (0.0, 0.0, 0.0), (600, 712))
    return [block, single, edge, twice, off]


@pytest.mark.filterwarnings("ignore::data.errors.DataWarning")
def test_fast_paths_equal_the_whole_image_rules_to_the_bit():
    cfg = ScannerConfig(step=0.003)
    scans = scan_objects(daily_objects(2, 1, ("book", "bottle_cap", "banana")), cfg,
                         seed=1).scans
    for scan in [*scans, *hand_made_scans()]:
        for smooth in (0.0, 1.0):
            got = silhouette_polygon(scan, cfg, smooth).vertices
            want = whole_image_silhouette(scan, cfg, smooth)
            assert got.shape == want.shape and np.array_equal(got, want), scan.name
        np.testing.assert_array_equal(range_image(scan), scan.range_image())
        z, cell = height_map(scan, cfg)
        z_ref, cell_ref = scan.height_map(cfg)
        np.testing.assert_array_equal(z, z_ref)
        assert cell == cell_ref
