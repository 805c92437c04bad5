"""FLIRT matcher: detector and beta-grid formulas, RANSAC pose, invariances, bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data import se2
from loopclosure.matchers import get_matcher
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher
from loopclosure.matchers.flirt_features import (
    FlirtFeatureConfig,
    beta_grids,
    describe_polygon,
    detect,
    scale_levels,
    smoothed_curves,
)
from loopclosure.polygon import Polygon, polygon_from_scan
from tests.helpers import shared_file

SQUARE = Polygon(np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]))


def star(
    lobes: int, amp: float, n: int = 200, scale: float = 5.0, seed: int = 0, noise: float = 0.0
) -> Polygon:
    """Star-shaped 'room' around the origin: r = scale (1 + amp sin(lobes a) + 0.2 cos a)."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(-np.pi, np.pi, n, endpoint=False)
    r = scale * (1.0 + amp * np.sin(lobes * ang + 0.3) + 0.2 * np.cos(ang))
    r = r + rng.normal(0.0, noise * scale, n)
    return Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))


def circle_curve(radius: float, n: int) -> np.ndarray:
    a = 2.0 * np.pi * np.arange(n) / n
    return np.column_stack([radius * np.cos(a), radius * np.sin(a)])


# ---------------------------------------------------------------- formulas


def test_gaussian_smoothing_shrinks_a_circle_by_the_closed_form_factor() -> None:
    # Smoothing x = R cos(s / R) along arc length with a Gaussian of width sigma
    # multiplies it by exp(-sigma^2 / (2 R^2)).
    radius, n = 2.0, 256
    step = 2.0 * np.pi * radius / n
    sigmas = np.array([1.0, 4.0, 16.0])  # samples
    smooth, deriv = smoothed_curves(circle_curve(radius, n), sigmas)
    expected = radius * np.exp(-((sigmas * step) ** 2) / (2.0 * radius**2))
    np.testing.assert_allclose(np.linalg.norm(smooth, axis=-1), expected[:, None] * np.ones(n))
    # d/ds of the smoothed curve per sample: speed = factor * step (tangent length).
    speed = (expected * step / radius)[:, None] * np.ones(n)
    np.testing.assert_allclose(np.linalg.norm(deriv, axis=-1), speed)


def test_scale_normalised_displacement_of_a_circle() -> None:
    # delta(sigma) = (R - R exp(-u^2 / 2)) / sigma with u = sigma / R, the same at every point.
    radius, n = 3.0, 256
    cfg = FlirtFeatureConfig(n_samples=n)
    step = 2.0 * np.pi * radius / n
    _, _, delta = detect(circle_curve(radius, n), step, cfg)
    u = scale_levels(cfg) * step / radius
    expected = (1.0 - np.exp(-(u**2) / 2.0)) / u
    np.testing.assert_allclose(delta, expected[:, None] * np.ones(n), rtol=1e-9)


def test_square_corners_are_the_interest_points() -> None:
    # A right-angle corner is displaced by sigma (a + b) / sqrt(2 pi) under smoothing:
    # delta = 2 cos(45 deg) / sqrt(2 pi) = 0.5642, positive (convex).
    feats = describe_polygon(SQUARE, FlirtFeatureConfig())
    assert len(feats) == 4
    np.testing.assert_allclose(np.sort(np.abs(feats.points), axis=0), 2.0)
    np.testing.assert_allclose(feats.responses, np.sqrt(2.0) / np.sqrt(2.0 * np.pi), atol=1e-3)
    # Orientation = outward normal = the diagonal through the corner.
    np.testing.assert_allclose(
        feats.orientations, np.arctan2(feats.points[:, 1], feats.points[:, 0]), atol=1e-9
    )


def test_beta_grid_hand_case() -> None:
    # One grid of radius 1 at the origin, 1 ring x 4 sectors (sector 0 centred on +x).
    # A beam from (-5, 0.1) ends at (0.5, 0.1): it crosses sectors 2 and 1 and ends in 0.
    cfg = FlirtFeatureConfig(rings=1, sectors=4, support_factor=2.0, chord_samples=10)
    ends = np.array([[0.5, 0.1], [-5.0, 3.0]])  # the second beam misses the disc
    occ, var = beta_grids(
        np.zeros((1, 2)), np.array([0.5]), np.zeros(1), ends, np.array([-5.0, 0.1]), cfg
    )
    # Beta(1, 1) prior: occ = (hits + 1) / (hits + misses + 2).
    np.testing.assert_allclose(occ[0], [2 / 3, 1 / 3, 1 / 3, 1 / 2])
    np.testing.assert_allclose(var[0], [1 / 18, 1 / 18, 1 / 18, 1 / 12])


