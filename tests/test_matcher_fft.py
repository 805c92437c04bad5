"""FFT matcher: range function, Fourier amplitudes, heading estimate, exact batched norms.

Registry, options, degenerate polygons, batching, rotation (to 1 % of the amplitudes)
and scale invariance and retrieval: test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.matchers.fft import (
    FFTDescriptor,
    FFTMatcher,
    heading_from_range_functions,
    range_function,
)
from loopclosure.polygon import Polygon
from tests.matcher_shapes import NOTCHED, SQUARE, random_star, room, smooth_star

# --- range function and descriptor -----------------------------------------------------------


def test_range_function_of_square_by_hand() -> None:
    r = range_function(SQUARE, np.zeros(2), 8)
    np.testing.assert_allclose(r, [1, np.sqrt(2)] * 4)


def test_range_function_of_rectangle_matches_formula() -> None:
    a, b = 2.0, 1.0
    rect = np.array([[a, -b], [a, b], [-a, b], [-a, -b]])
    theta = np.arange(64) * 2 * np.pi / 64
    with np.errstate(divide="ignore"):
        expected = np.minimum(a / np.abs(np.cos(theta)), b / np.abs(np.sin(theta)))
    np.testing.assert_allclose(range_function(rect, np.zeros(2), 64), expected, rtol=1e-12)


def test_non_star_shaped_polygon_farthest_and_nearest_hit() -> None:
    far = range_function(NOTCHED, np.zeros(2), 16, "farthest")
    near = range_function(NOTCHED, np.zeros(2), 16, "nearest")
    assert far[0] == pytest.approx(3.0)  # ray along +x
    assert near[0] == pytest.approx(1.0)
    assert far[8] == pytest.approx(1.0) and near[8] == pytest.approx(1.0)  # along -x


def test_centre_outside_polygon_gives_zero_range_bins() -> None:
    r = range_function(SQUARE + np.array([5.0, 0.0]), np.zeros(2), 32)
    assert np.all(np.isfinite(r))
    assert r[16] == 0.0  # pointing away from the square
    assert r[0] == pytest.approx(6.0)  # farthest hit: the far side


def test_circle_descriptor_is_mean_radius_and_no_harmonics() -> None:
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circle = Polygon(5.0 * np.column_stack([np.cos(t), np.sin(t)]) + [10.0, -4.0])
    d = FFTMatcher().describe(circle)
    assert d.amplitudes[0] == pytest.approx(5.0, rel=1e-5)
    assert np.all(d.amplitudes[1:] < 1e-5)
    np.testing.assert_allclose(d.centre, [10.0, -4.0], atol=1e-9)
    assert d.amplitudes.dtype == np.float32 and d.amplitudes.shape == (16,)


def test_square_descriptor_has_only_multiples_of_four() -> None:
    d = FFTMatcher(n_bins=256).describe(Polygon(SQUARE * 3))
    amp = d.amplitudes
    mult4 = np.arange(len(amp)) % 4 == 0
    assert np.all(amp[~mult4] < 1e-5 * amp[0])
    assert amp[4] > 0.01 * amp[0]


# --- heading --------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-3.1, 3.1))
def test_heading_recovers_rotation_of_smooth_room(seed: int, angle: float) -> None:
    m = FFTMatcher()
    p = smooth_star(np.random.default_rng(seed))
    est, score = m.heading(m.describe(p), m.describe(p.rotated(angle)))
    err = (est - angle + np.pi) % (2 * np.pi) - np.pi
    assert abs(err) < np.deg2rad(0.05)  # bins are 1.4 degrees: the parabola refines
    assert score > 0.99


def test_heading_of_spiky_polygons_is_sub_bin_on_average() -> None:
    m = FFTMatcher()
    errs = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        angle = rng.uniform(-3.1, 3.1)
        p = random_star(rng)
        est, score = m.heading(m.describe(p), m.describe(p.rotated(angle)))
        errs.append(abs((est - angle + np.pi) % (2 * np.pi) - np.pi))
        assert score > 0.8
    # Whole bins alone would give a median error of ~0.35 degrees (a quarter bin).
    assert np.median(errs) < np.deg2rad(0.2)
    assert max(errs) < np.deg2rad(1.0)


def test_heading_of_displaced_scan_of_same_room() -> None:
    rng = np.random.default_rng(7)
    p = room(1, rng)
    q = Polygon(p.vertices + rng.normal(0, 0.02, p.vertices.shape)).rotated(1.0)
    est, score = heading_from_range_functions(
        FFTMatcher().describe(p).range_function, FFTMatcher().describe(q).range_function
    )
    assert est == pytest.approx(1.0, abs=np.deg2rad(2))
    assert score > 0.8


def test_heading_of_constant_range_function_is_undefined_score_zero() -> None:
    assert heading_from_range_functions(np.ones(64), np.ones(64)) == (0.0, 0.0)
    with pytest.raises(UserError, match="r_a and r_b"):
        heading_from_range_functions(np.ones(64), np.ones(32))


def test_heading_by_hand_shift() -> None:
    r = np.zeros(64)
    r[10] = 1.0
    angle, score = heading_from_range_functions(r, np.roll(r, 5))
    assert angle == pytest.approx(5 * 2 * np.pi / 64)
    assert score == pytest.approx(1.0)


# --- batched distances ------------------------------------------------------------------------


def test_batched_distances_are_the_exact_norm() -> None:
    # The float32 expansion ||q||^2 + ||x||^2 - 2 q.x against the float64 norm.
    m = FFTMatcher()
    rng = np.random.default_rng(0)
    descs = [m.describe(random_star(rng)) for _ in range(30)]
    d = m.distances(descs[0], m.stack(descs))
    exact = np.linalg.norm(
        np.stack([x.amplitudes for x in descs]).astype(float) - descs[0].amplitudes, axis=1
    )
    np.testing.assert_allclose(d, exact, rtol=1e-3, atol=1e-5)


def test_large_database_query_is_accurate() -> None:
    m = FFTMatcher()
    rng = np.random.default_rng(1)
    rows = rng.uniform(0, 5, (20_000, 16)).astype(np.float32)
    rows[123] = rows[7] * 1.0001  # a near-duplicate: recomputed exactly
    descs = [FFTDescriptor(r, np.zeros(256), np.zeros(2)) for r in rows]
    stacked = m.stack(descs)
    d = m.distances(descs[7], stacked)
    exact = np.linalg.norm(rows.astype(float) - rows[7].astype(float), axis=1)
    assert d.dtype == np.float64 and d.shape == (20_000,)
    np.testing.assert_allclose(d, exact, rtol=1e-3, atol=1e-4)
    assert d[7] == 0.0
    assert d[123] == pytest.approx(exact[123], rel=1e-6)


def test_near_radius_describes_the_polygon_within_that_distance_of_the_sensor() -> None:
    # Square of half side 10 m about the sensor: its corners (14.1 m) are pulled to 4 m
    # along the diagonals, leaving the square of half side h = 4 / sqrt(2) = 2.83 m, whose
    # mean range about its centre is h (4 / pi) ln(tan(3 pi / 8)).
    d = FFTMatcher(near_radius=4.0).describe(Polygon(SQUARE * 10))
    h = 4.0 / np.sqrt(2.0)
    assert d.amplitudes[0] == pytest.approx(h * 4 / np.pi * np.log(np.tan(3 * np.pi / 8)), rel=1e-3)
    assert d.range_function.max() == pytest.approx(4.0, rel=1e-3)
    # A polygon already within the radius is described as without it.
    near = Polygon(SQUARE * 2)
    within = FFTMatcher(near_radius=4.0).describe(near).amplitudes
    np.testing.assert_array_equal(within, FFTMatcher().describe(near).amplitudes)


def test_near_radius_is_unused_when_scale_invariant_and_must_be_positive() -> None:
    p = Polygon(SQUARE * 10)
    a = FFTMatcher(scale_invariant=True, near_radius=4.0).describe(p).amplitudes
    np.testing.assert_array_equal(a, FFTMatcher(scale_invariant=True).describe(p).amplitudes)
    with pytest.raises(UserError):
        FFTMatcher(near_radius=-1.0)


def test_far_weight_appends_the_whole_polygons_amplitudes() -> None:
    p = Polygon(SQUARE * 10)
    m = FFTMatcher(near_radius=4.0, far_weight=0.5)
    d = m.describe(p)
    near = FFTMatcher(near_radius=4.0).describe(p)
    whole = FFTMatcher().describe(p)
    assert d.amplitudes.shape == (32,) and m.width == 32
    np.testing.assert_array_equal(d.amplitudes[:16], near.amplitudes)
    np.testing.assert_allclose(d.amplitudes[16:], 0.5 * whole.amplitudes, rtol=1e-6)
    np.testing.assert_array_equal(d.range_function, near.range_function)
    # Distance: sqrt(|near_a - near_b|^2 + w^2 |whole_a - whole_b|^2).  Squares of half
    # side 10 and 12 m have the same near polygon (corners pulled to 4 m), so only the
    # far term is left.
    q = Polygon(SQUARE * 12)
    dq = m.distance(d, m.describe(q))
    far = np.linalg.norm(
        FFTMatcher().describe(q).amplitudes.astype(float) - whole.amplitudes.astype(float))
    assert dq == pytest.approx(0.5 * far, rel=1e-4)
    with pytest.raises(UserError):
        FFTMatcher(far_weight=-0.1)
