"""Surface-pair histogram: samples and pair features by hand, pose invariance as properties.

The shared clauses (registry, batching, rotation about the sensor origin, scale option,
retrieval of rooms) are tested in test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.matchers.pair_histogram import (
    PairHistogramMatcher,
    pair_histogram,
    surface_samples,
)
from loopclosure.polygon import Polygon
from tests.matcher_shapes import random_star


def test_surface_samples_of_a_unit_square_by_hand() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pts, nrm, w = surface_samples(square, step=0.5, max_edge=2.0, max_range=10.0)
    # Two samples per edge at t = 1/4, 3/4, weight 0.5 m each, outward normals (CCW).
    np.testing.assert_allclose(pts[:2], [[0.25, 0.0], [0.75, 0.0]])
    np.testing.assert_allclose(pts[2:4], [[1.0, 0.25], [1.0, 0.75]])
    np.testing.assert_allclose(nrm[:2], [[0.0, -1.0], [0.0, -1.0]])
    np.testing.assert_allclose(nrm[2:4], [[1.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(w, 0.5)
    assert len(pts) == 8


def test_open_space_and_depth_jumps_are_not_surfaces() -> None:
    # A 2 m wall at x = 2 joined to vertices at the 20 m range cap: only the wall counts.
    v = np.array([[2.0, -1.0], [2.0, 1.0], [0.0, 20.0], [-20.0, 0.0], [0.0, -20.0]])
    pts, _, w = surface_samples(v, step=0.5, max_edge=3.0, max_range=19.5)
    np.testing.assert_allclose(pts[:, 0], 2.0)
    assert np.isclose(w.sum(), 2.0)
    # The same wall as two 1 m pieces split by a 1.5 m jump: the jump is dropped.
    v2 = np.array([[2.0, -1.0], [2.0, 0.0], [3.5, 0.0], [3.5, 1.0], [0.0, 20.0], [-20.0, 0.0]])
    _, _, w2 = surface_samples(v2, step=0.5, max_edge=1.2, max_range=19.5)
    assert np.isclose(w2.sum(), 2.0)


def test_pair_histogram_of_three_points_by_hand() -> None:
    pts = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 2.0]])
    nrm = np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    w = np.array([1.0, 2.0, 1.0])
    h = pair_histogram(pts, nrm, w, max_distance=4.0, n_distance=4, n_angle=2)
    expected = np.zeros((4, 2))
    # (a, b): d = 3, along both surfaces (alpha 0), weight 2, counted at both ends.
    expected[3, 0] += 4.0
    # (a, c): d = 2; straight across a's surface (pi/2), along c's (0); weight 1.
    expected[2, 1] += 1.0
    expected[2, 0] += 1.0
    # (b, c): d = sqrt(13); at b alpha = asin(2/sqrt13) = 0.59 rad (bin 0), at c
    # asin(3/sqrt13) = 0.98 rad (bin 1, above pi/4); weight 2.
    expected[3, 0] += 2.0
    expected[3, 1] += 2.0
    np.testing.assert_allclose(h, expected)


def test_descriptor_is_a_unit_vector_and_empty_surfaces_match_nothing() -> None:
    m = PairHistogramMatcher()
    d = m.describe(random_star(np.random.default_rng(0)))
    assert d.dtype == np.float32 and np.isclose(np.linalg.norm(d), 1.0, atol=1e-6)
    # Every vertex at the range cap: open space all round, no surface.
    t = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    open_space = Polygon(20.0 * np.column_stack([np.cos(t), np.sin(t)]))
    e = m.describe(open_space)
    assert not e.any()
    assert np.isclose(m.distance(d, e), 1.0, atol=1e-6)


def _moved(p: Polygon, angle: float, shift: np.ndarray) -> Polygon:
    c, s = np.cos(angle), np.sin(angle)
    return Polygon(p.vertices @ np.array([[c, s], [-s, c]]) + shift)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.floats(-np.pi, np.pi),
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
)
def test_distance_to_a_moved_copy_is_near_zero(
    seed: int, angle: float, dx: float, dy: float
) -> None:
    """The sensor anywhere in the place, any heading: the same descriptor (up to pairs
    within rounding of a bin edge)."""
    m = PairHistogramMatcher()
    p = random_star(np.random.default_rng(seed))
    q = _moved(p, angle, np.array([dx, dy]))
    assert m.distance(m.describe(p), m.describe(q)) < 2e-3


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 400))
def test_compiled_kernel_gives_the_numpy_histogram(seed: int, n: int) -> None:
    from loopclosure.matchers.pair_kernel import pair_histogram_compiled

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-8, 8, (n, 2))
    pts[: n // 4] = np.round(pts[: n // 4])  # repeated points: pairs at distance 0
    ang = rng.uniform(-np.pi, np.pi, n)
    nrm = np.column_stack([np.cos(ang), np.sin(ang)])
    w = rng.uniform(0.05, 0.3, n)
    args = dict(max_distance=10.0, n_distance=40, n_angle=8)
    np.testing.assert_allclose(pair_histogram_compiled(pts, nrm, w, **args),
                               pair_histogram(pts, nrm, w, **args), rtol=1e-12, atol=1e-12)


def test_compiled_and_numpy_descriptors_agree_on_a_room() -> None:
    poly = random_star(np.random.default_rng(3), 180)
    fast = PairHistogramMatcher().describe(poly)
    slow = PairHistogramMatcher(compiled=False).describe(poly)
    np.testing.assert_allclose(fast, slow, rtol=1e-6, atol=1e-7)


def test_compiled_surface_samples_equal_the_numpy_ones() -> None:
    """Same samples, normals and weights to the bit: random rings, a repeated vertex
    (zero-length edge), a vertex beyond the range, long edges and a lone vertex."""
    from loopclosure.matchers.pair_histogram import surface_samples, surface_samples_numpy

    rng = np.random.default_rng(6)
    settings = (dict(step=0.25, max_edge=1.0, max_range=20.0),
                dict(step=0.01, max_edge=np.inf, max_range=np.inf))
    for n in (0, 1, 2, 40):
        v = rng.normal(0.0, 5.0, (n, 2))
        if n > 3:
            v[1] = v[2]
            v[3] = [np.inf, 0.0]
        for kw in settings:
            for got, ref in zip(surface_samples(v, **kw), surface_samples_numpy(v, **kw),
                                strict=True):
                assert got.shape == ref.shape
                np.testing.assert_array_equal(got, ref)
    # hand-checked: a 1 m edge at step 0.5 gives two samples at its quarter points
    pts, nrm, w = surface_samples(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 5.0]]),
                                  step=0.5, max_edge=2.0, max_range=10.0)
    np.testing.assert_array_equal(pts, [[0.25, 0.0], [0.75, 0.0]])
    np.testing.assert_array_equal(nrm, [[0.0, -1.0], [0.0, -1.0]])
    np.testing.assert_array_equal(w, [0.5, 0.5])


def test_angle_table_counts_the_edges_as_comparing_with_each() -> None:
    """The table's angle bins are the comparison count: histograms equal to the bit
    for several bin counts (one too fine for a table falls back to counting), and a
    hand-checked table for edges 0.3, 0.6 at 16 buckets."""
    from loopclosure.matchers import pair_kernel

    base, near, buckets = pair_kernel.angle_table(np.array([0.3, 0.6]))
    assert buckets == 16
    assert base[:6].tolist() == [0, 0, 0, 0, 0, 0] and base[11:].tolist() == [2] * 5
    assert near[4] == 0.3 and near[9] == 0.6 and np.isinf(near[7])
    rng = np.random.default_rng(8)
    pts = rng.normal(0.0, 4.0, (120, 2))
    nrm = rng.normal(size=(120, 2))
    nrm /= np.hypot(nrm[:, 0], nrm[:, 1])[:, None]
    w = rng.random(120)
    for n_angle in (1, 3, 8, 45, 90):
        edges = np.sin(np.arange(1, n_angle) * (0.5 * np.pi / n_angle))
        ref = np.zeros(40 * n_angle)
        pair_kernel._pair_kernel_counting(pts, nrm, w, 10.0, 40, n_angle, edges, ref)
        got = pair_kernel.pair_histogram_compiled(pts, nrm, w, max_distance=10.0,
                                                  n_distance=40, n_angle=n_angle)
        np.testing.assert_array_equal(got.ravel(), ref)
