"""Shape-context matcher: histograms by hand, chi^2, assignment, invariances, retrieval."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from data.errors import UserError
from loopclosure.matchers import get_matcher
from loopclosure.matchers.shape_context import (
    ShapeContextConfig,
    ShapeContextMatcher,
    _harmonic_factors,
)
from loopclosure.polygon import Polygon


def star(seed: int, n: int = 150) -> Polygon:
    """Random smooth star-shaped polygon, radius 3 m +- lobes of 2..6 cycles (up to 0.8 m)."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    k = np.arange(2, 7)
    amp, phase = rng.uniform(-0.8, 0.8, 5), rng.uniform(0, 2 * np.pi, 5)
    r = 3.0 + (amp[:, None] * np.cos(k[:, None] * ang[None, :] + phase[:, None])).sum(axis=0)
    return Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))


def test_histogram_of_a_square_by_hand() -> None:
    # 4 samples on a 2 x 2 m square = its corners.  Corner 0 at (-1, -1): the tangent is
    # the direction of p_1 - p_3 = (1,-1) - (-1,1) = (2, -2), i.e. -45 degrees.  Its
    # neighbours: p_1 at 2 m along +x (45 deg from the tangent), p_2 at 2.83 m along 45 deg
    # (90 deg), p_3 at 2 m along +y (135 deg).  r0 = 1 m; r_inner = 0.25 and r_outer = 4
    # give the radial edges 0.25, 0.5, 1, 2, 4.
    sq = Polygon(np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float))
    m = ShapeContextMatcher(
        n_points=4, tangent_span=1, mean_distance=1.0, r_inner=0.25, r_outer=4.0
    )
    h = m.describe(sq).astype(int)
    # Edges 0.25, 0.5, 1, 2, 4: 2 m -> bin 4 ([2, 4)), 2.83 m -> bin 4.  Angular bins of
    # 30 degrees: 45 -> 1, 90 -> 3, 135 -> 4.
    expected = np.zeros(60, int)
    expected[[4 * 12 + 1, 4 * 12 + 3, 4 * 12 + 4]] = 1
    np.testing.assert_array_equal(h[0], expected)
    # Every corner sees the same context (the square is symmetric).
    for row in h:
        np.testing.assert_array_equal(row, expected)


def test_harmonic_kernel_factors() -> None:
    v, w = _harmonic_factors(99)
    a = np.arange(100.0)
    s = a[:, None] + a[None, :]
    f = np.divide(a[:, None] * a[None, :], s, out=np.zeros_like(s), where=s > 0)
    assert np.abs((v * w) @ v.T - f).max() < 1e-9
    assert v.shape[1] <= 20


def test_chi2_costs_match_the_formula() -> None:
    m = ShapeContextMatcher()
    a, b = m.describe(star(1)), m.describe(star(2))
    got = m.chi2_costs(a, m.stack([b]))[0]
    h = a[:, None, :] / 99.0
    g = b[None, :, :] / 99.0
    s = h + g
    want = 0.5 * np.divide((h - g) ** 2, s, out=np.zeros_like(s), where=s > 0).sum(axis=2)
    np.testing.assert_allclose(got, want, atol=1e-6)
    # distance = mean matched cost of the optimal assignment
    r, c = linear_sum_assignment(want)
    assert m.distance(a, b) == pytest.approx(want[r, c].mean(), abs=1e-6)


def test_dummy_nodes_cap_outlier_costs() -> None:
    m = ShapeContextMatcher(dummy_fraction=0.25, dummy_cost=0.0)
    a, b = m.describe(star(1)), m.describe(star(2))
    # Dummies at zero cost absorb the 25 worst points of each side.
    assert m.distance(a, b) < ShapeContextMatcher().distance(a, b)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), angle=st.floats(-np.pi, np.pi))
def test_rotation_invariance(seed: int, angle: float) -> None:
    # Tangent-relative angles: rotating a polygon rotates samples and tangents together,
    # so every histogram is unchanged except where an angle falls within rounding of a bin
    # edge (a count moves to the neighbouring bin): at most ~1e-3 of the cost scale.
    m = ShapeContextMatcher()
    a, b = star(seed), star(seed + 1)
    da = m.describe(a)
    assert m.distance(da, m.describe(a.rotated(angle))) < 2e-3
    d_ab = m.distance(da, m.describe(b))
    assert abs(m.distance(da, m.describe(b.rotated(angle))) - d_ab) < 2e-3


def test_translation_and_start_vertex() -> None:
    m = ShapeContextMatcher()
    a = star(4)
    moved = Polygon(np.roll(a.vertices, 37, axis=0) + np.array([5.0, -2.0]))
    other = m.distance(m.describe(a), m.describe(star(5)))
    assert m.distance(m.describe(a), m.describe(moved)) < 0.3 * other


