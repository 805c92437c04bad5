"""Grid heading hypotheses: the polar occupancy grid by hand, the convention, invariance.

The convention (`loopclosure.headings`): the heading of the query in the stored frame;
a query sensor turned by theta from the stored one sees the stored polygon rotated by
-theta about its origin.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from loopclosure.headings import (
    headings_from_polar_grids,
    headings_from_range_functions,
    polar_occupancy,
)
from loopclosure.matchers.fft import FFTMatcher
from loopclosure.matchers.pair_histogram import surface_samples
from loopclosure.place_database import PlaceDatabase
from loopclosure.polygon import Polygon
from tests.matcher_shapes import random_star


def test_polar_occupancy_by_hand() -> None:
    pts = np.array([[1.5, 0.0], [0.0, 2.5], [-0.5, -0.01], [30.0, 0.0]])
    g = polar_occupancy(pts, rings=4, sectors=4, max_range=4.0)
    # Sectors of 90 degrees from -pi: (1.5, 0) bearing 0 -> sector 2, ring 1;
    # (0, 2.5) bearing pi/2 -> sector 3, ring 2; (-0.5, -0.01) bearing just above -pi ->
    # sector 0, ring 0; the point at 30 m is beyond the grid.
    expected = np.zeros((4, 4), bool)
    expected[1, 2] = expected[2, 3] = expected[0, 0] = True
    np.testing.assert_array_equal(g, expected)


def _grid(p: Polygon) -> np.ndarray:
    pts, _, _ = surface_samples(p.vertices, step=0.1, max_edge=10.0, max_range=19.5)
    return polar_occupancy(pts, 20, 120, 20.0)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(-3.1, 3.1))
def test_grid_heading_recovers_a_turned_sensor(seed: int, theta: float) -> None:
    stored = random_star(np.random.default_rng(seed))
    query = stored.rotated(-theta)
    h, score = headings_from_polar_grids(_grid(query), _grid(stored)[None], 3)
    err = abs((h[0, 0] - theta + np.pi) % (2 * np.pi) - np.pi)
    assert err < np.radians(2.0)  # 3-degree sectors, refined by a parabola
    assert score[0, 0] > 0.5 and np.all(np.diff(score[0][np.isfinite(score[0])]) <= 0)


def test_grid_and_range_headings_share_the_convention() -> None:
    stored = random_star(np.random.default_rng(4))
    query = stored.rotated(-0.7)
    hg, _ = headings_from_polar_grids(_grid(query), _grid(stored)[None], 1)
    fft = FFTMatcher()
    hr, _ = headings_from_range_functions(
        fft.describe(query).range_function, fft.describe(stored).range_function[None], 1
    )
    assert abs(hg[0, 0] - 0.7) < 0.03 and abs(hr[0, 0] - 0.7) < 0.03


def test_empty_grid_gives_no_hypothesis() -> None:
    h, score = headings_from_polar_grids(np.zeros((4, 8)), np.ones((2, 4, 8)), 2)
    assert h.shape == (2, 2) and np.all(score == -np.inf)


def test_database_puts_grid_headings_first_and_drops_duplicates() -> None:
    rng = np.random.default_rng(1)
    db = PlaceDatabase()
    places = [random_star(rng) for _ in range(6)]
    for i, p in enumerate(places):
        db.add(i, p)
    match = db.query(places[2].rotated(-1.0))[0]
    assert match.key == 2
    heads = [h for h, _ in match.headings]
    assert abs(heads[0] - 1.0) < 0.03
    assert len(heads) <= db.config.grid_headings + db.config.n_headings
    # No two hypotheses within 5 degrees of each other across the producers.
    first = np.array(heads[: db.config.grid_headings])
    rest = np.array(heads[db.config.grid_headings:])
    if len(rest):
        gap = np.abs((rest[:, None] - first[None] + np.pi) % (2 * np.pi) - np.pi)
        assert gap.min() >= np.radians(5.0) - 1e-9
