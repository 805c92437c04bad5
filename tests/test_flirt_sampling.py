"""FLIRT's contour-sampling option: a metric step and the range-capped edges dropped.

Hand-checked sample counts and masks, the option's path equal to the default's when
it samples the same points, and keypoints that repeat better between two views of a
synthetic room with two open doorways (no-return beams at the range cap).
"""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.raycast import LaserModel, trace
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher
from loopclosure.matchers.flirt_features import FlirtFeatureConfig, describe_polygon
from loopclosure.matchers.flirt_sampling import border_distance, kept_samples, sample_count
from loopclosure.polygon import Polygon, polygon_from_scan

SQUARE = Polygon(np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]))


def test_sample_count_is_the_perimeter_over_the_step_clipped() -> None:
    # Perimeter 16 m: 0.2 m -> 80 samples; 0.3 m -> round(53.3) = 53; a 1 m step
    # gives 16 (the floor); 1 mm would be 16000, clipped to max_samples.
    assert sample_count(SQUARE, 0.0, 256, 4096) == 256  # option off
    assert sample_count(SQUARE, 0.2, 256, 4096) == 80
    assert sample_count(SQUARE, 0.3, 256, 4096) == 53
    assert sample_count(SQUARE, 1.0, 256, 4096) == 16
    assert sample_count(SQUARE, 1e-3, 256, 500) == 500
    # In units of sqrt(area) (scale invariant): perimeter 16 / 4 = 4, step 0.1 -> 40.
    assert sample_count(SQUARE, 0.1, 256, 4096, unit=4.0) == 40
    features = describe_polygon(SQUARE, FlirtFeatureConfig(sample_step=0.2))
    assert features.step == pytest.approx(0.2)


def test_kept_samples_drop_the_edges_touching_a_far_vertex() -> None:
    # Vertices at ranges 2.83, 2.83, 30, 2.83 (the third at the cap): edges 1 (v1 -> v2)
    # and 2 (v2 -> v3) are dropped.  Edge lengths 4, 30.13, 30.13, 4 (ends at s = 4,
    # 34.13, 64.27, 68.27 m); 8 samples every 8.53 m: s = 0 on edge 0, the seven others
    # (8.5 .. 59.7 m) on edges 1 and 2.
    v = np.array([[2.0, -2.0], [2.0, 2.0], [-30.0 / np.sqrt(2), 30.0 / np.sqrt(2)],
                  [-2.0, -2.0]])
    poly = Polygon(v)
    kept = kept_samples(poly, 8, 15.0)
    np.testing.assert_array_equal(kept, [True, False, False, False, False, False, False, False])
    # Twelve samples every 5.69 m: the last at 62.6 m is still on edge 2.
    assert kept_samples(poly, 12, 15.0).sum() == 1
    assert kept_samples(poly, 12, 31.0).all()  # nothing reaches 31 m


def test_kept_samples_drop_the_depth_jumps() -> None:
    # Counter-clockwise from (2, -2): a radial jump edge out to the far wall x = 6, the
    # far wall, a jump edge back, the near wall x = 2 (vertex ranges 2.83, 8.49, 8.49,
    # 2.83).  Edge ranges differ by 5.66, 0, 5.66, 0: with max_jump 1 m edges 0 and 2
    # go.  Edge lengths 5.66, 12, 5.66, 4 (ends at s = 5.66, 17.66, 23.31, 27.31 m); 8
    # samples every 3.41 m: s = 0, 3.41 on edge 0; 6.83 .. 17.07 on edge 1; 20.49 on
    # edge 2; 23.90 on edge 3.
    v = np.array([[2.0, -2.0], [6.0, -6.0], [6.0, 6.0], [2.0, 2.0]])
    poly = Polygon(v)
    np.testing.assert_array_equal(poly.vertices, v)  # already counter-clockwise
    np.testing.assert_array_equal(kept_samples(poly, 8, 0.0, 1.0),
                                  [False, False, True, True, True, True, False, True])
    # max_range 5 m also drops the far wall (edge 1): only edge 3 is kept.
    np.testing.assert_array_equal(kept_samples(poly, 8, 5.0, 1.0),
                                  [False, False, False, False, False, False, False, True])
    assert kept_samples(poly, 8, 0.0, 6.0).all()


def test_border_distance_is_circular_in_samples() -> None:
    kept = np.array([True, True, False, True, True, True, True, True])
    np.testing.assert_array_equal(border_distance(kept), [2, 1, 0, 1, 2, 3, 4, 3])
    assert np.isinf(border_distance(np.ones(5, bool))).all()
    np.testing.assert_array_equal(border_distance(np.zeros(3, bool)), [0, 0, 0])


