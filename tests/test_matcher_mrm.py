"""MRM (multi-scale convexity/concavity) matcher: formulas, DP, invariances, retrieval."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.matchers import get_matcher
from loopclosure.matchers.mrm import MRMConfig, MRMMatcher, _dtw_cyclic
from loopclosure.polygon import Polygon


def star(seed: int, n: int = 150) -> Polygon:
    """Random smooth star-shaped polygon, radius 3 m +- lobes of 2..6 cycles (up to 0.8 m)."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    k = np.arange(2, 7)
    amp, phase = rng.uniform(-0.8, 0.8, 5), rng.uniform(0, 2 * np.pi, 5)
    r = 3.0 + (amp[:, None] * np.cos(k[:, None] * ang[None, :] + phase[:, None])).sum(axis=0)
    return Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))


def regular(n: int, radius: float) -> Polygon:
    a = 2 * np.pi * np.arange(n) / n
    return Polygon(radius * np.column_stack([np.cos(a), np.sin(a)]))


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


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), angle=st.floats(-np.pi, np.pi))
def test_rotation_invariance(seed: int, angle: float) -> None:
    m = MRMMatcher()
    a, b = star(seed), star(seed + 1)
    da = m.describe(a)
    # The descriptor only uses displacement lengths and their side: exact up to rounding.
    assert m.distance(da, m.describe(a.rotated(angle))) < 1e-9
    assert m.distance(da, m.describe(b.rotated(angle))) == pytest.approx(
        m.distance(da, m.describe(b)), rel=1e-9, abs=1e-12
    )


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.integers(1, 99))
def test_start_vertex_and_translation(seed: int, shift: int) -> None:
    # A rolled descriptor (another start sample) matches exactly: the DP searches start offsets.
    m = MRMMatcher()
    a = star(seed)
    da = m.describe(a)
    rolled = type(da)(np.roll(da.mcc, shift, axis=0), None, da.complexity)
    assert m.distance(da, rolled) < 1e-12
    # Another first vertex resamples the contour at other arc-length phases; the residual
    # is sampling noise of the N = 100 samples (median 22 %, at most 34 % of the distance
    # between two different random stars over 30 seeds), never near a different shape.
    moved = Polygon(np.roll(a.vertices, shift, axis=0) + np.array([3.0, -7.0]))
    other = m.distance(da, m.describe(star(seed + 1)))
    assert m.distance(da, m.describe(moved)) < 0.5 * other


def test_batched_equals_single_and_registry() -> None:
    m = get_matcher("mrm")
    assert isinstance(m, MRMMatcher) and m.rotation_invariant
    descs = [m.describe(star(s)) for s in range(7)]
    stacked = m.stack(descs)
    for q in descs[:3]:
        batched = m.distances(q, stacked)
        single = [m.distance(q, d) for d in descs]
        np.testing.assert_allclose(batched, single, rtol=1e-12)
    chunked = MRMMatcher(chunk=2)
    np.testing.assert_allclose(chunked.distances(descs[0], stacked), m.distances(descs[0], stacked))
    assert m.stack([]).mcc.shape == (0, 100, 10)


def test_scale_handling() -> None:
    a = star(5)
    big = Polygon(a.vertices * 2.5)
    metric = MRMMatcher()
    da = metric.describe(a)
    # Descriptors scale with size: d_big = 2.5 d_a.  The un-warped path costs
    # mean|1.5 d_a| [m]; warping can only lower it.
    unwarped = 1.5 * np.abs(da.mcc).mean()
    assert 0.5 * unwarped < metric.distance(da, metric.describe(big)) <= unwarped + 1e-12
    inv = MRMMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(a), inv.describe(big)) < 1e-9


def test_mirror_option() -> None:
    a = star(11)
    # Mirror image, vertex 0 kept first (so both resample the same points): counter-clockwise
    # order of the mirrored vertices is the reversed order.
    image = (a.vertices * [-1.0, 1.0])[::-1]
    mirrored = Polygon(np.roll(image, 1, axis=0))
    plain, mirror = MRMMatcher(), MRMMatcher(mirror=True)
    assert plain.distance(plain.describe(a), plain.describe(mirrored)) > 0.005
    assert mirror.distance(mirror.describe(a), mirror.describe(mirrored)) < 1e-9


@pytest.mark.parametrize(
    "vertices",
    [
        [[0, 0], [1, 0], [0, 1]],  # 3 vertices
        [[0, 0], [10, 0], [10, 0.001], [0, 0.001]],  # very thin
        [[0, 0], [1e5, 0], [1e5, 1e5], [0, 1e5]],  # huge
        [[0, 0], [1e-5, 0], [1e-5, 1e-5], [0, 1e-5]],  # tiny
        [[0, 0], [1, 0], [1, 0], [1, 1], [1, 1], [0, 1]],  # duplicate points
    ],
)
@pytest.mark.parametrize("scale_invariant", [False, True])
def test_degenerate_polygons_finite(vertices: list[list[float]], scale_invariant: bool) -> None:
    m = MRMMatcher(scale_invariant=scale_invariant)
    d = m.describe(Polygon(np.array(vertices, float)))
    assert np.isfinite(d.mcc).all() and np.isfinite(d.complexity) and d.complexity > 0
    ref = m.describe(star(1))
    dist = m.distances(d, m.stack([d, ref]))
    assert np.isfinite(dist).all() and (dist >= 0).all() and dist[0] < 1e-9


def test_retrieval_nearest_neighbour_same_kind() -> None:
    rng = np.random.default_rng(0)
    kinds = [star(100), star(200), star(300)]

    def noisy(p: Polygon) -> Polygon:
        v = p.vertices + rng.normal(0, 0.05, p.vertices.shape)
        return Polygon(v).rotated(rng.uniform(-np.pi, np.pi))

    shapes = [noisy(k) for k in kinds for _ in range(4)]
    labels = np.repeat(np.arange(3), 4)
    m = MRMMatcher()
    descs = [m.describe(s) for s in shapes]
    d = m.pairwise(descs)
    np.fill_diagonal(d, np.inf)
    assert (labels[d.argmin(axis=1)] == labels).all()


def test_config_validation() -> None:
    with pytest.raises(UserError):
        MRMConfig(n_points=3)
    with pytest.raises(UserError):
        MRMConfig(band=0.0)
    with pytest.raises(UserError):
        MRMMatcher(bogus=1)