def test_featureless_circle_gets_fallback_points() -> None:
    circle = Polygon(circle_curve(4.0, 256))
    feats = describe_polygon(circle, FlirtFeatureConfig())
    assert len(feats) == FlirtFeatureConfig().min_features + 1
    assert np.all(feats.responses == 0.0)
    m = FlirtMatcher()
    assert m.distance(m.describe(circle), m.describe(circle.rotated(0.4))) < 1e-9
    assert 0.0 <= m.distance(m.describe(circle), m.describe(SQUARE)) <= 2.0


# ---------------------------------------------------------------- matching


def test_identical_shapes_have_distance_zero() -> None:
    m = FlirtMatcher()
    for poly in (SQUARE, star(3, 0.3), Polygon(np.array([[0, 0], [3, 0], [0.5, 2.0]]))):
        d = m.describe(poly)
        res = m.match(d, d)
        assert res.distance == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(res.pose, 0.0, atol=1e-9)
        assert len(res.inliers) == len(d)


def test_ransac_recovers_a_rigid_transform() -> None:
    # Centroid viewpoint: the descriptors are then invariant to any rigid motion.
    m = FlirtMatcher(viewpoint="centroid")
    base = star(4, 0.25, seed=1, noise=0.002)
    pose = np.array([3.0, -2.0, 0.8])  # pose of `base`'s frame in the moved frame
    moved = Polygon(se2.transform_points(pose, base.vertices))
    res = m.match(m.describe(moved), m.describe(base))
    np.testing.assert_allclose(res.pose, pose, atol=1e-9)
    assert len(res.inliers) == len(m.describe(base))
    assert res.distance < 1e-9


def test_distance_is_monotone_in_match_quality() -> None:
    m = FlirtMatcher()
    a = star(3, 0.3, seed=2)
    da = m.describe(a)
    near = m.distance(da, m.describe(star(3, 0.3, seed=3, noise=0.002)))
    far = m.distance(da, m.describe(star(5, 0.3, seed=4)))
    assert 0.0 < near < 1.0 <= far <= 2.0


def test_scale_matters_unless_asked_otherwise() -> None:
    room = star(3, 0.3)
    big = Polygon(room.vertices * 1.5)
    m = FlirtMatcher()
    assert m.distance(m.describe(room), m.describe(big)) >= 1.0
    inv = FlirtMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(room), inv.describe(big)) < 1e-9


def test_batched_equals_single() -> None:
    m = FlirtMatcher()
    polys = [star(3, 0.3), star(4, 0.2, seed=5), SQUARE, star(3, 0.3, seed=6, noise=0.003)]
    descs = [m.describe(p) for p in polys]
    batched = m.distances(descs[0], m.stack(descs))
    single = [m.distance(descs[0], d) for d in descs]
    np.testing.assert_allclose(batched, single, atol=1e-12)
    assert batched[0] == pytest.approx(0.0, abs=1e-12)


def test_deterministic_and_seeded() -> None:
    # Enough features that RANSAC samples its hypotheses.
    a, b = star(5, 0.3, n=400), star(5, 0.3, n=400, seed=8, noise=0.004)
    m = FlirtMatcher(max_hypotheses=50)
    da, db = m.describe(a), m.describe(b)
    assert m.distance(da, db) == m.distance(da, db)
    np.testing.assert_array_equal(m.match(da, db).inliers, m.match(da, db).inliers)


def test_retrieval_sanity_same_kind_is_nearest() -> None:
    m = FlirtMatcher()
    rng = np.random.default_rng(11)
    shapes, kinds = [], []
    for lobes in (3, 4, 5):
        for i in range(4):
            p = star(lobes, 0.25, seed=100 * lobes + i, noise=0.003)
            shapes.append(p.rotated(float(rng.uniform(-np.pi, np.pi))))
            kinds.append(lobes)
    d = m.pairwise([m.describe(p) for p in shapes])
    np.fill_diagonal(d, np.inf)
    kinds_arr = np.array(kinds)
    assert np.all(kinds_arr[np.argmin(d, axis=1)] == kinds_arr)


# ---------------------------------------------------------------- invariance


