"""Ring projection matcher: exact circle-inside measure, invariances, batched distances."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.matchers import get_matcher
from loopclosure.matchers.ring_projection import RingConfig, RingProjectionMatcher, ring_profile
from loopclosure.polygon import Polygon
from tests.helpers import shared_file

SQUARE = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
NOTCHED = np.array(
    [[-1, -1], [3, -1], [3, 1], [2, 1], [2, -0.5], [1, -0.5], [1, 1], [-1, 1]], dtype=float
)
C_SHAPE = np.array(  # centroid outside the polygon
    [[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [4, 3], [4, 4], [0, 4]], dtype=float
)


def star_polygon(rng: np.random.Generator, n: int = 40) -> Polygon:
    """Random star-shaped polygon about the origin, radii 2-6 m."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(2, 6, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def room(kind: int, rng: np.random.Generator) -> Polygon:
    base = {
        0: np.array([[0, 0], [8, 0], [8, 5], [0, 5]], float),
        1: np.array([[0, 0], [8, 0], [8, 3], [3, 3], [3, 8], [0, 8]], float),
        2: np.array([[0, 0], [12, 0], [12, 2], [0, 2]], float),
    }[kind]
    pts = Polygon(base).resample(120) + rng.normal(0, 0.03, (120, 2))
    return Polygon(pts).rotated(rng.uniform(-np.pi, np.pi)).translated(rng.normal(0, 1, 2))


def monte_carlo_profile(
    p: Polygon, centre: np.ndarray, step: float, n: int, samples: int = 20_000
) -> np.ndarray:
    theta = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    gam = (np.arange(n) + 0.5) * step
    pts = centre + (gam[:, None, None] * np.stack([np.cos(theta), np.sin(theta)], -1))
    return p.contains(pts.reshape(-1, 2)).reshape(n, -1).mean(axis=1) * 2 * np.pi


# --- hand-checked profiles --------------------------------------------------------------------


def test_square_profile_by_hand() -> None:
    # Circle of radius g about the centre of the square [-1, 1]^2: fully inside for g < 1,
    # for 1 < g < sqrt(2) the four corners keep 8 * (pi/4 - arccos(1/g)) ... i.e. the angle
    # inside is 2 pi - 8 arccos(1 / g); outside beyond sqrt(2).
    f = ring_profile(SQUARE, np.zeros(2), 0.1, 16)
    g = (np.arange(16) + 0.5) * 0.1
    corners = 2 * np.pi - 8 * np.arccos(np.minimum(1 / g, 1))
    expected = np.where(g < 1, 2 * np.pi, np.where(g < np.sqrt(2), corners, 0.0))
    np.testing.assert_allclose(f, expected, atol=1e-12)


def test_circle_profile_is_a_step() -> None:
    t = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    circle = 3.0 * np.column_stack([np.cos(t), np.sin(t)])
    f = ring_profile(circle, np.zeros(2), 0.25, 20)
    g = (np.arange(20) + 0.5) * 0.25
    np.testing.assert_allclose(f, np.where(g < 3.0, 2 * np.pi, 0.0), atol=1e-12)


def test_descriptor_fraction_and_arc_length_of_square() -> None:
    p = Polygon(SQUARE * 4)  # half side 4 m
    frac = RingProjectionMatcher(arc_length=False, n_rings=10, max_radius=10.0).describe(p)
    assert frac.dtype == np.float32
    g = np.arange(10) + 0.5
    corners = 1 - 4 / np.pi * np.arccos(np.minimum(4 / g, 1))
    expected = np.where(g < 4, 1.0, np.where(g < 4 * np.sqrt(2), corners, 0.0))
    np.testing.assert_allclose(frac, expected, atol=1e-6)
    arc = RingProjectionMatcher(arc_length=True, n_rings=10, max_radius=10.0).describe(p)
    np.testing.assert_allclose(arc, 2 * np.pi * g * expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("vertices", [NOTCHED, C_SHAPE, SQUARE * 3])
def test_exact_profile_agrees_with_sampled_point_in_polygon(vertices: np.ndarray) -> None:
    p = Polygon(vertices)
    c = p.centroid()
    step = 0.2
    exact = ring_profile(p.vertices, c, step, 20)
    # 20,000 samples per circle: each crossing is off by at most half a sample.
    np.testing.assert_allclose(exact, monte_carlo_profile(p, c, step, 20), atol=1e-3)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_exact_profile_agrees_with_sampling_on_random_polygons(seed: int) -> None:
    p = star_polygon(np.random.default_rng(seed), n=20)
    c = p.centroid() + np.random.default_rng(seed).normal(0, 0.5, 2)
    exact = ring_profile(p.vertices, c, 0.35, 20)
    # 4,000 samples: each of the (at most ~20) crossings of a circle is off by at most
    # half a sample, pi / 4000.
    sampled = monte_carlo_profile(p, c, 0.35, 20, samples=4000)
    np.testing.assert_allclose(exact, sampled, atol=20 * np.pi / 4000)


# --- invariances ------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_to_rotated_copy_is_zero(seed: int, angle: float) -> None:
    m = RingProjectionMatcher()
    p = star_polygon(np.random.default_rng(seed))
    # The profile is exact, so only rounding differs (float32 descriptors).
    assert m.distance(m.describe(p), m.describe(p.rotated(angle))) < 1e-4


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_unchanged_when_one_polygon_rotates(seed: int, angle: float) -> None:
    m = RingProjectionMatcher()
    rng = np.random.default_rng(seed)
    p, q = star_polygon(rng), star_polygon(rng)
    a, b, b_rot = m.describe(p), m.describe(q), m.describe(q.rotated(angle))
    assert m.distance(a, b) == pytest.approx(m.distance(a, b_rot), abs=1e-4)


def test_scale_invariant_option() -> None:
    p = star_polygon(np.random.default_rng(2))
    big = Polygon(p.vertices * 6.0)
    inv = RingProjectionMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(p), inv.describe(big)) < 1e-4
    plain = RingProjectionMatcher()
    assert plain.distance(plain.describe(p), plain.describe(big)) > 1.0


