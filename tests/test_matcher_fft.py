"""FFT matcher: range function, Fourier amplitudes, heading estimate, batched distances."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.matchers import get_matcher
from loopclosure.matchers.fft import (
    FFTConfig,
    FFTDescriptor,
    FFTMatcher,
    heading_from_range_functions,
    range_function,
)
from loopclosure.polygon import Polygon
from tests.helpers import shared_file

SQUARE = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
# Box [-1, 3] x [-1, 1] with a notch [1, 2] x [-0.5, 1] cut from the top: the ray along
# +x from the origin leaves at x = 1, re-enters at x = 2 and leaves again at x = 3.
NOTCHED = np.array(
    [[-1, -1], [3, -1], [3, 1], [2, 1], [2, -0.5], [1, -0.5], [1, 1], [-1, 1]], dtype=float
)


def star_polygon(rng: np.random.Generator, n: int = 40, smooth: bool = True) -> Polygon:
    """Random star-shaped polygon about the origin, radii 2-6 m ("a room")."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    if smooth:
        k = np.arange(1, 5)
        r = 4 + (rng.normal(0, 0.5, (4, 1)) * np.cos(k[:, None] * a + rng.uniform(0, 6, (4, 1))))
        r = r.sum(axis=0) - 3 * 4
    else:
        r = rng.uniform(2, 6, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def room(kind: int, rng: np.random.Generator) -> Polygon:
    """Three kinds of place, with noisy vertices and a random pose."""
    base = {
        0: np.array([[0, 0], [8, 0], [8, 5], [0, 5]], float),  # rectangle room
        1: np.array([[0, 0], [8, 0], [8, 3], [3, 3], [3, 8], [0, 8]], float),  # L room
        2: np.array([[0, 0], [12, 0], [12, 2], [0, 2]], float),  # corridor
    }[kind]
    poly = Polygon(base)
    pts = poly.resample(120) + rng.normal(0, 0.03, (120, 2))
    return Polygon(pts).rotated(rng.uniform(-np.pi, np.pi)).translated(rng.normal(0, 1, 2))


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


# --- invariances ------------------------------------------------------------------------------

# Tolerance of the rotation tests: a rotation by an angle that is not a multiple of the bin
# width samples the range function at other angles; for these smooth rooms (radii 2-6 m,
# 4 harmonics) the difference of the 16 amplitudes stays below 1 % of the descriptor norm.
ROT_TOL = 0.01


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_to_rotated_copy_is_near_zero(seed: int, angle: float) -> None:
    m = FFTMatcher()
    p = star_polygon(np.random.default_rng(seed))
    a, b = m.describe(p), m.describe(p.rotated(angle))
    assert m.distance(a, b) <= ROT_TOL * np.linalg.norm(a.amplitudes)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_unchanged_when_one_polygon_rotates(seed: int, angle: float) -> None:
    m = FFTMatcher()
    rng = np.random.default_rng(seed)
    p, q = star_polygon(rng), star_polygon(rng)
    a, b, b_rot = m.describe(p), m.describe(q), m.describe(q.rotated(angle))
    scale = np.linalg.norm(b.amplitudes)
    assert abs(m.distance(a, b) - m.distance(a, b_rot)) <= ROT_TOL * scale


def test_scale_invariant_option() -> None:
    p = star_polygon(np.random.default_rng(3))
    big = Polygon(p.vertices * 7.5)
    inv = FFTMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(p), inv.describe(big)) < 1e-6
    plain = FFTMatcher()
    assert plain.distance(plain.describe(p), plain.describe(big)) > 1.0


# --- heading --------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-3.1, 3.1))
def test_heading_recovers_rotation_of_smooth_room(seed: int, angle: float) -> None:
    m = FFTMatcher()
    p = star_polygon(np.random.default_rng(seed))
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
        p = star_polygon(rng, smooth=False)
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
    with pytest.raises(ValueError):
        heading_from_range_functions(np.ones(64), np.ones(32))