def test_batched_equals_single_and_registry() -> None:
    m = get_matcher("shape-context")
    assert isinstance(m, ShapeContextMatcher) and m.rotation_invariant
    descs = [m.describe(star(s)) for s in range(6)]
    stacked = m.stack(descs)
    for q in descs[:3]:
        np.testing.assert_allclose(
            m.distances(q, stacked), [m.distance(q, d) for d in descs], rtol=1e-6, atol=1e-7
        )
    assert ShapeContextMatcher(chunk=4).distances(descs[0], stacked) == pytest.approx(
        m.distances(descs[0], stacked), abs=1e-7
    )
    assert len(m.distances(descs[0], m.stack([]))) == 0


def test_scale_handling() -> None:
    a = star(3)
    big = Polygon(a.vertices * 2.0)
    metric = ShapeContextMatcher()
    assert metric.distance(metric.describe(a), metric.describe(big)) > 0.05
    inv = ShapeContextMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(a), inv.describe(big)) < 1e-5


@pytest.mark.parametrize(
    "vertices",
    [
        [[0, 0], [1, 0], [0, 1]],
        [[0, 0], [10, 0], [10, 0.001], [0, 0.001]],
        [[0, 0], [1e5, 0], [1e5, 1e5], [0, 1e5]],
        [[0, 0], [1e-5, 0], [1e-5, 1e-5], [0, 1e-5]],
        [[0, 0], [1, 0], [1, 0], [1, 1], [1, 1], [0, 1]],
    ],
)
@pytest.mark.parametrize("scale_invariant", [False, True])
def test_degenerate_polygons_finite(vertices: list[list[float]], scale_invariant: bool) -> None:
    m = ShapeContextMatcher(scale_invariant=scale_invariant)
    d = m.describe(Polygon(np.array(vertices, float)))
    dist = m.distances(d, m.stack([d, m.describe(star(1))]))
    assert np.isfinite(dist).all() and (dist >= 0).all() and dist[0] < 1e-5


def test_retrieval_nearest_neighbour_same_kind() -> None:
    rng = np.random.default_rng(0)
    kinds = [star(100), star(200), star(300)]

    def noisy(p: Polygon) -> Polygon:
        v = p.vertices + rng.normal(0, 0.05, p.vertices.shape)
        return Polygon(v).rotated(rng.uniform(-np.pi, np.pi))

    shapes = [noisy(k) for k in kinds for _ in range(4)]
    labels = np.repeat(np.arange(3), 4)
    m = ShapeContextMatcher()
    d = m.pairwise([m.describe(s) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert (labels[d.argmin(axis=1)] == labels).all()


def test_config_validation() -> None:
    with pytest.raises(UserError):
        ShapeContextConfig(r_inner=3.0, r_outer=2.0)
    with pytest.raises(UserError):
        ShapeContextConfig(mean_distance=0.0)
    with pytest.raises(UserError):
        ShapeContextMatcher(bogus=1)


def _reference_counts(matcher: ShapeContextMatcher, polygon: Polygon) -> np.ndarray:
    """Shape-context counts by the straightforward formulation (roll, %, searchsorted)."""
    cfg = matcher.config
    n = cfg.n_points
    pts = polygon.resample(n)
    z = pts[:, 0] + 1j * pts[:, 1]
    dz = z[None, :] - z[:, None]
    r = np.abs(dz)
    off = ~np.eye(n, dtype=bool)
    r0 = float(r[off].mean()) if cfg.scale_invariant else cfg.mean_distance
    r = r / max(r0, np.finfo(float).tiny)
    tangent = np.roll(z, -cfg.tangent_span) - np.roll(z, cfg.tangent_span)
    theta = np.angle(dz * np.exp(-1j * np.angle(tangent))[:, None]) % (2 * np.pi)
    edges = np.geomspace(cfg.r_inner, cfg.r_outer, cfg.n_radial)
    rb = np.searchsorted(edges, r, side="right")
    ab = np.minimum((theta * (cfg.n_angular / (2 * np.pi))).astype(int), cfg.n_angular - 1)
    bins = rb * cfg.n_angular + ab
    counts = np.zeros((n, matcher.n_bins), dtype=int)
    keep = off & (r < edges[-1])
    np.add.at(counts, (np.nonzero(keep)[0], bins[keep]), 1)
    return counts


@pytest.mark.parametrize("scale_invariant", [False, True])
def test_vectorised_describe_equals_straightforward_formulation(scale_invariant: bool) -> None:
    # Squares put many tangent-relative angles exactly on bin edges (0, pi): the fast
    # path's wrap and radial binning must reproduce the reference exactly there too.
    shapes = [star(s) for s in range(4)] + [Polygon(np.array([[0, 0], [6, 0], [6, 6], [0, 6.0]]))]
    for cfg in ({}, {"n_points": 37, "n_radial": 3, "n_angular": 7, "tangent_span": 3}):
        m = ShapeContextMatcher(scale_invariant=scale_invariant, **cfg)
        for p in shapes:
            np.testing.assert_array_equal(m.describe(p), _reference_counts(m, p))