# --- batched distances ------------------------------------------------------------------------


@pytest.mark.parametrize("norm", ["l2", "l1"])
def test_batched_equals_single_and_exact(norm: str) -> None:
    m = RingProjectionMatcher(norm=norm)
    rng = np.random.default_rng(0)
    descs = [m.describe(star_polygon(rng)) for _ in range(25)]
    d = m.distances(descs[0], m.stack(descs))
    single = np.array([m.distance(descs[0], x) for x in descs])
    np.testing.assert_allclose(d, single, rtol=1e-5, atol=1e-6)
    diff = np.stack(descs).astype(float) - descs[0]
    exact = np.abs(diff).sum(axis=1) if norm == "l1" else np.linalg.norm(diff, axis=1)
    np.testing.assert_allclose(d, exact, rtol=1e-3, atol=1e-5)
    assert d[0] == 0.0
    assert m.distances(m.describe(Polygon(SQUARE)), m.stack([])).shape == (0,)


# --- degenerate polygons ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "vertices",
    [
        np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
        np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 0.01], [0.0, 0.01]]),
        SQUARE * 1e6,
        SQUARE * 1e-3,
        np.array([[0, 0], [1, 0], [1, 0], [1, 1], [0, 1], [0, 0]], float),
        C_SHAPE,
    ],
)
@pytest.mark.parametrize("scale_invariant", [False, True])
def test_degenerate_polygons_give_finite_descriptors(
    vertices: np.ndarray, scale_invariant: bool
) -> None:
    m = RingProjectionMatcher(scale_invariant=scale_invariant)
    d = m.describe(Polygon(vertices))
    assert np.all(np.isfinite(d)) and np.all(d >= 0)
    dist = m.distance(d, m.describe(Polygon(SQUARE)))
    assert np.isfinite(dist) and dist >= 0
    assert m.distance(d, d) == 0.0


def test_registry_and_config_errors() -> None:
    m = get_matcher("ring", n_rings=12)
    assert isinstance(m, RingProjectionMatcher) and m.config.n_rings == 12
    assert m.describe(Polygon(SQUARE)).shape == (12,)
    assert RingProjectionMatcher(RingConfig(max_radius=5.0)).config.max_radius == 5.0
    with pytest.raises(TypeError):
        RingProjectionMatcher(rings=3)
    with pytest.raises(ValueError):
        RingProjectionMatcher(max_radius=-1.0)
    with pytest.raises(ValueError):
        RingProjectionMatcher(norm="cosine")


# --- retrieval --------------------------------------------------------------------------------


def test_nearest_neighbour_is_same_kind_of_room() -> None:
    m = RingProjectionMatcher()
    rng = np.random.default_rng(11)
    kinds = np.repeat(np.arange(3), 6)
    d = m.pairwise([m.describe(room(k, rng)) for k in kinds])
    np.fill_diagonal(d, np.inf)
    assert np.all(kinds[d.argmin(axis=1)] == kinds)


def test_mpeg7_retrieval_on_real_shapes() -> None:
    folder = shared_file("mpeg7-subset")
    from data.mpeg7 import load_silhouettes

    shapes = [s for s in load_silhouettes(folder) if s.label in ("apple", "bone", "key")]
    labels = np.array([s.label for s in shapes])
    m = RingProjectionMatcher(scale_invariant=True)
    d = m.pairwise([m.describe(Polygon(s.contour)) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[d.argmin(axis=1)] == labels) > 0.8
