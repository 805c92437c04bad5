"""Tangent space (turning function) matcher: formula cases, invariances, batching."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.matchers import get_matcher
from loopclosure.matchers.tangent_space import (
    TangentConfig,
    TangentDescriptor,
    TangentSpaceMatcher,
    turning_function,
)
from loopclosure.polygon import Polygon
from tests.helpers import shared_file

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def regular(n: int, radius: float) -> Polygon:
    t = np.arange(n) * 2 * np.pi / n
    return Polygon(radius * np.column_stack([np.cos(t), np.sin(t)]))


def star_polygon(rng: np.random.Generator, n: int = 30) -> Polygon:
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(2, 6, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def room(kind: int, rng: np.random.Generator) -> Polygon:
    base = {
        0: np.array([[0, 0], [8, 0], [8, 5], [0, 5]], float),
        1: np.array([[0, 0], [8, 0], [8, 3], [3, 3], [3, 8], [0, 8]], float),
        2: np.array([[0, 0], [12, 0], [12, 2], [0, 2]], float),
    }[kind]
    pts = np.roll(Polygon(base).resample(120), rng.integers(120), axis=0)
    pts = pts + rng.normal(0, 0.02, (120, 2))
    return Polygon(pts).rotated(rng.uniform(-np.pi, np.pi)).translated(rng.normal(0, 1, 2))


# --- hand-checked cases -----------------------------------------------------------------------


def test_turning_function_of_square() -> None:
    theta, total = turning_function(Polygon(SQUARE).resample(8))
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
    circle, square = regular(64, 1.0), Polygon(SQUARE)
    l1 = TangentSpaceMatcher(n_points=64, norm="l1", scale_invariant=True)
    assert l1.distance(l1.describe(circle), l1.describe(square)) == pytest.approx(np.pi / 8)
    l2 = TangentSpaceMatcher(n_points=64, norm="l2", scale_invariant=True)
    expected = np.pi / 32 * np.sqrt((16**2 - 1) / 12)
    assert l2.distance(l2.describe(circle), l2.describe(square)) == pytest.approx(expected)


def test_perimeter_term_when_not_scale_invariant() -> None:
    m = TangentSpaceMatcher(scale_weight=2.0)
    a, b = m.describe(Polygon(SQUARE)), m.describe(Polygon(SQUARE * 3))
    assert m.distance(a, b) == pytest.approx(2.0 * np.log(3.0), abs=1e-9)
    inv = TangentSpaceMatcher(scale_invariant=True)
    assert inv.distance(inv.describe(Polygon(SQUARE)), inv.describe(Polygon(SQUARE * 3))) < 1e-9


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_start_point_is_found(norm: str) -> None:
    # Starting the turning function k samples later rolls its periodic part by k.
    m = TangentSpaceMatcher(norm=norm)
    d = m.describe(star_polygon(np.random.default_rng(3)))
    for k in (1, 17, 40):
        later = TangentDescriptor(np.roll(d.periodic, -k), np.roll(d.turning, -k),
                                  d.log_perimeter)
        assert m.distance(d, later) < 1e-12
        assert m.distance(later, d) < 1e-12


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_matches_brute_force_over_shifts_and_rotations(norm: str) -> None:
    m = TangentSpaceMatcher(norm=norm, n_points=32, scale_invariant=True)
    rng = np.random.default_rng(8)
    a, b = m.describe(star_polygon(rng)), m.describe(star_polygon(rng))
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


# --- invariances ------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_to_rotated_copy_is_zero(seed: int, angle: float) -> None:
    m = TangentSpaceMatcher()
    p = star_polygon(np.random.default_rng(seed))
    # A rotation adds a constant to every edge angle: only rounding differs.
    assert m.distance(m.describe(p), m.describe(p.rotated(angle))) < 1e-9


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(-np.pi, np.pi))
def test_distance_unchanged_when_one_polygon_rotates(seed: int, angle: float) -> None:
    m = TangentSpaceMatcher()
    rng = np.random.default_rng(seed)
    p, q = star_polygon(rng), star_polygon(rng)
    a, b, b_rot = m.describe(p), m.describe(q), m.describe(q.rotated(angle))
    assert m.distance(a, b) == pytest.approx(m.distance(a, b_rot), abs=1e-9)


# --- batched distances ------------------------------------------------------------------------


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_batched_equals_single(norm: str, monkeypatch: pytest.MonkeyPatch) -> None:
    import loopclosure.matchers.tangent_space as mod

    m = TangentSpaceMatcher(norm=norm)
    rng = np.random.default_rng(0)
    descs = [m.describe(star_polygon(rng)) for _ in range(15)]
    d = m.distances(descs[0], m.stack(descs))
    single = np.array([m.distance(descs[0], x) for x in descs])
    np.testing.assert_allclose(d, single, rtol=1e-9, atol=1e-12)
    assert d[0] == 0.0 and np.all(d[1:] > 0)
    monkeypatch.setattr(mod, "_CHUNK_VALUES", 1)  # one entry per chunk
    np.testing.assert_allclose(m.distances(descs[0], m.stack(descs)), d, rtol=1e-12)
    assert m.distances(descs[0], m.stack([])).shape == (0,)


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
@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_degenerate_polygons_give_finite_descriptors(vertices: np.ndarray, norm: str) -> None:
    m = TangentSpaceMatcher(norm=norm)
    d = m.describe(Polygon(vertices))
    assert np.all(np.isfinite(d.periodic)) and np.isfinite(d.log_perimeter)
    dist = m.distance(d, m.describe(Polygon(SQUARE)))
    assert np.isfinite(dist) and dist >= 0
    assert m.distance(d, d) == 0.0


def test_registry_and_config_errors() -> None:
    m = get_matcher("tangent", n_points=32, norm="l2")
    assert isinstance(m, TangentSpaceMatcher) and m.rotation_invariant
    assert m.describe(Polygon(SQUARE)).periodic.shape == (32,)
    assert TangentSpaceMatcher(TangentConfig(scale_weight=0.5)).config.scale_weight == 0.5
    with pytest.raises(TypeError):
        TangentSpaceMatcher(points=3)
    with pytest.raises(ValueError):
        TangentSpaceMatcher(norm="linf")


# --- retrieval --------------------------------------------------------------------------------


def test_nearest_neighbour_is_same_kind_of_room() -> None:
    m = TangentSpaceMatcher()
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
    m = TangentSpaceMatcher(scale_invariant=True)
    d = m.pairwise([m.describe(Polygon(s.contour)) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[d.argmin(axis=1)] == labels) > 0.8
