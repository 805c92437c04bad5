"""Ring projection matcher: the exact circle-inside measure, by hand and against sampling.

The exact profile makes ring projection rotation invariant to float32 rounding (1e-4);
that and the other shared clauses are tested in test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.matchers.ring_projection import RingProjectionMatcher, ring_profile
from loopclosure.polygon import Polygon
from tests.matcher_shapes import C_SHAPE, NOTCHED, SQUARE, random_star


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
    p = random_star(np.random.default_rng(seed), n=20)
    c = p.centroid() + np.random.default_rng(seed).normal(0, 0.5, 2)
    exact = ring_profile(p.vertices, c, 0.35, 20)
    # 4,000 samples: each of the (at most ~20) crossings of a circle is off by at most
    # half a sample, pi / 4000.
    sampled = monte_carlo_profile(p, c, 0.35, 20, samples=4000)
    np.testing.assert_allclose(exact, sampled, atol=20 * np.pi / 4000)


# --- batched distances ------------------------------------------------------------------------


@pytest.mark.parametrize("norm", ["l2", "l1"])
def test_batched_distances_are_the_exact_norm(norm: str) -> None:
    # float32 profiles (and, for l2, the expansion ||q||^2 + ||x||^2 - 2 q.x) against the
    # float64 norm of the differences.
    m = RingProjectionMatcher(norm=norm)
    rng = np.random.default_rng(0)
    descs = [m.describe(random_star(rng)) for _ in range(25)]
    d = m.distances(descs[0], m.stack(descs))
    diff = np.stack(descs).astype(float) - descs[0]
    exact = np.abs(diff).sum(axis=1) if norm == "l1" else np.linalg.norm(diff, axis=1)
    np.testing.assert_allclose(d, exact, rtol=1e-3, atol=1e-5)


def test_l1_and_l2_distances_of_arc_lengths_by_hand() -> None:
    # Rings at 0.5 and 1.5 m.  A square of half-side 0.25 m lies within both circles,
    # which never enter it: profile (0, 0).  A square of half-side 2 m contains both
    # circles: arcs (pi, 3 pi) [m].
    def square(h: float) -> Polygon:
        return Polygon(np.array([[-h, -h], [h, -h], [h, h], [-h, h]]))
    small, big = square(0.25), square(2.0)
    l1 = RingProjectionMatcher(n_rings=2, max_radius=2.0, norm="l1")
    np.testing.assert_allclose(l1.describe(big), [np.pi, 3 * np.pi], rtol=1e-6)
    assert l1.distance(l1.describe(small), l1.describe(big)) == pytest.approx(4 * np.pi, rel=1e-6)
    l2 = RingProjectionMatcher(n_rings=2, max_radius=2.0)  # the default norm
    assert l2.distance(l2.describe(small), l2.describe(big)) == pytest.approx(
        np.sqrt(10) * np.pi, rel=1e-6)


def test_near_radius_describes_the_polygon_within_that_distance_of_the_sensor() -> None:
    # Square of half side 10 m about the sensor: its corners (14.1 m) are pulled to 4 m
    # along the diagonals, leaving the square of half side h = 4 / sqrt(2) = 2.83 m.
    p = Polygon(SQUARE * 10)
    m = RingProjectionMatcher(arc_length=False, n_rings=20, max_radius=5.0, near_radius=4.0)
    h = 4.0 / np.sqrt(2.0)
    g = (np.arange(20) + 0.5) * 0.25
    corners = 1 - 4 / np.pi * np.arccos(np.minimum(h / g, 1))
    expected = np.where(g < h, 1.0, np.where(g < 4.0, corners, 0.0))
    np.testing.assert_allclose(m.describe(p), expected, atol=1e-6)
    # A polygon already within the radius is described as without it.
    near = Polygon(SQUARE * 2)
    np.testing.assert_array_equal(
        m.describe(near), RingProjectionMatcher(arc_length=False, n_rings=20,
                                                max_radius=5.0).describe(near))


def test_near_radius_is_unused_when_scale_invariant_and_must_be_positive() -> None:
    p = Polygon(SQUARE * 10)
    a = RingProjectionMatcher(scale_invariant=True, near_radius=4.0).describe(p)
    np.testing.assert_array_equal(a, RingProjectionMatcher(scale_invariant=True).describe(p))
    with pytest.raises(UserError):
        RingProjectionMatcher(near_radius=0.0)
