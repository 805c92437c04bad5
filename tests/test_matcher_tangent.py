"""Tangent space (turning function) matcher: formula cases, start point, chunked search.

Shared matcher clauses (rotation invariance to 1e-9, batching, degenerate polygons,
retrieval, options): test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.matchers.tangent_space import (
    TangentDescriptor,
    TangentSpaceMatcher,
    turning_function,
)
from loopclosure.polygon import Polygon
from tests.matcher_shapes import UNIT_SQUARE, random_star, regular

# --- hand-checked cases -----------------------------------------------------------------------


def test_turning_function_of_square() -> None:
    theta, total = turning_function(Polygon(UNIT_SQUARE).resample(8))
    np.testing.assert_allclose(theta, np.repeat([0, 0.5, 1.0, 1.5], 2) * np.pi, atol=1e-12)
    assert total == pytest.approx(2 * np.pi)


def test_turning_function_of_triangle_and_clockwise_loop() -> None:
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2]])
    theta, total = turning_function(tri)
    np.testing.assert_allclose(theta, [0, 2 * np.pi / 3, 4 * np.pi / 3], atol=1e-12)
    assert total == pytest.approx(2 * np.pi)
    _, total_cw = turning_function(tri[::-1])
    assert total_cw == pytest.approx(-2 * np.pi)


def test_regular_polygon_has_constant_periodic_part() -> None:
    d = TangentSpaceMatcher(n_points=64).describe(regular(64, 3.0))
    assert np.ptp(d.periodic) < 1e-9


def test_circle_versus_square_by_hand() -> None:
    # With n = 64 samples the square's periodic part Theta(s) - 2 pi s is a sawtooth: per
    # side the 16 values -(pi/2)(j/16), j = 0..15 (plus a constant).  Against the constant
    # of the 64-gon, for every start:
    #   L1: min_theta mean |saw - theta| = mean |v - median| = (pi/32) * 4 = pi / 8,
    #   L2: sqrt(var(saw)) = (pi/32) * sqrt((16^2 - 1) / 12).
    circle, square = regular(64, 1.0), Polygon(UNIT_SQUARE)
    l1 = TangentSpaceMatcher(n_points=64, norm="l1", scale_invariant=True)
    assert l1.distance(l1.describe(circle), l1.describe(square)) == pytest.approx(np.pi / 8)
    l2 = TangentSpaceMatcher(n_points=64, norm="l2", scale_invariant=True)
    expected = np.pi / 32 * np.sqrt((16**2 - 1) / 12)
    assert l2.distance(l2.describe(circle), l2.describe(square)) == pytest.approx(expected)


def test_perimeter_term_when_not_scale_invariant() -> None:
    small, big = Polygon(UNIT_SQUARE), Polygon(UNIT_SQUARE * 3)
    m = TangentSpaceMatcher(scale_weight=2.0)
    assert m.distance(m.describe(small), m.describe(big)) == pytest.approx(
        2.0 * np.log(3.0), abs=1e-9
    )
    inv = TangentSpaceMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(small), inv.describe(big)) < 1e-9


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_start_point_is_found(norm: str) -> None:
    # Starting the turning function k samples later rolls its periodic part by k.
    m = TangentSpaceMatcher(norm=norm)
    d = m.describe(random_star(np.random.default_rng(3), 30))
    for k in (1, 17, 40):
        later = TangentDescriptor(np.roll(d.periodic, -k), np.roll(d.turning, -k),
                                  d.log_perimeter)
        assert m.distance(d, later) < 1e-12
        assert m.distance(later, d) < 1e-12


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_matches_brute_force_over_shifts_and_rotations(norm: str) -> None:
    m = TangentSpaceMatcher(norm=norm, n_points=32, scale_invariant=True)
    rng = np.random.default_rng(8)
    a, b = m.describe(random_star(rng, 30)), m.describe(random_star(rng, 30))
    best = np.inf
    for t in range(32):
        diff = np.roll(a.periodic, -t) - b.periodic
        thetas = np.linspace(-diff.max(), -diff.min(), 20001)
        if norm == "l1":
            cost = np.abs(diff[None, :] + thetas[:, None]).mean(axis=1).min()
        else:
            cost = np.sqrt(((diff[None, :] + thetas[:, None]) ** 2).mean(axis=1).min())
        best = min(best, cost)
    # The grid of rotations spans every useful rotation in steps below 1e-3 rad: the
    # closed forms may only be better, by at most that step.
    assert m.distance(a, b) <= best + 1e-12
    assert m.distance(a, b) == pytest.approx(best, abs=1e-3)


# --- chunked database -------------------------------------------------------------------------


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_chunked_database_equals_unchunked(norm: str, monkeypatch: pytest.MonkeyPatch) -> None:
    import loopclosure.matchers.tangent_space as mod

    m = TangentSpaceMatcher(norm=norm)
    rng = np.random.default_rng(0)
    descs = [m.describe(random_star(rng, 30)) for _ in range(15)]
    d = m.distances(descs[0], m.stack(descs))
    monkeypatch.setattr(mod, "_CHUNK_VALUES", 1)  # one entry per chunk
    np.testing.assert_allclose(m.distances(descs[0], m.stack(descs)), d, rtol=1e-12)
