"""Unit tests of loopclosure.polygon: geometry of `Polygon` and the scan -> polygon rule."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from data.types import Scan
from loopclosure.polygon import (
    DegeneratePolygonError,
    Polygon,
    PolygonConfig,
    polygon_from_scan,
    polygon_within,
    signed_area,
)

SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
# L-shape: the 2 x 2 square minus its top-right 1 x 1 quarter (area 3).
L_SHAPE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])


def full_scan(ranges: np.ndarray, max_range: float = 30.0, min_range: float = 0.0) -> Scan:
    n = len(ranges)
    angles = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return Scan(0.0, np.asarray(ranges, float), angles, max_range, min_range)


# --- geometry ------------------------------------------------------------------------


def test_square_area_perimeter_centroid() -> None:
    p = Polygon(SQUARE + np.array([3.0, -1.0]))
    assert p.area == pytest.approx(4.0)
    assert p.perimeter == pytest.approx(8.0)
    np.testing.assert_allclose(p.centroid(), [4.0, 0.0])
    np.testing.assert_allclose(p.edge_lengths(), [2.0, 2.0, 2.0, 2.0])


def test_l_shape_area_and_centroid_by_hand() -> None:
    # Centroid = (3 unit squares at (0.5,0.5), (1.5,0.5), (0.5,1.5)) / 3.
    p = Polygon(L_SHAPE)
    assert p.area == pytest.approx(3.0)
    np.testing.assert_allclose(p.centroid(), [2.5 / 3, 2.5 / 3])
    assert p.perimeter == pytest.approx(8.0)


def test_triangle_centroid_is_vertex_mean() -> None:
    v = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 6.0]])
    p = Polygon(v)
    assert p.area == pytest.approx(9.0)
    np.testing.assert_allclose(p.centroid(), v.mean(axis=0))


def test_clockwise_input_is_reversed_to_counter_clockwise() -> None:
    p = Polygon(SQUARE[::-1])
    assert signed_area(p.vertices) > 0
    assert p.area == pytest.approx(4.0)


def test_repeated_closing_vertex_and_duplicates_are_dropped() -> None:
    v = np.vstack([SQUARE[:1], SQUARE[:1], SQUARE[1:], SQUARE[:1]])
    p = Polygon(v)
    assert len(p) == 4
    assert p.area == pytest.approx(4.0)


def test_non_finite_vertices_are_dropped() -> None:
    v = np.vstack([SQUARE[:2], [[np.nan, 1.0]], SQUARE[2:]])
    assert len(Polygon(v)) == 4


@pytest.mark.parametrize(
    "vertices",
    [
        np.array([[0.0, 0.0], [1.0, 1.0]]),  # two points
        np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]),  # collinear: zero area
        np.zeros((5, 2)),  # one point repeated
        np.zeros((0, 2)),
    ],
)
def test_degenerate_polygons_raise_user_error(vertices: np.ndarray) -> None:
    with pytest.raises(DegeneratePolygonError):
        Polygon(vertices)
    assert issubclass(DegeneratePolygonError, UserError)


def test_resample_square_by_arc_length_from_vertex_zero() -> None:
    pts = Polygon(SQUARE).resample(8)
    expected = [[0, 0], [1, 0], [2, 0], [2, 1], [2, 2], [1, 2], [0, 2], [0, 1]]
    np.testing.assert_allclose(pts, expected, atol=1e-12)


def test_resample_is_equally_spaced_along_the_boundary() -> None:
    p = Polygon(L_SHAPE)
    pts = p.resample(16)  # perimeter 8: spacing 0.5, each point on an edge
    assert pts.shape == (16, 2)
    inside_or_on = p.contains(pts * 0.999 + 0.001 * p.centroid())
    assert inside_or_on.all()
    steps = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    assert steps.max() <= 0.5 + 1e-12  # chords never exceed the arc spacing


def test_contains_concave_polygon() -> None:
    p = Polygon(L_SHAPE)
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5], [-0.1, 0.5], [2.5, 2.5]])
    np.testing.assert_array_equal(p.contains(pts), [True, True, True, False, False, False])


def test_rotated_about_origin_and_translated() -> None:
    p = Polygon(SQUARE)
    r = p.rotated(np.pi / 2)
    np.testing.assert_allclose(r.vertices[1], [0.0, 2.0], atol=1e-12)  # (2, 0) -> (0, 2)
    np.testing.assert_allclose(r.centroid(), [-1.0, 1.0], atol=1e-12)
    assert r.area == pytest.approx(4.0)
    t = p.translated(np.array([1.0, -2.0]))
    np.testing.assert_allclose(t.centroid(), [2.0, -1.0])


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(3, 30),
    seed=st.integers(0, 2**31 - 1),
    angle=st.floats(-np.pi, np.pi),
    scale=st.floats(0.01, 1000.0),
)
def test_area_perimeter_invariant_under_rigid_motion_and_scale(
    n: int, seed: int, angle: float, scale: float
) -> None:
    rng = np.random.default_rng(seed)
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(0.5, 3.0, n)
    v = np.column_stack([r * np.cos(a), r * np.sin(a)])
    p = Polygon(v)
    q = Polygon(v * scale).rotated(angle).translated(np.array([5.0, -3.0]))
    assert q.area == pytest.approx(p.area * scale**2, rel=1e-9)
    assert q.perimeter == pytest.approx(p.perimeter * scale, rel=1e-9)
    c, s = np.cos(angle), np.sin(angle)
    expected = np.array([[c, -s], [s, c]]) @ (p.centroid() * scale) + [5.0, -3.0]
    np.testing.assert_allclose(q.centroid(), expected, atol=1e-9 * max(scale, 1.0))


# --- scan -> polygon ---------------------------------------------------------------------


def test_full_circle_scan_gives_regular_polygon_without_origin() -> None:
    n, r = 360, 2.0
    p = polygon_from_scan(full_scan(np.full(n, r)))
    assert len(p) == n
    assert p.area == pytest.approx(0.5 * n * r**2 * np.sin(2 * np.pi / n))
    np.testing.assert_allclose(p.centroid(), [0.0, 0.0], atol=1e-12)
    assert not np.any(np.all(p.vertices == 0.0, axis=1))


def test_no_return_beams_are_placed_at_the_capped_range() -> None:
    ranges = np.full(36, 2.0)
    ranges[5] = 8.0  # == max_range: no return
    scan = full_scan(ranges, max_range=8.0)
    p = polygon_from_scan(scan, PolygonConfig(range_cap=5.0))
    assert len(p) == 36
    dist = np.linalg.norm(p.vertices, axis=1)
    assert np.sort(dist)[-1] == pytest.approx(5.0)  # min(range_cap, max_range)
    assert np.sum(np.isclose(dist, 2.0)) == 35
    q = polygon_from_scan(scan, PolygonConfig(range_cap=50.0))
    assert np.linalg.norm(q.vertices, axis=1).max() == pytest.approx(8.0)


def test_long_real_returns_are_capped() -> None:
    ranges = np.full(36, 2.0)
    ranges[3] = 40.0
    p = polygon_from_scan(full_scan(ranges, max_range=80.0), PolygonConfig(range_cap=30.0))
    assert np.linalg.norm(p.vertices, axis=1).max() == pytest.approx(30.0)


def test_invalid_beams_are_dropped() -> None:
    ranges = np.full(36, 2.0)
    ranges[[1, 7, 20]] = [np.nan, 0.0, 0.05]
    ranges[30] = -np.inf
    p = polygon_from_scan(full_scan(ranges, min_range=0.1))
    assert len(p) == 32
    np.testing.assert_allclose(np.linalg.norm(p.vertices, axis=1), 2.0)


def test_positive_infinity_is_no_return_not_nan() -> None:
    # ROS (REP 117) reports "no return" as +inf: placed at the cap, never NaN.
    ranges = np.full(36, 2.0)
    ranges[4] = np.inf
    p = polygon_from_scan(full_scan(ranges, max_range=10.0))
    assert np.all(np.isfinite(p.vertices))
    assert np.linalg.norm(p.vertices, axis=1).max() == pytest.approx(10.0)


def test_partial_scan_is_closed_through_the_origin() -> None:
    n = 181  # -90 .. +90 degrees
    angles = np.linspace(-np.pi / 2, np.pi / 2, n)
    scan = Scan(0.0, np.full(n, 3.0), angles, 30.0)
    p = polygon_from_scan(scan)
    assert len(p) == n + 1
    assert np.any(np.all(np.isclose(p.vertices, 0.0), axis=1))
    # Half disc of radius 3 (as a fan of 180 triangles).
    assert p.area == pytest.approx(0.5 * 180 * 9.0 * np.sin(np.pi / 180))
    assert signed_area(p.vertices) > 0


def test_small_gap_is_not_closed_through_origin() -> None:
    n = 356  # 356 one-degree beams: a 4-degree gap < max_gap_deg = 10
    angles = np.deg2rad(np.arange(n) - 180.0)
    p = polygon_from_scan(Scan(0.0, np.full(n, 3.0), angles, 30.0))
    assert len(p) == n


def test_too_few_valid_beams_raise() -> None:
    ranges = np.full(36, np.nan)
    ranges[:2] = 1.0
    with pytest.raises(DegeneratePolygonError, match="usable beams"):
        polygon_from_scan(full_scan(ranges))
    with pytest.raises(DegeneratePolygonError):
        polygon_from_scan(full_scan(np.zeros(36)))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), invalid=st.floats(0.0, 0.5))
def test_random_scans_give_finite_counter_clockwise_polygons(seed: int, invalid: float) -> None:
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.5, 12.0, 360)
    r[rng.random(360) < invalid] = np.nan
    r[rng.random(360) < 0.1] = 10.0  # max range
    try:
        p = polygon_from_scan(full_scan(r, max_range=10.0))
    except DegeneratePolygonError:
        assert np.sum(np.isfinite(r)) < 3
        return
    assert np.all(np.isfinite(p.vertices))
    assert signed_area(p.vertices) > 0
    assert np.linalg.norm(p.vertices, axis=1).max() <= 10.0 + 1e-9


def test_square_far_from_origin_keeps_its_four_vertices() -> None:
    p = Polygon(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) + 1e6)
    assert len(p) == 4
    assert p.area == pytest.approx(1.0)


@given(st.integers(0, 10_000), st.integers(3, 300))
@settings(max_examples=40, deadline=None)
def test_resample_equals_interp_of_linspace_exactly(seed: int, n: int) -> None:
    # The fast resample must be bit-identical to the plain formulation every matcher
    # relied on: interp(linspace(0, L, n, endpoint=False), cumulative arc length, closed).
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 40))
    r = rng.uniform(0.5, 20.0, 40)
    p = Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))
    v = p.vertices
    closed = np.vstack([v, v[:1]])
    cum = np.concatenate([[0.0], np.cumsum(p.edge_lengths())])
    s = np.linspace(0.0, cum[-1], n, endpoint=False)
    ref = np.column_stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])])
    np.testing.assert_array_equal(p.resample(n), ref)


def test_polygon_within_pulls_far_vertices_onto_the_circle() -> None:
    # (4, 4) is sqrt(32) = 5.657 m from the origin: pulled to (5/sqrt 2, 5/sqrt 2);
    # (-1, -1) at 1.414 m, (4, -1) and (-1, 4) at 4.123 m stay.
    quad = Polygon(np.array([[-1.0, -1.0], [4.0, -1.0], [4.0, 4.0], [-1.0, 4.0]]))
    out = polygon_within(quad, 5.0)
    h = 5.0 / np.sqrt(2.0)
    np.testing.assert_allclose(out.vertices, [[-1.0, -1.0], [4.0, -1.0], [h, h], [-1.0, 4.0]])
    assert polygon_within(quad, 10.0) is quad


def test_polygon_within_equals_the_scan_rule_with_that_cap() -> None:
    angles = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    ranges = 3.0 + 4.0 * np.abs(np.sin(2.0 * angles))  # 3..7 m
    ranges[10:14] = 30.0  # no return
    ranges[40] = 25.0  # a long real return next to a short one
    whole = polygon_from_scan(full_scan(ranges))
    capped = polygon_from_scan(full_scan(ranges), PolygonConfig(range_cap=5.0))
    np.testing.assert_allclose(polygon_within(whole, 5.0).vertices, capped.vertices, atol=1e-12)


def test_polygon_within_merges_vertices_of_one_beam() -> None:
    # Two vertices on the ray at 0 degrees, 6 m and 8 m: both land on (5, 0).
    v = np.array([[2.0, -2.0], [6.0, 0.0], [8.0, 0.0], [2.0, 2.0], [-2.0, 0.0]])
    out = polygon_within(Polygon(v), 5.0)
    np.testing.assert_allclose(out.vertices, [[2.0, -2.0], [5.0, 0.0], [2.0, 2.0], [-2.0, 0.0]])


def test_polygon_within_rejects_a_non_positive_radius() -> None:
    with pytest.raises(UserError):
        polygon_within(Polygon(SQUARE - 1.0), 0.0)
