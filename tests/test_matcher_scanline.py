"""Scan-line matcher: intersection function by hand, integral geometry, the line family.

How close a rotated copy stays (25 % of the distance to another blob) and the other
shared clauses: test_matcher_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.matchers.scan_line import ScanLineMatcher, intersection_function
from loopclosure.polygon import Polygon
from tests.matcher_shapes import blob, regular


def test_intersection_function_by_hand() -> None:
    # Chords [0, 1] and [3, 7].  Pairs (length, sign): (1,+) (3,-) (7,+) (2,+) (6,-) (4,+).
    x = [0.0, 1.0, 3.0, 7.0]
    want = [2, 1, 0, 1, 0, 1, 0]
    assert list(intersection_function(x, [0.5, 1.5, 2.5, 3.5, 5.0, 6.5, 8.0])) == want
    # One chord of length L: S(xi) = 1{L > xi}.
    assert list(intersection_function([2.0, 5.0], [0.0, 2.9, 3.1])) == [1, 1, 0]


def test_disc_descriptor_by_hand() -> None:
    # Chords of a disc of radius rho at offset p have length 2 sqrt(rho^2 - p^2) in every
    # direction, so D(xi) = |{p : 2 sqrt(rho^2 - p^2) > xi}| = sqrt(4 rho^2 - xi^2).
    m = ScanLineMatcher(n_offsets=256, xi_max=4.0)
    d = m.describe(regular(720, 2.0))
    want = np.sqrt(np.maximum(16.0 - m.xi**2, 0.0))
    np.testing.assert_allclose(d, want, atol=0.02)


def test_convex_polygon_integral_geometry() -> None:
    # Cauchy: D(0+) = number of chords integrated over lines = mean width = perimeter / pi;
    # int D(xi) dxi = mean over directions of int chord length dp = area.
    rect = Polygon(np.array([[0, 0], [4, 0], [4, 2], [0, 2]], float))
    m = ScanLineMatcher(n_offsets=256, n_xi=400, xi_max=5.0)
    d = m.describe(rect)
    assert d[0] == pytest.approx(rect.perimeter / np.pi, rel=0.01)
    assert d.sum() * m.xi_step == pytest.approx(rect.area, rel=0.02)


def test_vectorised_describe_equals_line_by_line() -> None:
    m = ScanLineMatcher(n_directions=8, n_offsets=8)
    poly = blob(7)
    v = poly.vertices - poly.centroid()
    radius = np.sqrt((v**2).sum(axis=1).max()) * (1 + 1e-9)
    total = np.zeros(m.config.n_xi)
    for k in range(8):
        d, nrm = m._direction[k], m._normal[k]
        for j in range(8):
            p = m._jitter[k, j] * 2 * radius - radius
            pts = []
            for e in range(len(v)):
                a, b = v[e], v[(e + 1) % len(v)]
                sa, sb = a @ nrm - p, b @ nrm - p
                if (sa > 0) != (sb > 0):
                    pts.append((a + (b - a) * sa / (sa - sb)) @ d)
            total += intersection_function(sorted(pts), m.xi)
    want = total * (2 * radius / 8) / 8
    np.testing.assert_allclose(m.describe(poly), want, rtol=1e-9, atol=1e-9)


def test_translation_and_start_vertex_exact() -> None:
    # The line family lives in the centroid frame and ignores the vertex order.
    m = ScanLineMatcher()
    a = blob(3)
    moved = Polygon(np.roll(a.vertices, 17, axis=0) + np.array([4.0, -9.0]))
    np.testing.assert_allclose(m.describe(a), m.describe(moved), atol=1e-9)


def test_empty_stack_has_one_column_per_interval_length() -> None:
    m = ScanLineMatcher()
    assert m.stack([]).shape == (0, m.config.n_xi)
