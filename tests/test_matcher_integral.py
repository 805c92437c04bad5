"""Integral invariant matcher: the invariant by hand, the elastic DP, the cyclic start.

The clauses all matchers share, rotation invariance to 1e-9 among them, are tested
in test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.matchers.integral_invariant import (
    IntegralInvariantMatcher,
    elastic_match,
    integral_invariant,
)
from loopclosure.polygon import Polygon
from tests.matcher_shapes import SQUARE, random_star, regular


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
    p = random_star(np.random.default_rng(5))
    d = m.describe(p)
    for shift in (1, 7, 30):
        assert m.distance(d, np.roll(d, shift)) < 1e-12


# --- chunked database ------------------------------------------------------------------------


def test_chunked_database_equals_unchunked(monkeypatch: pytest.MonkeyPatch) -> None:
    import loopclosure.matchers.integral_invariant as mod

    m = IntegralInvariantMatcher()
    rng = np.random.default_rng(4)
    descs = [m.describe(random_star(rng)) for _ in range(9)]
    stacked = m.stack(descs)
    whole = m.distances(descs[1], stacked)
    monkeypatch.setattr(mod, "_CHUNK_VALUES", 1)  # one entry per chunk
    np.testing.assert_array_equal(m.distances(descs[1], stacked), whole)