@settings(max_examples=20, deadline=None)
@given(
    lobes=st.integers(2, 6),
    amp=st.floats(0.1, 0.4),
    seed=st.integers(0, 10_000),
    angle=st.floats(-np.pi, np.pi),
)
def test_rotation_about_the_sensor_gives_the_same_descriptor_match(
    lobes: int, amp: float, seed: int, angle: float
) -> None:
    m = FlirtMatcher()
    a = star(lobes, amp, seed=seed, noise=0.003)
    da = m.describe(a)
    # A polygon and its rotated copy match exactly (up to rounding).
    assert m.distance(da, m.describe(a.rotated(angle))) < 1e-9
    # distance(a, b) with b rotated: the same up to rounding for pairs that match.
    # Pairs that RANSAC rejects can pick another of several near-equal-cost
    # hypotheses after rounding (or a beam chord that grazes a grid flips), which
    # moves their distance, always in [1, 2], by a few hundredths at most
    # (largest seen in 60 random pairs: 0.033; matching pairs: 0.0014).
    b = star(lobes + 1, amp, seed=seed + 1, noise=0.003)
    same_place = star(lobes, amp, seed=seed + 2, noise=0.003)
    for other, tol in ((same_place, 0.01), (b, 0.06)):
        db = m.describe(other)
        dr = m.describe(other.rotated(angle))
        d0, d1 = m.distance(da, db), m.distance(da, dr)
        assert abs(d0 - d1) <= tol


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "vertices",
    [
        [[0, 0], [3, 0], [0.5, 2.0]],  # triangle
        [[0, 0], [10, 0], [10, 0.01], [0, 0.01]],  # very thin
        [[0, 0], [0, 0], [4, 0], [4, 0], [4, 3], [0, 3], [0, 3]],  # duplicate points
    ],
)
def test_degenerate_but_valid_polygons_are_finite(vertices: list[list[float]]) -> None:
    m = FlirtMatcher()
    p = Polygon(np.array(vertices, dtype=float))
    d = m.describe(p)
    for arr in (d.points, d.scales, d.orientations, d.occupancy, d.variance):
        assert np.all(np.isfinite(arr))
    assert m.distance(d, d) == pytest.approx(0.0, abs=1e-12)
    dist = m.distances(d, m.stack([d, m.describe(SQUARE), m.describe(star(3, 0.3))]))
    assert np.all(np.isfinite(dist)) and np.all(dist >= 0.0) and np.all(dist <= 2.0)


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_huge_and_tiny_polygons(scale: float) -> None:
    m = FlirtMatcher()
    p = Polygon(star(3, 0.3).vertices * scale)
    d = m.describe(p)
    assert np.all(np.isfinite(d.occupancy)) and len(d) >= 3
    assert m.distance(d, d) == pytest.approx(0.0, abs=1e-12)
    assert m.distance(d, m.describe(p.rotated(1.0))) < 1e-9


def test_config_overrides_and_errors() -> None:
    m = get_matcher("flirt", candidates=2, max_hypotheses=100)
    assert isinstance(m, FlirtMatcher)
    assert m.config.candidates == 2 and m.config.max_hypotheses == 100
    base = FlirtConfig(rings=3)
    assert FlirtMatcher(base, sectors=8).config.rings == 3
    with pytest.raises(TypeError, match="unknown FLIRT option"):
        FlirtMatcher(not_an_option=1)
    with pytest.raises(ValueError):
        FlirtMatcher(descriptor_distance="cosine")
    with pytest.raises(ValueError):
        FlirtMatcher(viewpoint="nowhere")


# ---------------------------------------------------------------- real and simulated data


def test_consecutive_real_scans_match_with_the_corrected_pose() -> None:
    """Intel lab (GMapping-corrected): FLIRT's transform ~ the pose change of the robot."""
    from data.carmen import CarmenLog

    path = shared_file("carmen-corrected/intel-corrected.log.gz")
    scans = list(itertools.islice(CarmenLog(path), 150))
    m = FlirtMatcher()
    errors, same = [], []
    for i in range(0, 148, 4):
        a, b = scans[i], scans[i + 1]
        res = m.match(m.describe(polygon_from_scan(a)), m.describe(polygon_from_scan(b)))
        truth = se2.between(a.odom, b.odom)
        errors.append(
            [np.hypot(*(res.pose[:2] - truth[:2])), abs(se2.wrap_angle(res.pose[2] - truth[2]))]
        )
        same.append(res.distance < 1.0)
    err = np.median(np.array(errors), axis=0)
    # Median motion between the pairs: 1.0 m, 4 degrees; measured median error of
    # FLIRT's transform 0.19 m, 1.2 degrees; 34 of 37 pairs declared the same place.
    assert err[0] < 0.3 and err[1] < 0.05
    assert np.mean(same) >= 0.7


def test_simulated_places_are_recognised() -> None:
    sim = pytest.importorskip("data.sim")
    data = sim.place_dataset("box", places=3, scans_per_place=4, seed=3)
    labels = np.array([label for label, _ in data])
    m = FlirtMatcher()
    d = m.pairwise([m.describe(polygon_from_scan(scan)) for _, scan in data])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[np.argmin(d, axis=1)] == labels) >= 0.9
