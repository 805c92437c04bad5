"""MRM (multi-scale convexity/concavity) matcher: formulas, the cyclic DP, start, scale.

The invariances (exact up to rounding), batching and the other shared clauses:
test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.matchers.mrm import MRMMatcher, _dtw_cyclic, resample_by_vertex
from loopclosure.polygon import Polygon
from tests.matcher_shapes import blob, regular


def test_circle_displacements_by_hand() -> None:
    # A regular N-gon sampled at its N vertices is the pure harmonic z(u) = rho e^{2 pi i u/N};
    # Gaussian smoothing scales it by g_k = exp(-2 pi^2 sigma_k^2 / N^2): every point moves
    # inwards (convex, +) by rho (g_{k-1} - g_k).
    n, rho = 100, 3.0
    m = MRMMatcher(n_points=n, n_scales=5)
    d = m.describe(regular(n, rho))
    sig = np.arange(6) * 1.0
    g = np.exp(-2 * np.pi**2 * sig**2 / n**2)
    expected = rho * (g[:-1] - g[1:])
    np.testing.assert_allclose(d.mcc, np.broadcast_to(expected, (n, 5)), rtol=1e-9, atol=1e-12)
    assert d.complexity > 0  # floored, never a division by zero
    assert m.distance(d, d) == 0.0


def test_signs_convex_and_concave() -> None:
    # L-shaped room: the reflex corner at (2, 2) is concave, the outer corners convex.
    room = Polygon(np.array([[0, 0], [4, 0], [4, 2], [2, 2], [2, 4], [0, 4]], float))
    m = MRMMatcher(n_points=96, n_scales=3)
    d = m.describe(room)
    pts = room.resample(96)
    reflex = np.argmin(np.hypot(*(pts - [2, 2]).T))
    corner = np.argmin(np.hypot(*(pts - [4, 0]).T))
    assert d.mcc[reflex, 0] < 0 < d.mcc[corner, 0]


def _dtw_reference(cost: np.ndarray, band: int | None) -> float:
    """Plain-loop DTW over every start offset (steps down, right, diagonal)."""
    n = len(cost)
    best = np.inf
    for s in range(n):
        c = cost[:, (np.arange(n) + s) % n]
        d = np.full((n, n), np.inf)
        for i in range(n):
            for j in range(n):
                if band is not None and abs(i - j) > band:
                    continue
                if i == j == 0:
                    d[i, j] = c[0, 0]
                    continue
                prev = min(
                    d[i - 1, j] if i else np.inf,
                    d[i, j - 1] if j else np.inf,
                    d[i - 1, j - 1] if i and j else np.inf,
                )
                d[i, j] = c[i, j] + prev
        best = min(best, d[-1, -1])
    return float(best)


@pytest.mark.parametrize("band", [None, 2, 4])
def test_dp_matches_plain_loops(band: int | None) -> None:
    rng = np.random.default_rng(3)
    cost = rng.random((4, 9, 9))
    got = _dtw_cyclic(cost, None, band)
    want = [_dtw_reference(c, band) for c in cost]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_dp_hand_checked() -> None:
    # Costs zero on the anti-shifted diagonal j = i + 1 (mod 3): start offset 1 is free.
    cost = np.ones((1, 3, 3))
    cost[0, [0, 1, 2], [1, 2, 0]] = 0.0
    assert _dtw_cyclic(cost, None, None)[0] == 0.0
    # Without the start search (band 0, one start offset searched around the best diagonal).
    assert _dtw_cyclic(cost, 1, 0)[0] == 0.0


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.integers(1, 99))
def test_start_vertex_and_translation(seed: int, shift: int) -> None:
    # A rolled descriptor (another start sample) matches exactly: the DP searches start offsets.
    m = MRMMatcher()
    a = blob(seed)
    da = m.describe(a)
    rolled = type(da)(np.roll(da.mcc, shift, axis=0), None, da.complexity)
    assert m.distance(da, rolled) < 1e-12
    # Another first vertex resamples the contour at other arc-length phases; the residual
    # is sampling noise of the N = 100 samples (median 22 %, at most 34 % of the distance
    # between two different random stars over 30 seeds), never near a different shape.
    moved = Polygon(np.roll(a.vertices, shift, axis=0) + np.array([3.0, -7.0]))
    other = m.distance(da, m.describe(blob(seed + 1)))
    assert m.distance(da, m.describe(moved)) < 0.5 * other


def test_chunked_distances_equal_unchunked() -> None:
    m = MRMMatcher()
    descs = [m.describe(blob(s)) for s in range(7)]
    stacked = m.stack(descs)
    chunked = MRMMatcher(chunk=2)
    np.testing.assert_allclose(chunked.distances(descs[0], stacked), m.distances(descs[0], stacked))
    assert m.stack([]).mcc.shape == (0, 100, 10)


def test_metric_distance_of_a_scaled_copy_is_bounded_by_the_unwarped_cost() -> None:
    a = blob(5)
    big = Polygon(a.vertices * 2.5)
    metric = MRMMatcher(normalisation="points")
    da, db = metric.describe(a), metric.describe(big)
    # Descriptors scale with size: d_big = 2.5 d_a.  The un-warped path costs
    # mean|1.5 d_a| [m]; warping can only lower it.
    unwarped = 1.5 * np.abs(da.mcc).mean()
    per_point = metric.distance(da, db)
    assert 0.5 * unwarped < per_point <= unwarped + 1e-12
    # The complexity normalisation divides the same path cost by (C_a + C_b) / 2, with
    # C_b = 2.5 C_a: a scaled copy stays at a distance > 0 (not scale invariant).
    assert db.complexity == pytest.approx(2.5 * da.complexity, rel=1e-12)
    default = MRMMatcher().distance(da, db)
    assert default == pytest.approx(per_point / (1.75 * da.complexity), rel=1e-12)


def test_mirror_option() -> None:
    a = blob(11)
    # Mirror image, vertex 0 kept first (so both resample the same points): counter-clockwise
    # order of the mirrored vertices is the reversed order.
    image = (a.vertices * [-1.0, 1.0])[::-1]
    mirrored = Polygon(np.roll(image, 1, axis=0))
    plain, mirror = MRMMatcher(), MRMMatcher(mirror=True)
    assert plain.distance(plain.describe(a), plain.describe(mirrored)) > 0.005
    assert mirror.distance(mirror.describe(a), mirror.describe(mirrored)) < 1e-9


def test_resample_by_vertex_by_hand() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    want = [[0, 0], [1, 0], [2, 0], [2, 1], [2, 2], [1, 2], [0, 2], [0, 1]]
    np.testing.assert_allclose(resample_by_vertex(square, 8), want)
    # Fewer samples than vertices: index steps of 4/3, between vertices 1-2 and 2-3.
    np.testing.assert_allclose(resample_by_vertex(square, 3), [[0, 0], [2, 2 / 3], [2 / 3, 2]])


def test_sampling_auto_is_arc_for_shapes_and_vertex_for_places() -> None:
    # Uneven edges: the two samplings differ.
    poly = Polygon(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 1.0], [9.0, 1.5], [0.0, 1.0]]))
    def mcc(**kw: object) -> np.ndarray:
        return MRMMatcher(**kw).describe(poly).mcc
    np.testing.assert_array_equal(mcc(), mcc(sampling="vertex"))
    np.testing.assert_array_equal(mcc(scale_invariant=True),
                                  mcc(scale_invariant=True, sampling="arc"))
    assert np.abs(mcc(sampling="arc") - mcc(sampling="vertex")).max() > 0.01
    with pytest.raises(UserError):
        MRMMatcher(sampling="angle")
    with pytest.raises(UserError):
        MRMMatcher(normalisation="area")
