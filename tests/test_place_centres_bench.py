"""benchmarks/place_centres.py: the reference points, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("place_centres")


# A room seen from the origin: walls at x = -1, y = -1, y = 1 (vertices at 1-2 m) and
# open space to the right, where two beams reach the cap at 10 m.
ROOM = np.array([[-1.0, -1.0], [1.0, -1.0], [10.0, -0.5], [10.0, 0.5], [1.0, 1.0], [-1.0, 1.0]])


def test_observed_drops_the_vertices_at_the_cap(bench) -> None:
    r = np.hypot(ROOM[:, 0], ROOM[:, 1])
    assert r[2] == r[3] == r.max()
    np.testing.assert_array_equal(bench.observed(ROOM), [1, 1, 0, 0, 1, 1])
    # Fewer than 3 observed: every vertex counts.
    tri = np.array([[5.0, 0.0], [0.0, 5.0], [-1.0, -1.0]])
    assert bench.observed(tri).all()


def test_boundary_centre_weighs_observed_edges_by_length(bench) -> None:
    # Observed edges: (-1,-1)-(1,-1) length 2, mid (0,-1); (1,1)-(-1,1) length 2, mid (0,1);
    # (-1,1)-(-1,-1) length 2, mid (-1,0): centroid (-1/3, 0).
    np.testing.assert_allclose(bench.boundary_centre(ROOM), [-1.0 / 3.0, 0.0])
    # Edges of at most 1.5 m: none is left, so the area centroid.
    area = bench.CENTRES["area"](ROOM)
    np.testing.assert_allclose(bench.boundary_centre(ROOM, 1.5), area)


def test_geometric_median_of_a_square_and_a_far_point(bench) -> None:
    # The four corners of a square and its centre: by symmetry the centre.
    pts = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0], [0.0, 0.0]])
    np.testing.assert_allclose(bench.geometric_median(pts), [0.0, 0.0], atol=1e-9)
    # Three collinear points: the middle one.
    line = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]])
    np.testing.assert_allclose(bench.geometric_median(line), [1.0, 0.0], atol=1e-6)


def test_descriptors_about_a_centre_by_hand(bench) -> None:
    # Square of half side 1 about its centre: rings 0.625 m apart; the first (0.3125 m)
    # lies inside: arc length 2 pi 0.3125; the FFT's mean range is (4 / pi) ln tan(3 pi/8).
    sq = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    ring = bench.ring_about(sq, np.zeros(2))
    assert ring[0] == pytest.approx(2 * np.pi * 0.3125)
    assert np.all(ring[3:] == 0.0)
    fft = bench.fft_about(sq, np.zeros(2))
    assert fft[0] == pytest.approx(4 / np.pi * np.log(np.tan(3 * np.pi / 8)), rel=1e-3)
