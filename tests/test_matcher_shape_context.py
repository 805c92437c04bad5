"""Shape-context matcher: histograms by hand, chi^2, assignment, the vectorised paths.

Rotation invariance up to bin-edge rounding (2e-3), batching and the other shared
clauses: test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from loopclosure.matchers.shape_context import ShapeContextMatcher, _harmonic_factors
from loopclosure.polygon import Polygon
from tests.matcher_shapes import blob


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
    a, b = m.describe(blob(1)), m.describe(blob(2))
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
    a, b = m.describe(blob(1)), m.describe(blob(2))
    # Dummies at zero cost absorb the 25 worst points of each side.
    assert m.distance(a, b) < ShapeContextMatcher().distance(a, b)


def test_translation_and_start_vertex() -> None:
    m = ShapeContextMatcher()
    a = blob(4)
    moved = Polygon(np.roll(a.vertices, 37, axis=0) + np.array([5.0, -2.0]))
    other = m.distance(m.describe(a), m.describe(blob(5)))
    assert m.distance(m.describe(a), m.describe(moved)) < 0.3 * other


def test_chunked_distances_equal_unchunked() -> None:
    m = ShapeContextMatcher()
    descs = [m.describe(blob(s)) for s in range(6)]
    stacked = m.stack(descs)
    assert ShapeContextMatcher(chunk=4).distances(descs[0], stacked) == pytest.approx(
        m.distances(descs[0], stacked), abs=1e-7
    )


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
    shapes = [blob(s) for s in range(4)] + [Polygon(np.array([[0, 0], [6, 0], [6, 6], [0, 6.0]]))]
    for cfg in ({}, {"n_points": 37, "n_radial": 3, "n_angular": 7, "tangent_span": 3}):
        m = ShapeContextMatcher(scale_invariant=scale_invariant, **cfg)
        for p in shapes:
            np.testing.assert_array_equal(m.describe(p), _reference_counts(m, p))


def test_harmonic_table_by_hand() -> None:
    from loopclosure.matchers.shape_context_kernel import harmonic_table

    f = harmonic_table(5)
    # F(a, b) = a b / (a + b): F(2, 3) = 6/5, F(4, 4) = 2, F(0, b) = F(0, 0) = 0.
    assert f.shape == (6, 6)
    assert f[2, 3] == pytest.approx(1.2) and f[3, 2] == f[2, 3]
    assert f[4, 4] == pytest.approx(2.0)
    assert f[0, 5] == 0.0 and f[0, 0] == 0.0


def test_compiled_assignment_by_hand_and_against_scipy() -> None:
    from loopclosure.matchers.shape_context_kernel import assignment_cost

    # Rows 0 -> 1, 1 -> 0, 2 -> 2: 1 + 2 + 2 = 5, the cheapest of the six permutations
    # (6, 7, 9, 11, 6 for the others).
    c = np.array([[4.0, 1.0, 3.0], [2.0, 0.0, 5.0], [3.0, 2.0, 2.0]])
    assert assignment_cost(c) == pytest.approx(5.0)
    rng = np.random.default_rng(3)
    for trial in range(40):
        n = int(rng.integers(1, 30))
        c = rng.random((n, n))
        if trial % 2:  # many ties
            c = np.round(c * 3) / 3
        r, k = linear_sum_assignment(c)
        assert assignment_cost(c) == pytest.approx(c[r, k].sum(), abs=1e-12)


def test_numba_chi2_costs_are_the_exact_formula() -> None:
    m = ShapeContextMatcher(kernel="numba", n_points=50)
    a, b = m.describe(blob(1)), m.describe(blob(2))
    got = m.chi2_costs(a, m.stack([b]))[0]
    h, g = a[:, None, :] / 49.0, b[None, :, :] / 49.0
    s = h + g
    want = 0.5 * np.divide((h - g) ** 2, s, out=np.zeros_like(s), where=s > 0).sum(axis=2)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("options", [{}, {"n_points": 40, "scale_invariant": True},
                                     {"dummy_fraction": 0.2, "dummy_cost": 0.1}])
def test_numba_kernel_equals_the_blas_path(options: dict) -> None:
    # Property: the compiled path gives the default path's distances (the float32 factor
    # product is the only difference, about 1e-7), and its symmetric pairwise matrix is
    # the row-by-row one.
    old = ShapeContextMatcher(**options)
    new = ShapeContextMatcher(kernel="numba", **options)
    shapes = [blob(s) for s in range(7)]
    shapes.append(Polygon(np.array([[0, 0], [6, 0], [6, 2], [0, 2.0]])))
    descs = [old.describe(p) for p in shapes]
    np.testing.assert_array_equal(descs[3], new.describe(shapes[3]))
    want = old.pairwise(descs)
    rows = np.stack([new.distances(q, new.stack(descs)) for q in descs])
    np.testing.assert_allclose(rows, want, rtol=0, atol=1e-6)
    np.testing.assert_allclose(new.pairwise(descs), rows, rtol=0, atol=1e-12)
    assert new.symmetric_pairwise and not old.symmetric_pairwise
    assert new.distance(descs[0], descs[1]) == pytest.approx(want[0, 1], abs=1e-6)
    assert new.distances(descs[0], new.stack([])).shape == (0,)


def test_unknown_kernel_is_refused() -> None:
    from data.errors import UserError

    with pytest.raises(UserError, match="kernel"):
        ShapeContextMatcher(kernel="gpu")