def test_option_path_equals_the_default_when_it_samples_the_same_points() -> None:
    # A step of perimeter / 256 gives the default's 256 samples, step and scales.
    poly = Polygon(np.array([[0.0, -1.0], [3.0, -1.0], [3.0, 2.0], [1.0, 2.0], [1.0, 1.0],
                             [-1.0, 1.0], [-1.0, -1.0]]))
    base = describe_polygon(poly, FlirtFeatureConfig())
    same = describe_polygon(poly, FlirtFeatureConfig(sample_step=poly.perimeter / 256))
    assert len(base) >= 3
    for name in ("points", "scales", "orientations", "responses", "occupancy", "evidence"):
        np.testing.assert_array_equal(getattr(same, name), getattr(base, name))


def test_no_interest_point_on_or_near_a_dropped_edge() -> None:
    v = np.array([[2.0, -2.0], [2.0, 2.0], [-30.0 / np.sqrt(2), 30.0 / np.sqrt(2)],
                  [-2.0, -2.0]])
    cfg = FlirtFeatureConfig(sample_step=0.1, max_range=15.0, min_features=1)
    f = describe_polygon(Polygon(v), cfg)
    assert len(f) >= 1
    # Every point lies on the kept edges (x = 2 or y = -2 within 4 m of the origin).
    assert (np.hypot(f.points[:, 0], f.points[:, 1]) < 3.0).all()
    # The corner (2, -2) between the two kept edges is found.
    assert np.hypot(*(f.points - [2.0, -2.0]).T).min() < 0.2
    # All edges dropped: a defined fallback descriptor, no error.
    f_none = describe_polygon(Polygon(v), FlirtFeatureConfig(max_range=1.0))
    assert len(f_none) == 4 and np.isfinite(f_none.occupancy).all()


def test_config_rejects_bad_sampling_values() -> None:
    for bad in ({"sample_step": -0.1}, {"max_range": float("nan")}, {"max_samples": 8},
                {"border_sigmas": -1.0}, {"max_jump": -1.0}):
        with pytest.raises(UserError):
            FlirtFeatureConfig(**bad)
    matcher = FlirtMatcher(sample_step=0.2, max_range=29.0)
    assert matcher.config.sample_step == 0.2
    assert FlirtConfig(max_range=29.0).features().max_range == 29.0


def _room() -> np.ndarray:
    """Walls of a 10 m x 6 m room with doorways in two walls (y 2..4 on the right, x
    3..5 at the top) and three boxes [m]."""
    def box(x0: float, y0: float, x1: float, y1: float) -> list:
        return [((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)),
                ((x0, y1), (x0, y0))]
    walls = [((0, 0), (10, 0)), ((10, 0), (10, 2)), ((10, 4), (10, 6)), ((10, 6), (5, 6)),
             ((3, 6), (0, 6)), ((0, 6), (0, 0))]
    walls += box(2, 1.5, 2.6, 2.1) + box(6, 3.5, 7, 4.2) + box(4, 0.8, 4.4, 1.2)
    return np.array(walls, float)


def _repeated_share(cfg: FlirtFeatureConfig, radius: float = 0.3) -> float:
    """Share of view A's keypoints with one of view B's within `radius` [m] once B's
    are moved into A's frame by the true relative pose."""
    laser = LaserModel(fov_deg=360.0, beams=360, max_range=30.0, noise_sigma=0.0, dropout=0.0)
    poses = np.array([[3.0, 3.0, 0.3], [4.2, 3.6, -1.0]])
    ranges = trace(_room(), poses, laser.angle_min, laser.angle_increment, laser.beams,
                   laser.max_range)
    ranges = np.where(np.isfinite(ranges), ranges, laser.max_range)  # no return
    a, b = (describe_polygon(polygon_from_scan(laser.scan(r, 0.0)), cfg) for r in ranges)
    rel = se2.between(poses[0], poses[1])  # p_A = R p_B + t
    c, s = np.cos(rel[2]), np.sin(rel[2])
    b_in_a = b.points @ np.array([[c, s], [-s, c]]) + rel[:2]
    d = np.hypot(*(a.points[:, None, :] - b_in_a[None]).transpose(2, 0, 1))
    return float((d.min(axis=1) <= radius).mean())


def test_metric_step_and_dropped_cap_repeat_better_between_two_views() -> None:
    # Each doorway lets beams out to the 30 m cap: the boundary is 163 m and 173 m
    # long in the two views, so 256 samples fall 0.64 / 0.67 m apart and at different
    # places on the walls; at 0.2 m and without the cap's arcs the same corners come
    # out in both views.
    default = _repeated_share(FlirtFeatureConfig())
    option = _repeated_share(FlirtFeatureConfig(sample_step=0.2, max_range=29.0))
    assert default < 0.4
    assert option > 0.5
