"""Integral invariant matcher: the invariant, the elastic DP, invariances, batching."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.matchers import get_matcher
from loopclosure.matchers.integral_invariant import (
    IntegralConfig,
    IntegralInvariantMatcher,
    elastic_match,
    integral_invariant,
)
from loopclosure.polygon import Polygon
from tests.helpers import shared_file

SQUARE = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def regular(n: int, radius: float) -> Polygon:
    t = np.arange(n) * 2 * np.pi / n
    return Polygon(radius * np.column_stack([np.cos(t), np.sin(t)]))


def star_polygon(rng: np.random.Generator, n: int = 40) -> Polygon:
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(2, 6, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def room(kind: int, rng: np.random.Generator) -> Polygon:
    base = {
        0: np.array([[0, 0], [8, 0], [8, 5], [0, 5]], float),
        1: np.array([[0, 0], [8, 0], [8, 3], [3, 3], [3, 8], [0, 8]], float),
        2: np.array([[0, 0], [12, 0], [12, 2], [0, 2]], float),
    }[kind]
    # Random start vertex too: the matcher must find the cyclic correspondence.
    pts = np.roll(Polygon(base).resample(120), rng.integers(120), axis=0)
    pts = pts + rng.normal(0, 0.03, (120, 2))
    return Polygon(pts).rotated(rng.uniform(-np.pi, np.pi)).translated(rng.normal(0, 1, 2))


def brute_force_dp(q: np.ndarray, t: np.ndarray, alpha: float, w: int) -> tuple[float, float]:
    """Cell-by-cell reference of the elastic DP (energy, matched-pair sum)."""
    n = len(q)
    energy = np.full((n, n), np.inf)
    matched = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if abs(i - j) > w:
                continue
            d = abs(q[i] - t[j])
            cands = []
            if i == 0 and j == 0:
                cands.append((d * d, d))
            if i > 0 and j > 0:
                cands.append((energy[i - 1, j - 1] + d * d, matched[i - 1, j - 1] + d))
            if i > 0:
                cands.append((energy[i - 1, j] + d * d / 2 + alpha, matched[i - 1, j] + d))
            if j > 0:
                cands.append((energy[i, j - 1] + d * d / 2 + alpha, matched[i, j - 1] + d))
            if cands:
                energy[i, j], matched[i, j] = min(cands, key=lambda c: c[0])
    return energy[-1, -1], matched[-1, -1]


# --- the invariant ----------------------------------------------------------------------------


def test_invariant_of_regular_polygon_by_hand() -> None:
    # Mean distance from a vertex of a regular n-gon (radius R) to all n vertices:
    # (1/n) sum_k 2 R sin(pi k / n) = (2 R / n) cot(pi / (2 n)).
    n, radius = 48, 3.0
    inv = integral_invariant(regular(n, radius).resample(n))
    expected = np.log(2 * radius / n / np.tan(np.pi / (2 * n)))
    np.testing.assert_allclose(inv, expected, rtol=1e-12)


def test_invariant_of_square_corner_and_midpoint() -> None:
    pts = Polygon(SQUARE).resample(8)  # corners and edge midpoints of the 2 x 2 square
    inv = integral_invariant(pts)
    # From corner (1, 1): distances 0, 1, 2, sqrt5, 2sqrt2, sqrt5, 2, 1.
    corner = np.log((0 + 1 + 2 + np.sqrt(5) + 2 * np.sqrt(2) + np.sqrt(5) + 2 + 1) / 8)
    # From midpoint (0, 1): distances 0, 1, sqrt2, sqrt5, 2, sqrt5, sqrt2, 1.
    mid = np.log((0 + 1 + np.sqrt(2) + np.sqrt(5) + 2 + np.sqrt(5) + np.sqrt(2) + 1) / 8)
    np.testing.assert_allclose(inv, [corner, mid] * 4, rtol=1e-12)


def test_distance_between_circles_is_log_radius_ratio() -> None:
    m = IntegralInvariantMatcher()
    a, b = m.describe(regular(48, 2.0)), m.describe(regular(48, 5.0))
    assert m.distance(a, b) == pytest.approx(np.log(5.0 / 2.0), rel=1e-9)
    inv = IntegralInvariantMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(regular(48, 2.0)), inv.describe(regular(48, 5.0))) < 1e-12


# --- the elastic DP ---------------------------------------------------------------------------


@pytest.mark.parametrize("alpha", [0.0, 0.05, 1.0])
@pytest.mark.parametrize("w", [2, 5, 11])
def test_vectorised_dp_equals_cell_by_cell(alpha: float, w: int) -> None:
    rng = np.random.default_rng(int(alpha * 100) + w)
    q = rng.normal(size=12)
    t = rng.normal(size=(4, 12))
    energy, matched = elastic_match(q, t, alpha, w)
    ref = np.array([brute_force_dp(q, row, alpha, w) for row in t])
    np.testing.assert_allclose(energy, ref[:, 0], rtol=1e-12)
    np.testing.assert_allclose(matched, ref[:, 1], rtol=1e-12)


def test_dp_absorbs_a_local_stretch() -> None:
    # Query repeats sample 3, target repeats sample 14 of the same sequence: the warping
    # pairs the repeats (one vertical, one horizontal step) with zero difference, the
    # rigid diagonal pairing is off by one sample in between.
    v = np.random.default_rng(2).normal(0, 3, 22)
    q = np.insert(v, 4, v[3])
    t = np.insert(v, 15, v[14])
    energy, matched = elastic_match(q, t[None, :], 0.01, 6)
    assert matched[0] == 0.0
    assert energy[0] == pytest.approx(2 * 0.01)  # two stretching steps, no data cost
    assert np.abs(q - t).sum() > 1.0


def test_cyclic_start_is_found() -> None:
    m = IntegralInvariantMatcher()
    p = star_polygon(np.random.default_rng(5))
    d = m.describe(p)
    for shift in (1, 7, 30):
        assert m.distance(d, np.roll(d, shift)) < 1e-12


# --- invariances ------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_to_rotated_copy_is_zero(seed: int, angle: float) -> None:
    m = IntegralInvariantMatcher()
    p = star_polygon(np.random.default_rng(seed))
    # Rotation is an isometry and keeps vertex 0: only rounding differs.
    assert m.distance(m.describe(p), m.describe(p.rotated(angle))) < 1e-9


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_unchanged_when_one_polygon_rotates(seed: int, angle: float) -> None:
    m = IntegralInvariantMatcher()
    rng = np.random.default_rng(seed)
    p, q = star_polygon(rng), star_polygon(rng)
    a, b, b_rot = m.describe(p), m.describe(q), m.describe(q.rotated(angle))
    assert m.distance(a, b) == pytest.approx(m.distance(a, b_rot), abs=1e-9)


# --- batched distances ------------------------------------------------------------------------


@pytest.mark.parametrize("n_starts", [1, 3])
def test_batched_equals_single(n_starts: int) -> None:
    m = IntegralInvariantMatcher(n_starts=n_starts)
    rng = np.random.default_rng(0)
    descs = [m.describe(star_polygon(rng)) for _ in range(12)]
    d = m.distances(descs[0], m.stack(descs))
    single = np.array([m.distance(descs[0], x) for x in descs])
    np.testing.assert_allclose(d, single, rtol=1e-12, atol=1e-15)
    assert d[0] == 0.0 and np.all(d[1:] > 0)
    assert m.distances(descs[0], m.stack([])).shape == (0,)


def test_chunked_database_equals_unchunked(monkeypatch: pytest.MonkeyPatch) -> None:
    import loopclosure.matchers.integral_invariant as mod

    m = IntegralInvariantMatcher()
    rng = np.random.default_rng(4)
    descs = [m.describe(star_polygon(rng)) for _ in range(9)]
    stacked = m.stack(descs)
    whole = m.distances(descs[1], stacked)
    monkeypatch.setattr(mod, "_CHUNK_VALUES", 1)  # one entry per chunk
    np.testing.assert_array_equal(m.distances(descs[1], stacked), whole)


# --- degenerate polygons ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "vertices",
    [
        np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
        np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 0.01], [0.0, 0.01]]),
        SQUARE * 1e6,
        SQUARE * 1e-3,
        np.array([[0, 0], [1, 0], [1, 0], [1, 1], [0, 1], [0, 0]], float),
    ],
)
@pytest.mark.parametrize("scale_invariant", [False, True])
def test_degenerate_polygons_give_finite_descriptors(
    vertices: np.ndarray, scale_invariant: bool
) -> None:
    m = IntegralInvariantMatcher(scale_invariant=scale_invariant)
    d = m.describe(Polygon(vertices))
    assert d.shape == (48,) and np.all(np.isfinite(d))
    dist = m.distance(d, m.describe(Polygon(SQUARE)))
    assert np.isfinite(dist) and dist >= 0
    assert m.distance(d, d) == 0.0


def test_registry_and_config_errors() -> None:
    m = get_matcher("integral", n_points=32, alpha=0.01)
    assert isinstance(m, IntegralInvariantMatcher)
    assert m.describe(Polygon(SQUARE)).shape == (32,)
    assert IntegralInvariantMatcher(IntegralConfig(band=0.5)).config.band == 0.5
    with pytest.raises(TypeError):
        IntegralInvariantMatcher(points=3)
    with pytest.raises(ValueError):
        IntegralInvariantMatcher(alpha=-1.0)
    with pytest.raises(ValueError):
        IntegralInvariantMatcher(band=0.0)


# --- retrieval --------------------------------------------------------------------------------


def test_nearest_neighbour_is_same_kind_of_room() -> None:
    m = IntegralInvariantMatcher()
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
    m = IntegralInvariantMatcher(scale_invariant=True)
    d = m.pairwise([m.describe(Polygon(s.contour)) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[d.argmin(axis=1)] == labels) > 0.8