def test_heading_by_hand_shift() -> None:
    r = np.zeros(64)
    r[10] = 1.0
    angle, score = heading_from_range_functions(r, np.roll(r, 5))
    assert angle == pytest.approx(5 * 2 * np.pi / 64)
    assert score == pytest.approx(1.0)


# --- batched distances ------------------------------------------------------------------------


def test_batched_equals_single_and_exact_norm() -> None:
    m = FFTMatcher()
    rng = np.random.default_rng(0)
    descs = [m.describe(star_polygon(rng, smooth=False)) for _ in range(30)]
    stacked = m.stack(descs)
    d = m.distances(descs[0], stacked)
    single = np.array([m.distance(descs[0], x) for x in descs])
    np.testing.assert_allclose(d, single, rtol=1e-5, atol=1e-6)
    exact = np.linalg.norm(
        np.stack([x.amplitudes for x in descs]).astype(float) - descs[0].amplitudes, axis=1
    )
    np.testing.assert_allclose(d, exact, rtol=1e-3, atol=1e-5)
    assert d[0] == 0.0
    assert m.distance(descs[3], descs[4]) == m.distances(descs[3], m.stack([descs[4]]))[0]


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


def test_empty_stack() -> None:
    m = FFTMatcher()
    d = m.distances(m.describe(Polygon(SQUARE)), m.stack([]))
    assert d.shape == (0,)


# --- degenerate polygons ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "vertices",
    [
        np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),  # triangle
        np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 0.01], [0.0, 0.01]]),  # very thin
        SQUARE * 1e6,  # huge
        SQUARE * 1e-3,  # small
        np.array([[0, 0], [1, 0], [1, 0], [1, 1], [0, 1], [0, 0]], float),  # duplicates
        NOTCHED,
    ],
)
@pytest.mark.parametrize("scale_invariant", [False, True])
def test_degenerate_polygons_give_finite_descriptors(
    vertices: np.ndarray, scale_invariant: bool
) -> None:
    m = FFTMatcher(scale_invariant=scale_invariant)
    d = m.describe(Polygon(vertices))
    assert np.all(np.isfinite(d.amplitudes)) and np.all(np.isfinite(d.range_function))
    other = m.describe(Polygon(SQUARE))
    dist = m.distance(d, other)
    assert np.isfinite(dist) and dist >= 0
    assert m.distance(d, d) == 0.0


# --- config and registry ----------------------------------------------------------------------


def test_registry_and_overrides() -> None:
    m = get_matcher("fft", n_harmonics=8, scale_invariant=True)
    assert isinstance(m, FFTMatcher) and m.rotation_invariant
    assert m.config.n_harmonics == 8 and m.config.scale_invariant
    assert FFTMatcher(FFTConfig(n_bins=128)).config.n_bins == 128
    with pytest.raises(TypeError):
        FFTMatcher(bins=3)
    with pytest.raises(ValueError):
        FFTMatcher(ray_hit="middle")
    with pytest.raises(ValueError):
        FFTMatcher(n_bins=64, n_harmonics=40)


# --- retrieval --------------------------------------------------------------------------------


def test_nearest_neighbour_is_same_kind_of_room() -> None:
    m = FFTMatcher()
    rng = np.random.default_rng(11)
    kinds = np.repeat(np.arange(3), 6)
    descs = [m.describe(room(k, rng)) for k in kinds]
    d = m.pairwise(descs)
    np.fill_diagonal(d, np.inf)
    assert np.all(kinds[d.argmin(axis=1)] == kinds)


def test_mpeg7_retrieval_on_real_shapes() -> None:
    folder = shared_file("mpeg7-subset")
    from data.mpeg7 import load_silhouettes

    shapes = [s for s in load_silhouettes(folder) if s.label in ("apple", "bone", "key")]
    labels = np.array([s.label for s in shapes])
    m = FFTMatcher(scale_invariant=True)
    d = m.pairwise([m.describe(Polygon(s.contour)) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[d.argmin(axis=1)] == labels) > 0.9
